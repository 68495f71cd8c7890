"""Pure motion helpers of the emulator: a trajectory prepared for interpolation, and the ruckig motion
behind MOVE_TO and JOG (one function for one controller's joints and for the master's whole cell)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from ruckig import InputParameter, Ruckig, Synchronization, Trajectory
from ruckig import Result as RuckigResult

from drivers.controller.codes import Command, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig
from drivers.controller.trajectory import FloatArray, JointTrajectory, hermite_coefficients
from drivers.robot.config import RobotConfig

IntArray = NDArray[np.int_]


@dataclass(frozen=True)
class PreparedTrajectory:
    """An accepted trajectory with its Hermite coefficients per segment, ready for per-tick evaluation.

    It holds the whole path of a coordinated motion (every joint the master and the slave move
    together, `joint_names`); `columns` picks the joints of the controller that runs it. Evaluating the
    whole path lets each controller compute the same stop profile (`drivers.emulator.core`).
    """

    joint_names: tuple[str, ...]  # the path's joints
    times: FloatArray  # (K,)
    positions: FloatArray  # (K, n) over the path's joints
    velocities: FloatArray  # (K, n)
    a1: FloatArray  # (K-1, n) acceleration at each segment start
    a2: FloatArray  # (K-1, n) jerk of each segment
    columns: IntArray  # this controller's joints within the path's, in its order
    start_tick: int | None  # not before this interpolation tick; None: pre-loaded, waits for a release
    ident: int = 0  # the controller's id of the accepted trajectory

    @staticmethod
    def build(trajectory: JointTrajectory, start_tick: int | None, ident: int = 0,
              joints: Sequence[str] | None = None) -> PreparedTrajectory:
        """`joints`: the controller's joints (default: all of the trajectory's), each in the path."""
        names = tuple(trajectory.joint_names)
        own = names if joints is None else tuple(joints)
        missing = [j for j in own if j not in names]
        if missing:
            raise ValueError(f"joint_names: the path lacks {missing[0]!r}")
        columns = np.array([names.index(j) for j in own], dtype=int)
        times = np.array(trajectory.times, dtype=float)
        positions = np.array(trajectory.positions, dtype=float)
        velocities = trajectory.point_velocities.copy()
        T = np.diff(times)[:, None]
        a1, a2 = hermite_coefficients(positions[:-1], velocities[:-1], positions[1:], velocities[1:], T)
        return PreparedTrajectory(names, times, positions, velocities, a1, a2, columns, start_tick, ident)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    @property
    def end_position(self) -> FloatArray:
        """The controller's joints at the last point."""
        return self.positions[-1, self.columns].copy()

    def evaluate(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, path velocity, path acceleration of every path joint at trajectory time `t`
        (clamped to the ends)."""
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
    traj = _rest_to_rest(start, target, max_velocity, max_acceleration, max_jerk)
    duration = float(traj.duration)
    if duration < _MIN_SEGMENT:
        raise PlanError("the target equals the start: nothing to move")
    merged = _phase_boundaries(traj, duration)
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


def _rest_to_rest(start: FloatArray, target: FloatArray, max_velocity: FloatArray,
                  max_acceleration: FloatArray, max_jerk: FloatArray) -> Trajectory:
    """ruckig's time-synchronised profile from rest to rest."""
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
    return traj


def _phase_boundaries(traj: Trajectory, duration: float) -> list[float]:
    """Every axis' phase boundaries (s) in [0, duration], those closer than `_MIN_SEGMENT` merged."""
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
    return merged


@dataclass(frozen=True)
class Axes:
    """The joints one controller moves (project order) and their limits: rad, rad/s, rad/s^2, rad/s^3."""

    names: tuple[str, ...]
    lower: FloatArray
    upper: FloatArray
    max_velocity: FloatArray
    max_acceleration: FloatArray
    max_jerk: FloatArray

    @staticmethod
    def of(robot_config: RobotConfig, names: Sequence[str]) -> Axes:
        idx = np.array([robot_config.index(name) for name in names], dtype=int)
        return Axes(tuple(names), robot_config.lower[idx], robot_config.upper[idx],
                    robot_config.max_velocity[idx], robot_config.max_acceleration[idx],
                    robot_config.max_jerk[idx])


def move_trajectory(command: Command, axes: Axes, start: FloatArray, values: Sequence[float] | FloatArray,
                    joint: str, permission: Reply, config: ControllerConfig) -> JointTrajectory | Reply:
    """The jerk-limited trajectory of a MOVE_TO (`values`: a target for every axis) or a JOG (`joint`
    moves by `values[0]` rad) from `start` (where the queue ends), or the reply that answers the command
    instead: INVALID for a bad target, `permission` (the lease and readiness check) when it refuses,
    SUCCESS when the target is `start`, FAILURE/PLAN_FAILED when ruckig cannot plan."""
    name = command.name.lower()
    target = _target(command, axes, start, values, joint)
    if isinstance(target, Reply):
        return target
    out = (target < axes.lower) | (target > axes.upper)
    if out.any():
        j = int(np.argmax(out))
        return Reply(Result.INVALID, Subcode.INVALID_DATA_POSITION,
                     f"{name}: {axes.names[j]} target {target[j]:.6f} rad is outside "
                     f"[{axes.lower[j]:.6f}, {axes.upper[j]:.6f}]", -1, axes.names[j])
    if not permission.ok:
        return permission
    if np.allclose(target, start, rtol=0.0, atol=1e-9):
        return Reply(Result.SUCCESS, Subcode.NONE, f"{name}: already at the target")
    f = config.move_to_limit_fraction
    try:
        times, positions, velocities = plan_point_to_point(
            start, target, axes.max_velocity * f, axes.max_acceleration * f, axes.max_jerk * f,
            config.max_points)
    except PlanError as exc:
        return Reply(Result.FAILURE, Subcode.PLAN_FAILED, f"{name}: {exc}")
    return JointTrajectory(axes.names, times, positions, velocities, name)


def _target(command: Command, axes: Axes, start: FloatArray, values: Sequence[float] | FloatArray,
            joint: str) -> FloatArray | Reply:
    """Every axis' target of a MOVE_TO or JOG, or INVALID/BAD_ARGUMENT naming the bad argument."""
    if command == Command.JOG:
        if joint not in axes.names:
            return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                         f"jog: joint must be one of {', '.join(axes.names)}, got {joint!r}", -1, joint)
        if len(values) != 1 or not np.isfinite(values[0]):
            return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                         f"jog: values must be (delta rad), got {list(values)}", -1, joint)
        target = np.array(start, dtype=float)
        target[axes.names.index(joint)] += float(values[0])
        return target
    target = np.asarray(values, dtype=float)
    if target.shape != (len(axes.names),) or not np.isfinite(target).all():
        return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                     f"move_to: values must be {len(axes.names)} finite joint positions, "
                     f"got {target.tolist()}")
    return target
