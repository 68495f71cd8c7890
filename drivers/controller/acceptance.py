"""MotoROS(2)-style trajectory acceptance, free of controller state (readiness is separate).

Rules, in the order they are checked (first failure wins; the reply names rule, point and joint):
array shapes; joint names and order; at least 2 and at most `max_points` points; finite values;
`time_from_start` zero on the first point only and strictly increasing; the first point at the current
position (within `start_tolerance`); positions inside limits at every point; velocities at points and
implied by consecutive points inside limits; the last point at rest; the Hermite interpolation between
points inside position, velocity and acceleration limits (exact bounds, so every 4 ms sample is inside).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from drivers.controller.codes import OK, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig
from drivers.controller.trajectory import FloatArray, JointTrajectory, segment_extrema
from drivers.robot.config import RobotConfig


def _invalid(sub: Subcode, text: str, point: int = -1, joint: str = "") -> Reply:
    return Reply(Result.INVALID, sub, text, point, joint)


def _first(mask: np.ndarray) -> tuple[int, int]:
    """(point, joint) of the first True in a (K, n) mask, row-major."""
    k, j = np.unravel_index(int(np.argmax(mask)), mask.shape)
    return int(k), int(j)


def check_trajectory(trajectory: JointTrajectory, current_position: FloatArray, robot_config: RobotConfig,
                     config: ControllerConfig, expected_joints: Sequence[str] | None = None) -> Reply:
    """Check a trajectory against every acceptance rule; `OK` or the first violation.

    The trajectory's `joint_names` must equal `expected_joints` (default: all joints of `robot_config`
    in project order), same order; velocities None are zero at every point (as MotoROS does).
    current_position: (n,) rad, in `expected_joints` order.
    """
    expected = tuple(expected_joints) if expected_joints is not None else robot_config.joint_names
    n = len(expected)
    try:
        pos = np.asarray(trajectory.positions, dtype=float)
        t = np.asarray(trajectory.times, dtype=float)
        vel = trajectory.point_velocities
        cur = np.asarray(current_position, dtype=float)
    except (TypeError, ValueError) as exc:
        return _invalid(Subcode.INVALID_MSGSIZE, f"arrays: not numeric ({exc})")
    if cur.shape != (n,):
        raise ValueError(f"current_position must have shape ({n},), got {cur.shape}")
    idx = [robot_config.index(name) for name in expected]
    limits = _Limits(robot_config.lower[idx], robot_config.upper[idx],
                     robot_config.max_velocity[idx] * (1.0 + config.limit_tolerance),
                     robot_config.max_acceleration[idx] * (1.0 + config.limit_tolerance))
    return (_check_names(tuple(trajectory.joint_names), expected)
            or _check_shapes(pos, vel, t, n, config.max_points)
            or _check_times(pos, vel, t, expected)
            or _check_start(pos, cur, expected, config.start_tolerance)
            or _check_points(pos, vel, t, expected, limits)
            or _check_interpolation(pos, vel, t, expected, limits)
            or OK)


@dataclass(frozen=True)
class _Limits:
    """Per joint, in the checked order: rad, and rad/s, rad/s^2 with the rounding slack."""

    lower: FloatArray
    upper: FloatArray
    velocity: FloatArray
    acceleration: FloatArray


def _check_names(names: tuple[str, ...], expected: tuple[str, ...]) -> Reply | None:
    """The columns are exactly the expected joints, in order."""
    if names == expected:
        return None
    for i, name in enumerate(names):
        if name not in expected:
            return _invalid(Subcode.INVALID_DATA, f"joint names: unknown joint {name!r}", -1, name)
        if name in names[:i]:
            return _invalid(Subcode.INVALID_DATA, f"joint names: {name!r} appears twice", -1, name)
    for name in expected:
        if name not in names:
            return _invalid(Subcode.INVALID_DATA, f"joint names: {name!r} is missing", -1, name)
    i = next(i for i, (a, b) in enumerate(zip(names, expected, strict=False)) if a != b)
    return _invalid(Subcode.INVALID_DATA,
                    f"joint order: column {i} is {names[i]!r}, expected {expected[i]!r}", -1, names[i])


def _check_shapes(pos: FloatArray, vel: FloatArray, t: FloatArray, n: int, max_points: int) -> Reply | None:
    """One value per joint and point; between 2 and `max_points` points."""
    if pos.ndim != 2 or pos.shape[1] != n:
        return _invalid(Subcode.INVALID_MSGSIZE, f"positions: shape must be (points, {n}), got {pos.shape}")
    k = pos.shape[0]
    if vel.shape != pos.shape:
        return _invalid(Subcode.INVALID_MSGSIZE, f"velocities: shape must be {pos.shape}, got {vel.shape}")
    if t.shape != (k,):
        return _invalid(Subcode.INVALID_MSGSIZE, f"times: shape must be ({k},), got {t.shape}")
    if k < 2:
        return _invalid(Subcode.INVALID_DATA_INSUFFICIENT, f"point count: at least 2 points needed, got {k}")
    if k > max_points:
        return _invalid(Subcode.INVALID_MSGSIZE, f"point count: at most {max_points} points allowed, got {k}",
                        max_points)
    return None


def _check_times(pos: FloatArray, vel: FloatArray, t: FloatArray, expected: tuple[str, ...]) -> Reply | None:
    """Finite values; time_from_start 0 on the first point, then strictly increasing."""
    for label, arr in (("positions", pos), ("velocities", vel)):
        bad = ~np.isfinite(arr)
        if bad.any():
            p, j = _first(bad)
            return _invalid(Subcode.INVALID_DATA, f"finite values: {label} of {expected[j]} at point {p} "
                            f"is {arr[p, j]}", p, expected[j])
    if not np.isfinite(t).all():
        p = int(np.argmax(~np.isfinite(t)))
        return _invalid(Subcode.INVALID_DATA, f"finite values: time_from_start at point {p} is {t[p]}", p)
    if t[0] != 0.0:
        return _invalid(Subcode.INVALID_DATA_TIME,
                        f"time: the first point must have time_from_start 0, got {t[0]}", 0)
    steps = np.diff(t)
    if (steps <= 0.0).any():
        p = int(np.argmax(steps <= 0.0)) + 1
        return _invalid(Subcode.INVALID_DATA_TIME, f"time: time_from_start must increase strictly; point {p} "
                        f"has {t[p]} after {t[p - 1]}", p)
    return None


def _check_start(pos: FloatArray, cur: FloatArray, expected: tuple[str, ...],
                 tolerance: float) -> Reply | None:
    """The first point is where the robot is (or where its queue ends)."""
    off = np.abs(pos[0] - cur) > tolerance
    if off.any():
        j = int(np.argmax(off))
        return _invalid(Subcode.INVALID_DATA_START_POS,
                        f"start position: {expected[j]} at point 0 is {pos[0, j]:.6f} rad, current is "
                        f"{cur[j]:.6f} rad (tolerance {tolerance} rad)", 0, expected[j])
    return None


def _check_points(pos: FloatArray, vel: FloatArray, t: FloatArray, expected: tuple[str, ...],
                  limits: _Limits) -> Reply | None:
    """At the points: positions and velocities inside the limits, so are the velocities implied by
    consecutive points, and the last point at rest."""
    lower, upper, vmax = limits.lower, limits.upper, limits.velocity
    out = (pos < lower) | (pos > upper)
    if out.any():
        p, j = _first(out)
        return _invalid(Subcode.INVALID_DATA_POSITION, f"position limits: {expected[j]} at point {p} is "
                        f"{pos[p, j]:.6f} rad, outside [{lower[j]:.6f}, {upper[j]:.6f}]", p, expected[j])
    fast = np.abs(vel) > vmax
    if fast.any():
        p, j = _first(fast)
        return _invalid(Subcode.INVALID_DATA_SPEED, f"velocity limits: {expected[j]} at point {p} has "
                        f"{vel[p, j]:.6f} rad/s, limit {vmax[j]:.6f}", p, expected[j])
    implied = np.abs(np.diff(pos, axis=0)) / np.diff(t)[:, None]
    fast = implied > vmax
    if fast.any():
        p, j = _first(fast)
        return _invalid(Subcode.INVALID_DATA_SPEED, f"implied velocity: {expected[j]} from point {p} to "
                        f"{p + 1} needs {implied[p, j]:.6f} rad/s, limit {vmax[j]:.6f}", p + 1, expected[j])
    moving = vel[-1] != 0.0
    if moving.any():
        j = int(np.argmax(moving))
        k = pos.shape[0]
        return _invalid(Subcode.INVALID_DATA_SPEED, f"last point at rest: {expected[j]} at point {k - 1} has "
                        f"velocity {vel[-1, j]} rad/s, must be 0", k - 1, expected[j])
    return None


def _check_interpolation(pos: FloatArray, vel: FloatArray, t: FloatArray, expected: tuple[str, ...],
                         limits: _Limits) -> Reply | None:
    """Between the points: the Hermite interpolation's exact extremes inside the limits."""
    lower, upper, vmax, amax = limits.lower, limits.upper, limits.velocity, limits.acceleration
    pmin, pmax, vpeak, apeak = segment_extrema(t, pos, vel)
    out = (pmin < lower) | (pmax > upper)
    if out.any():
        p, j = _first(out)
        return _invalid(Subcode.INVALID_DATA_POSITION, f"interpolated position limits: {expected[j]} between "
                        f"points {p} and {p + 1} reaches [{pmin[p, j]:.6f}, {pmax[p, j]:.6f}] rad, limits "
                        f"[{lower[j]:.6f}, {upper[j]:.6f}]", p + 1, expected[j])
    fast = vpeak > vmax
    if fast.any():
        p, j = _first(fast)
        return _invalid(Subcode.INVALID_DATA_SPEED,
                        f"interpolated velocity: {expected[j]} between points {p} and {p + 1} reaches "
                        f"{vpeak[p, j]:.6f} rad/s, limit {vmax[j]:.6f}", p + 1, expected[j])
    hard = apeak > amax
    if hard.any():
        p, j = _first(hard)
        return _invalid(Subcode.INVALID_DATA_ACCEL,
                        f"interpolated acceleration: {expected[j]} between points {p} and {p + 1} reaches "
                        f"{apeak[p, j]:.6f} rad/s^2, limit {amax[j]:.6f}", p + 1, expected[j])
    return None


@dataclass(frozen=True)
class Readiness:
    """What a controller must be for motion (MotoROS `CHECK_MOTION_READY`)."""

    e_stopped: bool
    alarm_code: int
    servo_on: bool
    held: bool
    play_mode: bool
    remote: bool
    traj_mode: bool
    queue_count: int
    queue_size: int


def check_ready(state: Readiness) -> Reply:
    """`OK`, NOT_READY with MotoROS' subcode, or BUSY when the queue is full (MotoROS: retry)."""
    checks = (
        (state.e_stopped, Subcode.NOT_READY_ESTOP, "e-stop is engaged: reset it and switch servos on"),
        (state.alarm_code != 0, Subcode.NOT_READY_ALARM, f"alarm {state.alarm_code} is active: reset it"),
        (not state.play_mode, Subcode.NOT_READY_NOT_PLAY, "the controller is in TEACH mode, not PLAY"),
        (not state.remote, Subcode.NOT_READY_NOT_REMOTE, "the controller is not in remote mode"),
        (not state.servo_on, Subcode.NOT_READY_SERVO_OFF, "servos are off: switch them on"),
        (state.held, Subcode.NOT_READY_HOLD, "the controller is held: resume first"),
        (not state.traj_mode, Subcode.NOT_READY_NOT_STARTED, "trajectory mode is not started"),
    )
    for failed, sub, text in checks:
        if failed:
            return Reply(Result.NOT_READY, sub, f"readiness: {text}")
    if state.queue_count >= state.queue_size:
        return Reply(Result.BUSY, Subcode.NONE,
                     f"readiness: the queue is full ({state.queue_count}/{state.queue_size}): retry")
    return OK
