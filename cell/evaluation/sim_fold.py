"""One fold of the recipe in the simulated world, along the planner's own path: how a path's apex
height (lift fraction) and speed change where the cloth lands.

The planner plans the fold from the garment's true landmarks; its trajectories are played into the
world as the controller would move the arms (the TCPs by forward kinematics of the planned joint
positions, in robot time), the grippers close and open where the plan says, and the world's cloth
follows. No processes and no wire: the same world the camera process runs, driven directly.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from cell.evaluation.ideal_fold import ideal_fold_iou
from cell.planning.folds import FoldPlan, FoldPlanner, GripperAction, load_recipe
from drivers.robot.config import load_robot_config
from drivers.robot.kinematics import CellKinematics
from drivers.sim.geometry import FoldLine
from drivers.sim.world import GarmentWorld

IOU_RESOLUTION_M = 0.001   # raster of the recipe's score (m), as `foldcell demo` scores


@dataclass(frozen=True)
class SimFoldResult:
    category: str
    seed: int
    fold: str
    lift_fraction: float
    speed: float                       # the planned timing's speed factor
    release_height: float              # m above the table where the grippers opened
    iou: float                         # the cloth's silhouette against the ideal fold
    place_errors: dict[str, float]     # m per arm: the cloth it held, from its ideal place (the reflection
                                       # of where it lay flat), on average
    crease_offset: float               # m: the crease short of the fold line (< 0: beyond it)
    corner_errors: dict[str, float]    # m: grasped landmark's vertex to its ideal place (the reflection);
                                       # a corner beyond the fingers may flop
    grasped: dict[str, bool]           # arm -> took cloth
    robot_time: float                  # s of the fold's motion
    wall_time: float                   # s to plan and simulate

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def run_first_fold(category: str, seed: int, lift_fraction: float | None = None, speed: float = 1.0,
                   planner: FoldPlanner | None = None, joint_state_period: float | None = None,
                   catch_up_period: float | None = None,
                   release_height: float | None = None, gripper_delay: float = 0.0) -> SimFoldResult:
    """The recipe's first fold of the garment of `seed` in the physics world; `lift_fraction`
    overrides the recipe's apex, `speed` scales the planned timing (2: twice as fast),
    `release_height` (m above the table) where the grippers open (default: config/planning.yaml's).
    `joint_state_period` (s of robot time): the world hears the joint states this often, as the
    camera process hears a controller's stream (None: at the planned points); `catch_up_period`:
    it is looked at (simulates what it heard) this often, as the camera process does (None: once,
    at the end). `gripper_delay` (s of robot time): the grippers' stream comes this much later than
    the joint states, as it may on a loaded machine."""
    if not speed > 0.0:
        raise ValueError(f"speed: must be positive, got {speed!r}")
    if joint_state_period is not None and not joint_state_period > 0.0:
        raise ValueError(f"joint_state_period: must be positive, got {joint_state_period!r}")
    if not gripper_delay >= 0.0:
        raise ValueError(f"gripper_delay: must be zero or positive, got {gripper_delay!r}")
    started = time.perf_counter()
    recipe = load_recipe(category)
    first = recipe.folds[0]
    if lift_fraction is not None:
        if not 0.0 <= lift_fraction <= 2.0:
            raise ValueError(f"lift_fraction: must be within 0..2, got {lift_fraction!r}")
        first = dataclasses.replace(first, lift_fraction=lift_fraction)
        recipe = dataclasses.replace(recipe, folds=(first, *recipe.folds[1:]))
    base = planner or FoldPlanner()
    motion = base.motion
    if release_height is not None:
        if not 0.0 <= release_height <= 0.3:
            raise ValueError(f"release_height: must be within 0..0.3 m, got {release_height!r}")
        motion = copy.copy(motion)
        motion.config = dataclasses.replace(
            motion.config, grasp=dataclasses.replace(motion.config.grasp, release_height=release_height))
    planner = FoldPlanner(motion, base.table, recipes={category: recipe})
    world = GarmentWorld(seed=seed, category=category, folding="physics")
    robot = load_robot_config()
    landmarks = {name: (float(x), float(y)) for name, (x, y) in world.truth_landmarks().items()}
    plan = planner.plan_fold(category, 0, landmarks, np.asarray(robot.home, dtype=float),
                             include_perceive=False)
    player = _Player(world, CellKinematics(robot), speed, joint_state_period, catch_up_period, gripper_delay)
    player.play(plan, np.asarray(robot.home, dtype=float))
    world.catch_up()
    iou = world.silhouette_iou([[(np.asarray(g), np.asarray(p))
                                 for g, p in zip(plan.grasp_points, plan.place_points, strict=True)]])
    vertices = world.landmark_vertices()
    flat = dict(zip(*world.flat_polygon(), strict=True))
    line = plan.fold_line
    normal = np.asarray(line.normal) / np.linalg.norm(line.normal)   # towards the side that stays
    mirror = FoldLine(np.asarray(line.point, dtype=float), normal)
    errors = {name: float(np.linalg.norm(vertices[name][:2] - mirror.reflect(flat[name])[0]))
              for name in first.grasp}
    grasped = {result.arm: result.grasped for result in world.grasp_results()}
    assert world.cloth is not None
    cloth = world.cloth.vertices
    flat_mesh = world.cloth.mesh.points
    place_errors = {}
    for pinch in world.cloth.pinch_log:
        if pinch.vertices:
            held = list(pinch.vertices)
            ideal = mirror.reflect(flat_mesh[held])
            place_errors[pinch.arm] = float(np.linalg.norm(cloth[held, :2] - ideal, axis=1).mean())
    crease_offset = float(np.min((cloth[:, :2] - np.asarray(line.point)) @ normal))
    return SimFoldResult(category, seed, first.name, first.lift_fraction, speed,
                         planner.config.grasp.release_height, iou, place_errors,
                         crease_offset, errors, grasped, plan.robot_time / speed,
                         time.perf_counter() - started)


@dataclass(frozen=True)
class SimRecipeResult:
    category: str
    seed: int
    folds: tuple[str, ...]
    ious: tuple[float, ...]            # after each fold, against the perfect folds of the recipe so far
    robot_time: float                  # s
    wall_time: float                   # s

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def run_recipe(category: str, seed: int, planner: FoldPlanner | None = None,
               resolution: float = IOU_RESOLUTION_M) -> SimRecipeResult:
    """Every fold of the recipe in the physics world, each planned from the true landmarks as they
    are after the folds before (perfect perception: what is left is the cloth's doing), scored after
    each fold against the ideal folds (`cell.evaluation.ideal_fold`, as the demo scores)."""
    started = time.perf_counter()
    planner = planner or FoldPlanner()
    recipe = planner.recipe(category)
    world = GarmentWorld(seed=seed, category=category, folding="physics")
    robot = load_robot_config()
    flat = dict(zip(*world.flat_polygon(), strict=True))
    player = _Player(world, CellKinematics(robot), 1.0, None, None)
    q = np.asarray(robot.home, dtype=float)
    ious = []
    for index in range(len(recipe.folds)):
        landmarks = {name: (float(x), float(y)) for name, (x, y) in world.truth_landmarks().items()}
        plan = planner.plan_fold(category, index, landmarks, q, include_perceive=False)
        q = player.play(plan, q)
        world.catch_up()
        ious.append(ideal_fold_iou(category, flat, world.garment.outline, index + 1, [world.silhouette()],
                                   resolution))
    return SimRecipeResult(category, seed, tuple(fold.name for fold in recipe.folds), tuple(ious),
                           player.clock, time.perf_counter() - started)


class _Player:
    """Plays planned steps into the world as the controller and the camera process would: the
    grippers' events at their times, the joint states (every `joint_state_period` s, or at the planned
    points) as TCP positions by forward kinematics, the grippers' stream (events, and every gripper's
    state heard at each joint state) `gripper_delay` s behind the joint states, the world simulating
    what it heard every `catch_up_period` s (or when asked)."""

    def __init__(self, world: GarmentWorld, kinematics: CellKinematics, speed: float,
                 joint_state_period: float | None, catch_up_period: float | None, gripper_delay: float = 0.0):
        self.world, self.kinematics = world, kinematics
        self.speed, self.joint_state_period, self.catch_up_period = speed, joint_state_period, catch_up_period
        self.gripper_delay = gripper_delay
        self.gripper_stream: list[tuple[float, Callable[[], object]]] = []   # (robot time, delivery)
        self.clock = self.looked_at = 0.0

    def play(self, plan: FoldPlan, q: np.ndarray) -> np.ndarray:
        """Play `plan` from joints `q`; the joints at its end."""
        for step in plan.steps:
            if isinstance(step, GripperAction):
                tcp = self.kinematics.tcp_pose(q, step.arm)[:3, 3]
                self._send_gripper(self.clock, functools.partial(
                    self.world.gripper_event, step.arm, step.action == "close", tcp, robot_time=self.clock))
                continue
            times = np.asarray(step.times, dtype=float) / self.speed
            positions_at = np.asarray(step.positions, dtype=float)
            if self.joint_state_period is not None:
                heard = np.append(np.arange(0.0, times[-1], self.joint_state_period), times[-1])
                positions_at = np.column_stack([np.interp(heard, times, joint) for joint in positions_at.T])
                times = heard
            for at, positions in zip(times, positions_at, strict=True):
                q = positions
                now = self.clock + float(at)
                tcps = self.kinematics.tcp_poses(q)
                self.world.gripper_motion(now, {arm: pose[:3, 3] for arm, pose in tcps.items()})
                for arm in tcps:
                    self._send_gripper(now, functools.partial(self.world.gripper_heard, arm, now))
                self._deliver(now - self.gripper_delay)
                if self.catch_up_period is not None and now >= self.looked_at + self.catch_up_period:
                    self.world.catch_up()
                    self.looked_at = now
            self.clock += float(times[-1])
        self._deliver(math.inf)
        return q

    def _send_gripper(self, when: float, delivery: Callable[[], object]) -> None:
        self.gripper_stream.append((when, delivery))
        self._deliver(self.clock - self.gripper_delay if self.gripper_delay else math.inf)

    def _deliver(self, until: float) -> None:
        """Deliver the grippers' stream, in order, up to robot time `until`."""
        while self.gripper_stream and self.gripper_stream[0][0] <= until:
            self.gripper_stream.pop(0)[1]()
