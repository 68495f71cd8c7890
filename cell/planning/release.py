"""Letting go of cloth the grippers hold when the plan that closed them is gone (a restarted cell, a
step that failed with the cloth in hand): carry it where that plan would have, open, retreat.

A gripper closed for a fold or a pull has a `Carry`: the TCP positions its plan took the cloth by and
to (world, m), kept in the job file while it holds. `plan_release` carries each held cloth along the
rest of that path from wherever the robot stands (by the apex while the gripper has not reached it),
or, when that cannot be planned or the gripper's carry is unknown, lowers it straight down to the
release height where it is; then the grippers open and back out along their fingers and up.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cell.planning.errors import PlanningError
from cell.planning.folds import FoldPlan, GripperAction, PlanStep, PullPlan
from cell.planning.motion import CartesianFailure, MotionPlanner, interpolate_poses

Point = tuple[float, float, float]


@dataclass(frozen=True)
class Carry:
    """Where a closed gripper's plan takes its cloth: by `apex` (None: along the table, a pull) to
    `place`, both TCP positions (world, m)."""

    apex: Point | None
    place: Point


def carry_of(plan: FoldPlan | PullPlan, arm: str, motion: MotionPlanner) -> Carry:
    """The carry of `arm`'s cloth in `plan`: the TCP path of the move after its gripper closes."""
    steps = list(plan.steps)
    closes = [i for i, s in enumerate(steps) if s == GripperAction(arm, "close")]
    if not closes:
        raise PlanningError(f"carry: the plan closes no gripper of arm {arm}")
    move = next((s for s in steps[closes[-1] + 1:] if not isinstance(s, GripperAction)), None)
    if move is None:
        raise PlanningError(f"carry: the plan does not move arm {arm}'s cloth after closing on it")
    tcp = np.array([motion.kin.tcp_pose(q, arm)[:3, 3] for q in move.positions])
    place = _point(tcp[-1])
    return Carry(None if isinstance(plan, PullPlan) else _point(tcp[int(np.argmax(tcp[:, 2]))]), place)


@dataclass(frozen=True)
class ReleasePlan:
    steps: tuple[PlanStep, ...]
    how: str      # what the release does, for the log


def plan_release(motion: MotionPlanner, q: np.ndarray, held: dict[str, Carry | None],
                 table_height: float) -> ReleasePlan:
    """The held cloths carried along their plans' path (or lowered where they are, `table_height`
    being the table top's world z), the grippers of `held` opened, and the arms backed out and up.
    Raises PlanningError when not even the lowering can be planned."""
    g = motion.config.grasp
    q = np.asarray(q, dtype=float)
    here = {arm: motion.kin.tcp_pose(q, arm) for arm in held}
    release_z = table_height + g.release_height
    lowered = {arm: [_at(pose, [pose[0, 3], pose[1, 3], release_z])] for arm, pose in here.items()}
    carried = {arm: lowered[arm] if (carry := held[arm]) is None else _carry_waypoints(pose, carry)
               for arm, pose in here.items()}
    known = any(carry is not None for carry in held.values())
    attempts = [(carried, "carried along its fold's path to the place point")] if known else []
    attempts.append((lowered, "lowered where it is"))
    failures = []
    for waypoints, how in attempts:
        path = motion.cartesian_path(q, _resampled(here, waypoints, g.cartesian_step), True)
        if isinstance(path, CartesianFailure):
            failures.append(f"{how}: arm {path.arm} at waypoint {path.index}: {path.reason}")
            continue
        down = motion.cartesian_move(path, "release-carry", True)
        at_place = {arm: ways[-1] for arm, ways in waypoints.items()}
        back = {arm: [_backed_out(pose, g.retreat_distance, g.retreat_lift)]
                for arm, pose in at_place.items()}
        out = motion.cartesian_path(path[-1], _resampled(at_place, back, g.cartesian_step), True)
        if isinstance(out, CartesianFailure):   # no room to slide the fingers out: straight up
            retreat = motion.lift_move(path[-1])
        else:
            retreat = motion.cartesian_move(out, "release-retreat", True)
        opens = tuple(GripperAction(arm, "open") for arm in held)
        arms = ", ".join(f"{arm} ({'its plan known' if held[arm] is not None else 'no plan known'})"
                         for arm in held)
        return ReleasePlan((down, *opens, retreat), f"cloth in gripper {arms} {how}")
    raise PlanningError("; ".join(failures))


def _carry_waypoints(pose: np.ndarray, carry: Carry) -> list[np.ndarray]:
    """The rest of the carry from the TCP at `pose`: by the apex while it lies ahead (farther from the
    place than the apex is), then to the place; the orientation kept."""
    place = np.array(carry.place)
    ways = []
    if carry.apex is not None:
        apex = np.array(carry.apex)
        if np.linalg.norm(pose[:2, 3] - place[:2]) > np.linalg.norm(apex[:2] - place[:2]):
            ways.append(_at(pose, apex))
    ways.append(_at(pose, place))
    return ways


def _backed_out(pose: np.ndarray, distance: float, lift: float) -> np.ndarray:
    """`pose` moved back against the fingers' direction (the TCP's z on the table) and up: the lower
    finger slides out from under the cloth the way it went in."""
    fingers = pose[:2, 2]
    norm = float(np.linalg.norm(fingers))
    back = -fingers / norm * distance if norm > 1e-6 else np.zeros(2)
    return _at(pose, [pose[0, 3] + back[0], pose[1, 3] + back[1], pose[2, 3] + lift])


def _resampled(start: dict[str, np.ndarray], waypoints: dict[str, list[np.ndarray]],
               step: float) -> dict[str, list[np.ndarray]]:
    """Poses every `step` m from each arm's start through its waypoints, every arm's list as long as
    the longest (a shorter one waits at its points)."""
    targets = {}
    for arm, ways in waypoints.items():
        poses, previous = [], start[arm]
        for way in ways:
            poses += interpolate_poses(previous, way, step)
            previous = way
        targets[arm] = poses
    n = max(len(poses) for poses in targets.values())
    return {arm: [poses[min(len(poses) - 1, round(i * (len(poses) - 1) / max(n - 1, 1)))] for i in range(n)]
            for arm, poses in targets.items()}


def _at(pose: np.ndarray, position) -> np.ndarray:
    moved = pose.copy()
    moved[:3, 3] = position
    return moved


def _point(xyz: np.ndarray) -> Point:
    return float(xyz[0]), float(xyz[1]), float(xyz[2])


__all__ = ["Carry", "ReleasePlan", "carry_of", "plan_release"]
