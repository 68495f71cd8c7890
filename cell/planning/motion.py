"""Motion planning for the cell: free moves (straight if free, else OMPL RRT-Connect in joint space
over both arms and the turn-table, simplified) and Cartesian moves by dense IK interpolation.

Everything works on 13-joint vectors in project order. `MotionPlanner` caches the model, the
collision objects and the IK solver; build it once (`default_motion_planner()`) and reuse it.
"""

from __future__ import annotations

import atexit
import gc
import itertools
import logging
import math
import weakref
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from cell.planning.collision import CollisionChecker
from cell.planning.config import PlanningConfig, default_planning_config
from cell.planning.errors import InvalidTrajectory, PlanningError
from cell.planning.ik import IkSolver
from cell.planning.trajectory import Limits, PlannedTrajectory, path_trajectory, ptp_trajectory
from drivers.controller.acceptance import check_trajectory
from drivers.controller.config import ControllerConfig, default_controller_config
from drivers.robot.kinematics import CellKinematics, default_kinematics

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CartesianFailure:
    """Why a Cartesian path failed: index of the waypoint, arm, reason."""

    index: int
    arm: str
    reason: str


class MotionPlanner:
    """Free and Cartesian motions of the whole cell. Not thread-safe (shared pinocchio data)."""

    def __init__(self, config: PlanningConfig | None = None, kin: CellKinematics | None = None,
                 controller_config: ControllerConfig | None = None):
        self.config = config or default_planning_config()
        self.kin = kin or default_kinematics()
        self.robot = self.kin.robot
        # the rules every trajectory must pass (config/controller.yaml): acceptance, points, tick
        self.controller_config = controller_config or default_controller_config()
        self.ik = IkSolver(self.kin, self.config.ik)
        self.collision = CollisionChecker(self.kin, self.config.collision)
        self.limits = Limits(self.robot, self.config.trajectory, self.controller_config)
        self.n = len(self.robot.joint_names)
        self.arm_indices = {a.name: np.array(self.robot.group_indices(a.group)) for a in self.robot.arms}
        self.ext_index = self.robot.index("ext_axis")
        self.perceive = np.array(self.config.motion.perceive)
        self._ompl: tuple[Any, ...] | None = None  # OMPL's objects, made on the first RRT-Connect

    # --- checks -----------------------------------------------------------------------------
    def within_limits(self, q: np.ndarray) -> bool:
        return bool(np.all(q >= self.robot.lower) and np.all(q <= self.robot.upper))

    def valid(self, q: np.ndarray, allow_finger_contact: bool = False) -> bool:
        return self.within_limits(q) and not self.collision.in_collision(q, allow_finger_contact)

    def segment_free(self, q0: np.ndarray, q1: np.ndarray, allow_finger_contact: bool = False) -> bool:
        """Straight joint-space segment checked every `check_step` rad."""
        steps = int(np.ceil(np.max(np.abs(q1 - q0)) / self.config.motion.check_step))
        for k in range(1, steps + 1):
            if self.collision.in_collision(q0 + (q1 - q0) * (k / steps), allow_finger_contact):
                return False
        return True

    def validate(self, traj: PlannedTrajectory, current: np.ndarray, period: float | None = None) -> None:
        """The controller's acceptance rules (`InvalidTrajectory` with the controller's reply), then
        collisions along the controller's interpolation, sampled every `period` s (default:
        motion.check_period; `PlanningError`)."""
        reply = check_trajectory(traj, np.asarray(current, dtype=float), self.robot, self.controller_config)
        if not reply.ok:
            raise InvalidTrajectory(f"segment {traj.label!r} would be rejected by the controller: "
                                    f"{reply.text}")
        for q in traj.dense_positions(period or self.config.motion.check_period):
            if self.collision.in_collision(q, traj.allow_finger_contact):
                pairs = self.collision.colliding_pairs(q, traj.allow_finger_contact)
                raise PlanningError(f"segment {traj.label!r} collides: {pairs[:3]}")

    # --- free moves -------------------------------------------------------------------------
    def free_path(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
        """Collision-free joint waypoints (M, 13) from q0 to q1: straight if free, else RRT-Connect."""
        q0 = np.asarray(q0, dtype=float)
        q1 = np.asarray(q1, dtype=float)
        if not self.valid(q1):
            raise PlanningError(f"goal configuration is not valid: {self.collision.colliding_pairs(q1)[:3]}")
        if not self.valid(q0):
            raise PlanningError(f"start configuration is outside the limits or in collision: "
                                f"{self.collision.colliding_pairs(q0)[:3]}; move the robot clear first")
        if self.segment_free(q0, q1):
            return np.vstack([q0, q1])
        # cheap detours before RRT-Connect: swing (S axes and turn-table) first, or last
        swing = np.concatenate([self.arm_indices[a][:1] for a in self.arm_indices] + [[self.ext_index]])
        swing_first = q0.copy()
        swing_first[swing] = q1[swing]
        swing_last = q1.copy()
        swing_last[swing] = q0[swing]
        for via in (swing_first, swing_last):
            if self.valid(via) and self.segment_free(q0, via) and self.segment_free(via, q1):
                return np.vstack([q0, via, q1])
        return self.rrt_connect(q0, q1)

    def _setup_ompl(self) -> tuple[Any, ...]:
        from ompl import base as ob
        from ompl import geometric as og
        from ompl import util as ou
        ou.setLogLevel(ou.LogLevel.LOG_WARN)
        space = ob.RealVectorStateSpace(self.n)
        bounds = ob.RealVectorBounds(self.n)
        for i in range(self.n):
            bounds.setLow(i, float(self.robot.lower[i]))
            bounds.setHigh(i, float(self.robot.upper[i]))
        space.setBounds(bounds)
        ss = og.SimpleSetup(space)
        n = self.n
        coll = self.collision

        def is_valid(state) -> bool:
            return not coll.in_collision(np.fromiter((state[i] for i in range(n)), float, n))

        ss.setStateValidityChecker(is_valid)
        si = ss.getSpaceInformation()
        extent = float(np.linalg.norm(self.robot.upper - self.robot.lower))
        # OMPL checks motions more coarsely; our own re-check at check_step follows (fast C++ tree search
        # with Python callbacks is dominated by the number of checks)
        si.setStateValidityCheckingResolution(self.config.motion.rrt_check_step / extent)
        planner = og.RRTConnect(si)
        planner.setRange(self.config.motion.rrt_range)
        ss.setPlanner(planner)
        self._ompl = (ob, og, space, ss, is_valid)
        # drop the OMPL objects before interpreter shutdown (nanobind otherwise reports them as leaks)
        atexit.register(_drop_ompl, weakref.ref(self))
        return self._ompl

    def rrt_connect(self, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
        """RRT-Connect in the 13-D joint space, simplified; every straight piece re-checked with our
        own resolution (a path failing it is planned again, `motion.rrt_attempts` times)."""
        _, _, space, ss, _ = self._ompl or self._setup_ompl()
        start, goal = space.allocState(), space.allocState()
        for i in range(self.n):
            start[i] = float(q0[i])
            goal[i] = float(q1[i])
        for _ in range(self.config.motion.rrt_attempts + 1):
            ss.clear()
            ss.setStartAndGoalStates(start, goal)
            status = ss.solve(self.config.motion.rrt_time_limit)
            if not ss.haveExactSolutionPath():
                raise PlanningError(
                    f"RRT-Connect found no free path in {self.config.motion.rrt_time_limit} s ({status})")
            if self.config.motion.simplify:
                ss.simplifySolution()
            path = ss.getSolutionPath()
            wps = np.array([[path.getState(k)[i] for i in range(self.n)]
                            for k in range(path.getStateCount())])
            wps[0], wps[-1] = q0, q1
            if all(self.segment_free(a, b) for a, b in itertools.pairwise(wps)):
                return wps
            log.debug("RRT-Connect path failed the dense re-check, planning again")
        raise PlanningError("RRT-Connect paths kept failing the dense re-check")

    def free_move(self, q0: np.ndarray, q1: np.ndarray, label: str = "free") -> PlannedTrajectory:
        """A validated, time-parameterised free move from q0 to q1. The result is checked at the
        controller's interpolation tick; a path that grazes an obstacle between the planner's checks
        is replaced by a new RRT-Connect path (a few attempts)."""
        wps = self.free_path(q0, q1)
        attempts = self.config.motion.rrt_attempts
        for attempt in range(attempts + 1):
            traj = ptp_trajectory(wps, self.limits, label)
            try:
                self.validate(traj, q0, self.controller_config.interpolation_period)
                return traj
            except PlanningError:
                if attempt == attempts:
                    raise
                log.debug("free move %s failed the dense check, re-planning", label)
                wps = self.rrt_connect(q0, q1)
        raise AssertionError("unreachable")

    def perceive_move(self, q0: np.ndarray) -> PlannedTrajectory:
        """Free move to the perceiving configuration (arms clear of the table and the camera view);
        the turn-table keeps its angle."""
        goal = self.perceive.copy()
        goal[self.ext_index] = q0[self.ext_index]
        return self.free_move(q0, goal, "perceive")

    def lift_move(self, q0: np.ndarray) -> PlannedTrajectory:
        """Both TCPs straight up by the retreat lift, fingers allowed on the table at the start: the
        way out of a fold that stopped half way, before any free move."""
        step = self.config.grasp.cartesian_step
        targets = {}
        for arm, start in self.kin.tcp_poses(q0).items():
            end = start.copy()
            end[2, 3] += self.config.grasp.retreat_lift
            targets[arm] = interpolate_poses(start, end, step)
        path = self.cartesian_path(q0, targets, allow_finger_contact=True)
        if isinstance(path, CartesianFailure):
            raise PlanningError(f"lift: arm {path.arm} at waypoint {path.index}: {path.reason}")
        return self.cartesian_move(path, "lift", True)

    # --- Cartesian moves --------------------------------------------------------------------
    def cartesian_path(self, q0: np.ndarray, targets: dict[str, list[np.ndarray]],
                       allow_finger_contact: bool) -> np.ndarray | CartesianFailure:
        """Dense IK along TCP poses (per arm a list of 4x4, all lists the same length), starting at q0.
        Returns the joint path (N, 13) or the first failure."""
        lengths = {len(v) for v in targets.values()}
        if len(lengths) != 1:
            raise ValueError("targets: every arm needs the same number of poses")
        max_step = self.config.grasp.max_joint_step
        path = [np.asarray(q0, dtype=float)]
        q = path[0].copy()
        for k in range(lengths.pop()):
            for arm, poses in targets.items():
                r = self.ik.solve(arm, poses[k], q)
                if not r.success:
                    return CartesianFailure(k, arm, "no IK solution (out of reach or at a joint limit)")
                idx = self.arm_indices[arm]
                if np.max(np.abs(r.q[idx] - q[idx])) > max_step:
                    return CartesianFailure(k, arm, "IK jumps between neighbouring points (discontinuity)")
                q = r.q
            if self.collision.in_collision(q, allow_finger_contact):
                pairs = self.collision.colliding_pairs(q, allow_finger_contact)
                who = f"{pairs[0][0]} with {pairs[0][1]}" if pairs else "unknown shapes"
                return CartesianFailure(k, next(iter(targets)), f"collision: {who}")
            path.append(q.copy())
        return np.array(path)

    def cartesian_move(self, path: np.ndarray, label: str, allow_finger_contact: bool) -> PlannedTrajectory:
        traj = path_trajectory(path, self.limits, label, allow_finger_contact)
        self.validate(traj, path[0])
        return traj


def _drop_ompl(ref: weakref.ref) -> None:
    planner = ref()
    if planner is not None:
        planner._ompl = None
        gc.collect()


def interpolate_poses(a: np.ndarray, b: np.ndarray, step: float) -> list[np.ndarray]:
    """Poses from a (excluded) to b (included) every `step` m; orientation of b throughout is
    assumed equal to a's (the fold keeps the gripper orientation)."""
    d = float(np.linalg.norm(b[:3, 3] - a[:3, 3]))
    # rounded first: a lift of 8 steps measured as 8.000000000000002 is 8 steps for every arm
    n = max(1, math.ceil(round(d / step, 9)))
    out = []
    for k in range(1, n + 1):
        T = b.copy()
        T[:3, 3] = a[:3, 3] + (b[:3, 3] - a[:3, 3]) * (k / n)
        out.append(T)
    return out


@lru_cache(maxsize=1)
def default_motion_planner() -> MotionPlanner:
    return MotionPlanner()


__all__ = ["CartesianFailure", "MotionPlanner", "default_motion_planner", "interpolate_poses"]
