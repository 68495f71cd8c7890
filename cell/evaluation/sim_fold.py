"""One fold of the recipe in the simulated world, along the planner's own path: how a path's apex
height (lift fraction) and speed change where the cloth lands.

The planner plans the fold from the garment's true landmarks; its trajectories are played into the
world as the controller would move the arms (`drivers.sim.player`: the controller's interpolation,
the TCPs by forward kinematics, in robot time), the grippers close and open where the plan says, and
the world's cloth follows. No processes and no wire: the same world the camera process runs, driven directly.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from cell.evaluation.fold_success import (
    FoldScore,
    SuccessCriteria,
    load_success_criteria,
    score_fold,
    score_recipe,
    unreachable,
)
from cell.evaluation.ideal_fold import IdealFold, ideal_fold_iou, ideal_folds
from cell.planning.errors import Unreachable
from cell.planning.folds import FoldPlan, FoldPlanner, GripperAction, PullPlan, fold_moves, load_recipe
from drivers.common.plane import signed_area
from drivers.robot.config import load_robot_config
from drivers.robot.kinematics import CellKinematics
from drivers.sim.player import TrajectoryPlayer
from drivers.sim.world import GarmentWorld

IOU_RESOLUTION_M = 0.001   # raster of the recipe's score (m), as `foldcell demo` scores


@dataclass(frozen=True)
class SimFoldResult:
    category: str
    seed: int
    fold: str
    lift_fraction: float
    crease_allowance: float            # m the grasped points were laid beyond their mirror points
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
    physics_wall_time: float           # s of that spent simulating the cloth
    score: FoldScore                   # the fold-success measure (`cell.evaluation.fold_success`)

    def as_dict(self) -> dict:
        out = {k: v for k, v in dataclasses.asdict(self).items() if k != "score"}
        return {**_measure_dict(self.score), **out}


def _measure_dict(score: FoldScore) -> dict:
    """The measure's figures first (what a script reads), the IoU beside them in the result."""
    figures = score.as_dict()
    return {"success": figures.pop("success"), "cause": figures.pop("cause"), **figures}


def landmark_state(world: GarmentWorld) -> tuple[dict[str, np.ndarray], float]:
    """The true landmarks (xy, m, named as the cell names the flat garment) and the top-view area (m²)."""
    landmarks = {name: point[:2].copy() for name, point in world.landmark_vertices().items()}
    return landmarks, abs(signed_area(world.silhouette()))


def took_cloth(world: GarmentWorld, since: int) -> dict[str, bool]:
    """Per arm, whether its grippers' closings after the first `since` took cloth."""
    took: dict[str, bool] = {}
    for result in world.grasp_results()[since:]:
        took[result.arm] = took.get(result.arm, False) or result.grasped
    return took


def run_first_fold(category: str, seed: int, lift_fraction: float | None = None, speed: float = 1.0,
                   planner: FoldPlanner | None = None, joint_state_period: float | None = None,
                   catch_up_period: float | None = None,
                   release_height: float | None = None, gripper_delay: float = 0.0,
                   crease_allowance: float | None = None) -> SimFoldResult:
    """The recipe's first fold of the garment of `seed` in the physics world; `lift_fraction`
    overrides the recipe's apex and `crease_allowance` (m) how far beyond their mirror points the
    grasped points are laid, `speed` scales the planned timing (2: twice as fast),
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
    if crease_allowance is not None:
        if not 0.0 <= crease_allowance <= 0.1:
            raise ValueError(f"crease_allowance: must be within 0..0.1 m, got {crease_allowance!r}")
        first = dataclasses.replace(first, crease_allowance=crease_allowance)
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
    flat = dict(zip(*world.flat_polygon(), strict=True))
    before, _ = landmark_state(world)
    player = TrajectoryPlayer(world, CellKinematics(robot), speed, joint_state_period, catch_up_period,
                              gripper_delay)
    simulating = time.perf_counter()
    _play(player, plan, np.asarray(robot.home, dtype=float))
    world.catch_up()
    physics_wall_time = time.perf_counter() - simulating
    after, area = landmark_state(world)
    score = score_fold(category, flat, world.garment.outline, 0, before, after, area,
                       load_success_criteria(), took_cloth(world, 0))
    iou = world.silhouette_iou([[(np.asarray(g), np.asarray(p))
                                 for g, p in zip(plan.grasp_points, plan.place_points, strict=True)]])
    vertices = world.landmark_vertices()
    mirror = plan.fold_line
    errors = {name: float(np.linalg.norm(vertices[name][:2] - mirror.reflect(flat[name])[0]))
              for name in first.held}
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
    crease_offset = -float(np.max(mirror.side(cloth[:, :2])))   # the cloth's reach to the moving side
    return SimFoldResult(category, seed, first.name, first.lift_fraction, first.crease_allowance, speed,
                         planner.config.grasp.release_height, iou, place_errors,
                         crease_offset, errors, grasped, plan.robot_time / speed,
                         time.perf_counter() - started, physics_wall_time, score)


@dataclass(frozen=True)
class SimRecipeResult:
    category: str
    seed: int
    hands: str                         # "planner": the cell's paths; "oracle": grippers placed exactly
    folds: tuple[str, ...]
    ious: tuple[float, ...]            # after each fold, against the perfect folds of the recipe so far
    scores: tuple[FoldScore, ...]      # the fold-success measure after each fold done (or the one that
                                       # could not be planned)
    recipe: FoldScore | None           # after the whole recipe (None: a fold was unreachable)
    robot_time: float                  # s
    wall_time: float                   # s
    pulls: tuple[PullPlan, ...] = ()   # the garment pulled into reach before a fold

    @property
    def success(self) -> bool:
        return self.recipe is not None and self.recipe.success and all(s.success for s in self.scores)

    @property
    def cause(self) -> str | None:
        """The first miss's cause (None: a success)."""
        for score in (*self.scores, *((self.recipe,) if self.recipe else ())):
            if not score.success:
                return score.cause
        return None

    def as_dict(self) -> dict:
        return {
            "category": self.category, "seed": self.seed, "hands": self.hands, "success": self.success,
            "cause": self.cause, "folds": list(self.folds), "ious": [round(i, 4) for i in self.ious],
            "per_fold": [_measure_dict(s) for s in self.scores],
            "recipe": _measure_dict(self.recipe) if self.recipe else None,
            "robot_time": round(self.robot_time, 2), "wall_time": round(self.wall_time, 2),
            "pulls": [{"before_fold": p.fold_index + 1, "offset_m": [round(v, 4) for v in p.offset],
                       "why": p.why} for p in self.pulls],
        }


def run_recipe(category: str, seed: int, planner: FoldPlanner | None = None,
               resolution: float = IOU_RESOLUTION_M, oracle: bool = False,
               criteria: SuccessCriteria | None = None, world: GarmentWorld | None = None) -> SimRecipeResult:
    """Every fold of the recipe in the physics world, scored after each fold by the fold-success
    measure and the IoU against the perfect folds so far (as the demo scores). `world`: a scene laid
    by the caller (default: the cell's scene of `seed`, in the physics world).

    The planner's hands (default): each fold planned from the true landmarks as they are after the
    folds before (perfect perception: what is left is the planner's and the cloth's doing), played as
    the controller moves the arms; a fold out of reach is preceded by a pull into reach, as the cell
    does (`FoldPlanner.plan_pull`). The oracle's (`oracle`): no robot and no planner, the grippers
    close exactly on the true landmarks the recipe holds and carry them along an arc to their places
    across the ideal fold line (laid the recipe's crease allowance beyond, as the planner lays them):
    what the cloth and the measure allow at best."""
    started = time.perf_counter()
    criteria = criteria or load_success_criteria()
    planner = planner or FoldPlanner()
    recipe = planner.recipe(category)
    world = world or GarmentWorld(seed=seed, category=category, folding="physics")
    robot = load_robot_config()
    flat = dict(zip(*world.flat_polygon(), strict=True))
    outline = world.garment.outline
    player = TrajectoryPlayer(world, CellKinematics(robot))
    hands = OracleHands(world, tuple(arm.name for arm in robot.arms), planner.config.grasp.height,
                         planner.config.grasp.release_height)
    q = np.asarray(robot.home, dtype=float)
    ious: list[float] = []
    scores: list[FoldScore] = []
    pulls: list[PullPlan] = []
    for index, spec in enumerate(recipe.folds):
        if not oracle:
            try:
                plan, q, flat, outline = _plan_in_reach(planner, player, world, category, index, q, flat,
                                                        outline, pulls)
            except Unreachable as exc:
                scores.append(unreachable(index + 1, str(exc)))
                break
        before, _ = landmark_state(world)
        closings = len(world.grasp_results())
        landmarks = {name: (float(x), float(y)) for name, (x, y) in world.truth_landmarks().items()}
        if oracle:
            # where the recipe holds (its points on the garment as folded so far), placed across the
            # ideal line rather than where the planner would
            grasps, _ = fold_moves(landmarks, spec)
            hands.fold(ideal_folds(category, flat)[index], grasps, spec.lift_fraction,
                       short_m=-spec.crease_allowance)
        else:
            q = _play(player, plan, q)
        world.catch_up()
        after, area = landmark_state(world)
        scores.append(score_fold(category, flat, outline, index, before, after, area, criteria,
                                 took_cloth(world, closings)))
        ious.append(ideal_fold_iou(category, flat, outline, index + 1, [world.silhouette()], resolution))
    whole = None
    if len(ious) == len(recipe.folds):
        after, area = landmark_state(world)
        whole = score_recipe(category, flat, outline, after, area, criteria)
    return SimRecipeResult(category, seed, "oracle" if oracle else "planner",
                           tuple(fold.name for fold in recipe.folds), tuple(ious), tuple(scores), whole,
                           hands.clock if oracle else player.clock, time.perf_counter() - started,
                           tuple(pulls))


def _plan_in_reach(planner: FoldPlanner, player: TrajectoryPlayer, world: GarmentWorld, category: str,
                   index: int, q: np.ndarray, flat: dict[str, np.ndarray], outline: np.ndarray,
                   pulls: list[PullPlan]) -> tuple[FoldPlan, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """Fold `index` planned as the cell plans it from the true landmarks, the garment pulled nearer
    first where the cell would (`FoldPlanner.plan_fold_or_pull`; raises Unreachable when no pull helps
    either). The measure's flat garment moves with it (a pull slides the garment, it does not fold it)."""
    while True:
        landmarks = {name: (float(x), float(y)) for name, (x, y) in world.truth_landmarks().items()}
        pulls_done = sum(pull.fold_index == index for pull in pulls)
        plan = planner.plan_fold_or_pull(category, index, landmarks, q, pulls_done, include_perceive=False)
        if isinstance(plan, FoldPlan):
            return plan, q, flat, outline
        q = _play(player, plan, q)
        world.catch_up()
        flat = dict(zip(*world.flat_polygon(), strict=True))    # the world moved it with the garment
        outline = world.garment.outline
        pulls.append(plan)


class OracleHands:
    """Grippers with no arm behind them, placed exactly: each closes on a point, rises along a
    half-sine arc (apex `lift_fraction` of the way) to the point's mirror image across the fold
    line and opens there. The arms the fold does not use wait high above the table."""

    SPEED = 0.15          # m/s along the way, about the planner's pace at a fold's middle
    MIN_DURATION = 1.0    # s
    PERIOD = 0.01         # s between recorded positions
    PARKED_HEIGHT = 0.5   # m above the table

    def __init__(self, world: GarmentWorld, arms: Sequence[str], grasp_height: float, release_height: float):
        self.world, self.arms = world, tuple(arms)
        self.grasp_height, self.release_height = grasp_height, release_height
        self.clock = 0.0

    def fold(self, line: IdealFold, grasps: np.ndarray, lift_fraction: float, short_m: float = 0.0,
             release_share: float = 1.0) -> None:
        """Carry `grasps` (k, 2; table frame, m) to their mirror images across `line`: laid `short_m`
        short of them (back towards the grasp), let go at `release_share` of the way (1: at the end)."""
        if len(grasps) > len(self.arms):
            raise ValueError(f"grasps: {len(grasps)} points for {len(self.arms)} grippers")
        if not 0.0 < release_share <= 1.0:
            raise ValueError(f"release_share: must be in (0, 1], got {release_share!r}")
        starts = np.array(grasps, dtype=float)
        mirrors = line.line.reflect(starts)
        way = mirrors - starts
        ends = mirrors - short_m * way / np.linalg.norm(way, axis=1, keepdims=True)
        length = float(np.max(np.linalg.norm(ends - starts, axis=1)))
        duration = max(self.MIN_DURATION, length / self.SPEED)
        t0 = self.clock + self.PERIOD
        used = self.arms[:len(starts)]
        self._move(t0, starts, self.grasp_height)
        for arm, start in zip(used, starts, strict=True):
            self._event(arm, True, start, self.grasp_height, t0)
        xy, height = starts, self.grasp_height + np.zeros(len(starts))
        for u in np.linspace(0.0, 1.0, int(duration / self.PERIOD) + 1)[1:]:
            share = 0.5 - 0.5 * math.cos(math.pi * u)      # rest to rest
            xy = starts + share * (ends - starts)
            lift = lift_fraction * np.linalg.norm(ends - starts, axis=1) * math.sin(math.pi * share)
            height = self.grasp_height + (self.release_height - self.grasp_height) * share + lift
            self._move(t0 + u * duration, xy, height)
            if u >= release_share:
                break
        t1 = t0 + u * duration + self.PERIOD
        self._move(t1, xy, height)
        for arm, point, h in zip(used, xy, height, strict=True):
            self._event(arm, False, point, float(h), t1)
        self.clock = t1 + self.PERIOD
        self._move(self.clock, xy, height + self.PARKED_HEIGHT)

    def slide(self, xy: np.ndarray, offset: np.ndarray, duration: float = 1.0) -> None:
        """Close one gripper on the cloth at `xy` and slide it `offset` (m) along the table: a drag."""
        start, shift = np.asarray(xy, dtype=float), np.asarray(offset, dtype=float)
        t0 = self.clock + self.PERIOD
        self._move(t0, start[None], self.grasp_height)
        self._event(self.arms[0], True, start, self.grasp_height, t0)
        for u in np.linspace(0.0, 1.0, int(duration / self.PERIOD) + 1)[1:]:
            self._move(t0 + u * duration, (start + u * shift)[None], self.grasp_height)
        t1 = t0 + duration + self.PERIOD
        self._event(self.arms[0], False, start + shift, self.grasp_height, t1)
        self.clock = t1 + self.PERIOD
        self._move(self.clock, (start + shift)[None], self.grasp_height + self.PARKED_HEIGHT)

    def _world_point(self, xy: np.ndarray, height: float) -> np.ndarray:
        return self.world.table.table_to_world(xy)[0] + np.array([0.0, 0.0, height])

    def _move(self, when: float, xy: np.ndarray, height: float | np.ndarray) -> None:
        heights = np.broadcast_to(np.asarray(height, dtype=float), (len(xy),))
        positions = {arm: self._world_point(np.array([0.0, 0.0]), self.PARKED_HEIGHT) for arm in self.arms}
        for arm, point, h in zip(self.arms, xy, heights, strict=False):
            positions[arm] = self._world_point(point, float(h))
        self.world.gripper_motion(when, positions)
        for arm in self.arms:
            self.world.gripper_heard(arm, when)

    def _event(self, arm: str, closed: bool, xy: np.ndarray, height: float, when: float) -> None:
        self.world.gripper_event(arm, closed, self._world_point(xy, height), robot_time=when)


def _play(player: TrajectoryPlayer, plan: FoldPlan | PullPlan, q: np.ndarray) -> np.ndarray:
    """Play `plan`'s steps from joints `q`; the joints at its end."""
    for step in plan.steps:
        if isinstance(step, GripperAction):
            player.gripper(step.arm, step.action == "close", q)
        else:
            q = player.trajectory(step)
    player.flush()
    return q
