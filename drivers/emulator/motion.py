"""Pure motion helpers of the emulator: a trajectory prepared for interpolation, and ruckig move-to."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Ruckig, Synchronization, Trajectory
from ruckig import Result as RuckigResult

from drivers.controller.interpolation import FloatArray, hermite_coefficients


@dataclass(frozen=True)
class PreparedTrajectory:
    """An accepted trajectory with its Hermite coefficients per segment, ready for per-tick evaluation."""

    times: FloatArray  # (K,)
    positions: FloatArray  # (K, n)
    velocities: FloatArray  # (K, n)
    a1: FloatArray  # (K-1, n) acceleration at each segment start
    a2: FloatArray  # (K-1, n) jerk of each segment
    start_tick: int  # not before this interpolation tick
    ident: int = 0  # the controller's id of the accepted trajectory

    @staticmethod
    def build(times: FloatArray, positions: FloatArray, velocities: FloatArray,
              start_tick: int, ident: int = 0) -> PreparedTrajectory:
        times = np.asarray(times, dtype=float).copy()
        positions = np.asarray(positions, dtype=float).copy()
        velocities = np.asarray(velocities, dtype=float).copy()
        T = np.diff(times)[:, None]
        a1, a2 = hermite_coefficients(positions[:-1], velocities[:-1], positions[1:], velocities[1:], T)
        return PreparedTrajectory(times, positions, velocities, a1, a2, start_tick, ident)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def evaluate(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, path velocity, path acceleration at trajectory time `t` (clamped to the ends)."""
        if t >= self.times[-1]:
            return self.positions[-1].copy(), self.velocities[-1].copy(), np.zeros(self.positions.shape[1])
        t = max(t, 0.0)
        seg = min(int(np.searchsorted(self.times, t, side="right")) - 1, len(self.times) - 2)
        tau = t - self.times[seg]
        p0, v0, a1, a2 = self.positions[seg], self.velocities[seg], self.a1[seg], self.a2[seg]
        p = p0 + tau * (v0 + tau * (a1 / 2.0 + tau * a2 / 6.0))
        v = v0 + tau * (a1 + tau * a2 / 2.0)
        a = a1 + tau * a2
        return p, v, a


class PlanError(ValueError):
    """ruckig could not plan the requested motion."""


# Breakpoints of different axes closer than this (s) are merged: a Hermite segment that short would
# divide by a near-zero duration. The merge moves a breakpoint by at most this much.
_MIN_SEGMENT = 1e-4


def plan_point_to_point(start: FloatArray, target: FloatArray, max_velocity: FloatArray,
                        max_acceleration: FloatArray, max_jerk: FloatArray,
                        max_points: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A jerk-limited motion from rest at `start` to rest at `target`, all axes finishing together.

    Returns (times (K,), positions (K, n), velocities (K, n)): the points are the union of every axis'
    ruckig phase boundaries, where the jerk changes. Between them every axis moves along one cubic, so
    MotoROS' Hermite interpolation through the points reproduces ruckig's profile (and its limits)
    exactly. First point at `start`, last at `target`, both at rest. Limits per axis, SI units.
    """
    start = np.asarray(start, dtype=float)
    target = np.asarray(target, dtype=float)
    n = start.size
    inp = InputParameter(n)
    inp.current_position = start.tolist()
    inp.current_velocity = [0.0] * n
    inp.current_acceleration = [0.0] * n
    inp.target_position = target.tolist()
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = np.asarray(max_velocity, dtype=float).tolist()
    inp.max_acceleration = np.asarray(max_acceleration, dtype=float).tolist()
    inp.max_jerk = np.asarray(max_jerk, dtype=float).tolist()
    inp.synchronization = Synchronization.Time
    traj = Trajectory(n)
    result = Ruckig(n).calculate(inp, traj)
    if result not in (RuckigResult.Working, RuckigResult.Finished):
        raise PlanError(f"ruckig failed: {result}")
    duration = float(traj.duration)
    if duration < _MIN_SEGMENT:
        raise PlanError("the target equals the start: nothing to move")
    bounds = [0.0, duration]
    for profile in traj.profiles[0]:
        bounds.extend(np.cumsum(profile.t).tolist())
    merged: list[float] = []
    for t in sorted(bounds):
        if 0.0 <= t <= duration and (not merged or t - merged[-1] >= _MIN_SEGMENT):
            merged.append(t)
    if duration - merged[-1] < _MIN_SEGMENT:
        merged[-1] = duration
    else:
        merged.append(duration)
    if len(merged) > max_points:
        raise PlanError(f"the profile needs {len(merged)} points, more than {max_points}")
    times = np.array(merged)
    positions = np.empty((times.size, n))
    velocities = np.empty((times.size, n))
    for i, t in enumerate(times):
        p, v, _ = traj.at_time(float(t))
        positions[i] = p
        velocities[i] = v
    positions[0], velocities[0] = start, 0.0
    positions[-1], velocities[-1] = target, 0.0
    return times, positions, velocities
