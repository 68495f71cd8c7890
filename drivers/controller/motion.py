"""The one jerk-limited rest-to-rest motion (ruckig) of the project: a planner's point-to-point moves,
and the MOVE_TO and JOG any controller front answers (the emulator's core, the master for its whole
cell, a MotoROS client that plans `move_to` itself)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Ruckig, Synchronization, Trajectory
from ruckig import Result as RuckigResult

from drivers.controller.codes import Command, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig
from drivers.controller.trajectory import FloatArray, JointTrajectory
from drivers.robot.config import RobotConfig


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
    traj = rest_to_rest(start, target, max_velocity, max_acceleration, max_jerk)
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


def rest_to_rest(start: FloatArray, target: FloatArray, max_velocity: FloatArray,
                 max_acceleration: FloatArray, max_jerk: FloatArray) -> Trajectory:
    """ruckig's profile from rest to rest, phase-synchronised: every axis follows the same profile
    scaled, so the path is the straight line in joint space (what the planner's collision check
    assumes between two waypoints, and what a pendant's move does); ruckig falls back to
    time synchronisation where phase is impossible. PlanError when ruckig cannot plan."""
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
    inp.synchronization = Synchronization.Phase
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
