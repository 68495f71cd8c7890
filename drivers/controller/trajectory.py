"""The trajectory a controller executes, and MotoROS' cubic Hermite interpolation between its points.

Units: s, rad, rad/s. Joint order is the trajectory's `joint_names` (the project order of
`config/robot/joints.yaml` for a whole-cell trajectory). Per joint, over a segment of duration T from
(p0, v0) to (p1, v1), vectorised over joints and samples:
    p(tau) = p0 + v0 tau + a1 tau^2/2 + a2 tau^3/6
    a1 = 6 (p1 - p0)/T^2 - 2 (v1 + 2 v0)/T,   a2 = -12 (p1 - p0)/T^3 + 6 (v1 + v0)/T^2
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class JointTrajectory:
    """A trajectory as sent (`trajectory_msgs/JointTrajectory`): K points over n joints."""

    joint_names: tuple[str, ...]
    times: FloatArray  # (K,) time_from_start, s; 0 on the first point
    positions: FloatArray  # (K, n) rad
    velocities: FloatArray | None = None  # (K, n) rad/s; None = interpolated with zero velocities
    label: str = ""  # what the motion is for, for logs (the message's header.frame_id)

    @property
    def duration(self) -> float:
        """time_from_start of the last point, s."""
        return float(self.times[-1])

    @property
    def point_velocities(self) -> FloatArray:
        """(K, n) velocities at the points, zero where none are given (as MotoROS interpolates)."""
        if self.velocities is None:
            return np.zeros_like(np.asarray(self.positions, dtype=float))
        return np.asarray(self.velocities, dtype=float)

    def dense_positions(self, period: float) -> FloatArray:
        """Positions (M, n) as the controller interpolates them, at most `period` s apart: every point,
        and each segment cut into equal steps."""
        times = np.asarray(self.times, dtype=float)
        steps = np.maximum(1, np.ceil(np.diff(times) / period).astype(int))
        instants = [times[:1]] + [times[k] + np.arange(1, m + 1) / m * (times[k + 1] - times[k])
                                  for k, m in enumerate(steps)]
        positions, _, _ = sample(times, self.positions, self.point_velocities, np.concatenate(instants))
        return positions


def hermite_coefficients(p0: FloatArray, v0: FloatArray, p1: FloatArray, v1: FloatArray,
                         duration: FloatArray | float) -> tuple[FloatArray, FloatArray]:
    """(a1, a2): the acceleration at the segment start and the (constant) jerk; broadcasts."""
    T = np.asarray(duration, dtype=float)
    dp = np.asarray(p1, dtype=float) - p0
    a1 = 6.0 * dp / T**2 - 2.0 * (np.asarray(v1) + 2.0 * np.asarray(v0)) / T
    a2 = -12.0 * dp / T**3 + 6.0 * (np.asarray(v1) + np.asarray(v0)) / T**2
    return a1, a2


def hermite(p0: FloatArray, v0: FloatArray, p1: FloatArray, v1: FloatArray, duration: FloatArray | float,
            tau: FloatArray | float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Position, velocity and acceleration at time `tau` (s) into the segment; broadcasts."""
    a1, a2 = hermite_coefficients(p0, v0, p1, v1, duration)
    tau = np.asarray(tau, dtype=float)
    p = p0 + v0 * tau + a1 * tau**2 / 2.0 + a2 * tau**3 / 6.0
    v = v0 + a1 * tau + a2 * tau**2 / 2.0
    a = a1 + a2 * tau
    return p, v, a


def sample(times: FloatArray, positions: FloatArray, velocities: FloatArray,
           t: FloatArray | float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Interpolate a trajectory (times (K,), positions/velocities (K, n)) at times `t` (M,) or scalar.

    Returns position, velocity, acceleration, each (M, n) (or (n,) for a scalar `t`). Times before the
    first point give the first point; times after the last give the last point at rest.
    """
    times = np.asarray(times, dtype=float)
    positions = np.asarray(positions, dtype=float)
    velocities = np.asarray(velocities, dtype=float)
    scalar = np.ndim(t) == 0
    t = np.atleast_1d(np.asarray(t, dtype=float))
    seg = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    tc = np.clip(t, times[0], times[-1])
    tau = (tc - times[seg])[:, None]
    T = (times[seg + 1] - times[seg])[:, None]
    p, v, a = hermite(positions[seg], velocities[seg], positions[seg + 1], velocities[seg + 1], T, tau)
    done = (t >= times[-1])[:, None]
    p = np.where(done, positions[-1], p)
    v = np.where(done, velocities[-1], v)
    a = np.where(done, 0.0, a)
    if scalar:
        return p[0], v[0], a[0]
    return p, v, a


def segment_extrema(times: FloatArray, positions: FloatArray,
                    velocities: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Exact extremes of the interpolated motion over each segment, per joint, each (K-1, n).

    Returns (min position, max position, max |velocity|, max |acceleration|). The acceleration is
    linear in tau, so its extremes are at the segment ends; the velocity is quadratic (vertex inside
    the segment); the position is cubic (extremes where the velocity is zero). Exact bounds include
    every sample the 4 ms interpolation can produce.
    """
    times = np.asarray(times, dtype=float)
    p0, p1 = positions[:-1], positions[1:]
    v0, v1 = velocities[:-1], velocities[1:]
    T = np.diff(times)[:, None] * np.ones_like(p0)
    a1, a2 = hermite_coefficients(p0, v0, p1, v1, T)
    a_end = a1 + a2 * T
    acc_max = np.maximum(np.abs(a1), np.abs(a_end))
    # velocity vertex at tau = -a1/a2
    with np.errstate(divide="ignore", invalid="ignore"):
        tv = np.where(a2 != 0.0, -a1 / a2, -1.0)
    inside = (tv > 0.0) & (tv < T)
    v_vertex = v0 + a1 * tv + a2 * tv**2 / 2.0
    vel_max = np.maximum(np.abs(v0), np.abs(v1))
    vel_max = np.where(inside, np.maximum(vel_max, np.abs(v_vertex)), vel_max)
    # position extremes: roots of v(tau) = v0 + a1 tau + a2 tau^2/2
    pmin = np.minimum(p0, p1)
    pmax = np.maximum(p0, p1)
    A, B, C = a2 / 2.0, a1, v0
    with np.errstate(divide="ignore", invalid="ignore"):
        disc = B * B - 4.0 * A * C
        sq = np.sqrt(np.where(disc >= 0.0, disc, 0.0))
        quad = np.abs(A) > 1e-12
        r1 = np.where(quad, (-B + sq) / (2.0 * A), np.where(B != 0.0, -C / B, -1.0))
        r2 = np.where(quad, (-B - sq) / (2.0 * A), -1.0)
    for r in (r1, r2):
        ok = (disc >= 0.0) & (r > 0.0) & (r < T) & np.isfinite(r)
        pr = p0 + v0 * r + a1 * r**2 / 2.0 + a2 * r**3 / 6.0
        pmin = np.where(ok, np.minimum(pmin, pr), pmin)
        pmax = np.where(ok, np.maximum(pmax, pr), pmax)
    return pmin, pmax, vel_max, acc_max
