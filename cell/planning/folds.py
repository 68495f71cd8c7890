"""Fold planning: from matched landmarks (table frame) and the category's recipe to a `FoldPlan`.

Per fold (paper Sec. IV, g-fold of van den Berg et al.): grasp points G and place points P from
the recipe, one common fold line (perpendicular bisector of the mean move G->P), and for each
grasping arm approach -> close -> triangular fold path (up to a height of `lift_fraction` x |GP|
above the fold line, then down to P) -> open -> retreat, then a free move to the perceiving
configuration. The gripper's lower finger slides under the cloth, so the approach is low and
nearly horizontal along the fold direction, from outside the edge; fingertips may touch the table
in those Cartesian segments only.

Reach: the turn-table angle is chosen per fold from `grasp.turntable_angles`, and several approach
yaws are tried per arm; a fold no combination can do raises `Unreachable` naming the point.

Landmarks are a dict name -> (x, y) in the `table` frame (m) whose insertion order is the garment
outline order (the perception model's vertex order, clockwise on screen); the expected folded
outline keeps that order and names F/T `fold<s>-from/-to` (shared fold convention).
"""

from __future__ import annotations

import dataclasses
import itertools
import logging
import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cell.planning.errors import PlanningError, PlanningInputError, Unreachable
from cell.planning.ik import look_rotation
from cell.planning.motion import CartesianFailure, MotionPlanner, default_motion_planner, interpolate_poses
from cell.planning.trajectory import PlannedTrajectory
from drivers.common.configfile import ConfigError, config_dir, load_yaml
from drivers.common.garments import CATEGORIES
from drivers.common.landmarks import TABLE, Landmarks
from drivers.common.plane import FoldLine, perimeter
from drivers.robot.table import TableConfig, default_table_config

log = logging.getLogger(__name__)


# --- recipes ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class FoldSpec:
    """One fold: each grasped landmark moves towards a target landmark by `fraction` of the way,
    which sets the fold line. `hold`: the landmarks the grippers hold instead, each laid on its
    mirror image across that line (a sleeve reaches past the side it is folded with: held by the
    side's corners it hangs and lands crumpled, held by its end it is carried over flat)."""

    name: str
    grasp: tuple[str, ...]
    toward: tuple[str, ...]
    fraction: tuple[float, ...]
    lift_fraction: float
    crease_allowance: float         # m each grasped point is laid beyond its mirror point: the
                                    # crease's bend takes that much back when the grippers let go
    hold: tuple[str, ...] = ()

    @property
    def held(self) -> tuple[str, ...]:
        """The landmarks the grippers close on."""
        return self.hold or self.grasp


@dataclass(frozen=True)
class Recipe:
    category: str
    folds: tuple[FoldSpec, ...]


def load_recipe(category: str, path: str | Path | None = None) -> Recipe:
    """The `recipe:` key of config/garments/<category>.yaml."""
    if category not in CATEGORIES:
        raise PlanningInputError(f"category must be one of {', '.join(CATEGORIES)}, got {category!r}")
    path = Path(path) if path else config_dir() / "garments" / f"{category}.yaml"
    f = load_yaml(path)
    folds = []
    for item in f.items("recipe"):
        item.reject_unknown({"name", "grasp", "toward", "fraction", "hold", "lift_fraction",
                             "crease_allowance"})
        grasp = item.strs("grasp")
        toward = item.strs("toward")
        fraction = item.floats("fraction")
        if not 1 <= len(grasp) <= 2:
            raise item.error("grasp", "one or two landmarks (one per arm)")
        if len(toward) != len(grasp) or len(fraction) != len(grasp):
            raise item.error("toward", "toward and fraction need one entry per grasp landmark")
        if any(not 0.0 < x <= 1.0 for x in fraction):
            raise item.error("fraction", "each fraction must be in (0, 1]")
        hold = item.strs("hold", ())
        if hold and len(hold) != len(grasp):
            raise item.error("hold", f"one landmark per grasp landmark ({len(grasp)}), got {len(hold)}")
        folds.append(FoldSpec(item.str("name"), grasp, toward, fraction,
                              item.float("lift_fraction", positive=True, max=2.0),
                              item.float("crease_allowance", min=0.0, max=0.1), hold))
    if not folds:
        raise ConfigError(path, "recipe", "needs at least one fold")
    return Recipe(category, tuple(folds))


# --- fold geometry ----------------------------------------------------------------------------
def _require_table(landmarks: Mapping[str, tuple[float, float]]) -> None:
    if isinstance(landmarks, Landmarks) and landmarks.frame != TABLE:
        raise PlanningInputError(f"landmarks: in the {landmarks.frame} frame, the table frame needed")


def _check_landmarks(landmarks: Mapping[str, tuple[float, float]]) -> tuple[list[str], np.ndarray]:
    if not isinstance(landmarks, Mapping) or len(landmarks) < 3:
        raise PlanningInputError("landmarks: need a mapping of at least 3 names -> (x, y) in the table frame")
    _require_table(landmarks)
    names = list(landmarks)
    try:
        pts = np.array([[float(v[0]), float(v[1])] for v in landmarks.values()])
    except (TypeError, ValueError, IndexError) as exc:
        raise PlanningInputError(f"landmarks: each value must be (x, y) in metres: {exc}") from exc
    if not np.all(np.isfinite(pts)):
        raise PlanningInputError("landmarks: non-finite coordinate")
    return names, pts


def fold_moves(landmarks: Mapping[str, tuple[float, float]], spec: FoldSpec) -> tuple[np.ndarray, np.ndarray]:
    """Grasp points G (k, 2) and place points P (k, 2) of one fold: the points held (`spec.held`)
    and their mirror images across the fold line."""
    for n in spec.grasp + spec.toward + spec.hold:
        if n not in landmarks:
            raise PlanningInputError(
                f"landmarks: fold {spec.name!r} needs {n!r}, have {', '.join(landmarks)}")
    G = np.array([landmarks[n] for n in spec.grasp], dtype=float)
    T = np.array([landmarks[n] for n in spec.toward], dtype=float)
    P = G + np.array(spec.fraction)[:, None] * (T - G)
    if len(G) > 1 or spec.hold:
        # two grasps fold flat only about one common line: each lands on its mirror image across it
        line = fold_line(G, P)
        G = np.array([landmarks[n] for n in spec.held], dtype=float)
        P = line.reflect(G)
    return G, P


def fold_line(G: np.ndarray, P: np.ndarray) -> FoldLine:
    """One common fold line: perpendicular bisector of the mean move (table frame; its normal
    points to G's side, the side that moves)."""
    d = np.mean(G - P, axis=0)
    n = float(np.linalg.norm(d))
    if n < 1e-6:
        raise PlanningInputError("fold moves are of zero length: grasp and place points coincide")
    return FoldLine(np.mean((G + P) / 2.0, axis=0), d / n)


def fold_outline(names: list[str], pts: np.ndarray, line: FoldLine, fold_number: int,
                 merge_fraction: float) -> Landmarks:
    """The folded outline per the shared fold convention (see module docstring)."""
    side = line.side(pts)          # > 0: moving part (G's side)
    moving = side > 0.0
    n = len(pts)
    if not moving.any():
        raise PlanningInputError("fold line leaves the whole garment on the stationary side")
    if moving.all():
        raise PlanningInputError("fold line puts the whole garment on the moving side")
    # start the walk at the beginning of the longest stationary run so the moving part is one block
    best_start, best_len = 0, -1
    for i in range(n):
        if not moving[i] and moving[i - 1]:
            length = 0
            while length < n and not moving[(i + length) % n]:
                length += 1
            if length > best_len:
                best_start, best_len = i, length
    order = [(best_start + k) % n for k in range(n)]
    stat = order[:best_len]
    first_mov = order[best_len]
    last_mov = order[-1]
    # the walk enters the moving part on edge (stat[-1] -> first_mov), leaves on (last_mov -> stat[0])

    def crossing(i: int, j: int) -> np.ndarray:
        si, sj = side[i], side[j]
        t = si / (si - sj)
        return pts[i] + t * (pts[j] - pts[i])

    F = crossing(stat[-1], first_mov)
    T = crossing(last_mov, stat[0])
    merge = merge_fraction * perimeter(pts)
    kept = [i for i in stat if np.linalg.norm(pts[i] - F) >= merge and np.linalg.norm(pts[i] - T) >= merge]
    # outline order: F and T take the place of the moving block (after the stationary run)
    new_names = [names[i] for i in kept] + [f"fold{fold_number}-from", f"fold{fold_number}-to"]
    new_pts = np.vstack([pts[kept].reshape(-1, 2), F, T])
    # keep the original starting vertex first when it survives (stable, readable output)
    if kept and names[0] in new_names:
        r = new_names.index(names[0])
        new_names = new_names[r:] + new_names[:r]
        new_pts = np.roll(new_pts, -r, axis=0)
    return Landmarks(TABLE, new_names, new_pts)


def inward_directions(names: list[str], pts: np.ndarray, grasp: tuple[str, ...]) -> np.ndarray:
    """Unit vectors from each grasped landmark into the cloth, along its corner's bisector."""
    out = []
    n = len(pts)
    contour = pts.astype(np.float32).reshape(-1, 1, 2)
    for name in grasp:
        i = names.index(name)
        p = pts[i]
        e1 = pts[(i - 1) % n] - p
        e2 = pts[(i + 1) % n] - p
        e1 = e1 / max(float(np.linalg.norm(e1)), 1e-9)
        e2 = e2 / max(float(np.linalg.norm(e2)), 1e-9)
        b = e1 + e2
        if float(np.linalg.norm(b)) < 1e-6:  # a straight outline: go perpendicular to it
            b = np.array([-e1[1], e1[0]])
        b = b / float(np.linalg.norm(b))
        probe = p + 1e-3 * b
        if cv2.pointPolygonTest(contour, (float(probe[0]), float(probe[1])), False) < 0:
            b = -b  # a reflex corner: its bisector points out of the cloth
        out.append(b)
    return np.array(out)


def _pairs(points: np.ndarray) -> tuple[tuple[float, float], ...]:
    return tuple((float(p[0]), float(p[1])) for p in points)


def _distance_into_circle(points: np.ndarray, direction: np.ndarray, radius: float) -> float | None:
    """The shortest move along unit `direction` that brings every one of `points` (relative to the
    circle's centre) within `radius`; None when no move along it does."""
    lower, upper = 0.0, math.inf
    for p in points:
        b = float(p @ direction)
        disc = b * b - (float(p @ p) - radius * radius)
        if disc < 0.0:
            return None
        root = math.sqrt(disc)
        lower, upper = max(lower, -b - root), min(upper, -b + root)
    return lower if lower <= upper else None


def _outline_points(pts: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along the closed outline `pts` (N, 2), every edge cut into pieces at most `spacing`
    long, and at each the unit direction into the cloth (the corner's bisector at a vertex, the
    edge's inner normal between)."""
    names = [str(i) for i in range(len(pts))]
    corners = inward_directions(names, pts, tuple(names))
    contour = pts.astype(np.float32).reshape(-1, 1, 2)
    points, inward = [], []
    for i, a in enumerate(pts):
        b = pts[(i + 1) % len(pts)]
        points.append(a)
        inward.append(corners[i])
        length = float(np.linalg.norm(b - a))
        normal = np.array([a[1] - b[1], b[0] - a[0]]) / max(length, 1e-12)
        middle = (a + b) / 2.0 + 1e-3 * normal
        if cv2.pointPolygonTest(contour, (float(middle[0]), float(middle[1])), False) < 0:
            normal = -normal
        pieces = math.ceil(length / spacing)
        for k in range(1, pieces):
            points.append(a + (b - a) * k / pieces)
            inward.append(normal)
    return np.array(points), np.array(inward)


def _room_along(points: np.ndarray, direction: np.ndarray, table: TableConfig) -> float:
    """How far `points` (table frame) can move along unit `direction` and stay on the table top."""
    room = math.inf
    for axis, size in ((0, table.size_x), (1, table.size_y)):
        step = float(direction[axis])
        if step < -1e-12:
            room = min(room, float(np.min(points[:, axis])) / -step)
        elif step > 1e-12:
            room = min(room, float(np.min(size - points[:, axis])) / step)
    return max(room, 0.0)


def _edge_distance(point: np.ndarray, outline: np.ndarray) -> float:
    """Distance (m) from `point` to the closed polygon `outline` (N, 2)."""
    a = outline
    b = np.roll(outline, -1, axis=0)
    ab = b - a
    along = np.einsum("ij,ij->i", point - a, ab) / np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-12)
    t = np.clip(along, 0.0, 1.0)
    return float(np.min(np.linalg.norm(a + t[:, None] * ab - point, axis=1)))


# --- plan -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class GripperAction:
    arm: str       # r1 | r2
    action: str    # open | close


PlanStep = PlannedTrajectory | GripperAction


@dataclass(frozen=True)
class _PlannedSteps:
    steps: tuple[PlanStep, ...]

    @property
    def trajectories(self) -> list[PlannedTrajectory]:
        return [s for s in self.steps if isinstance(s, PlannedTrajectory)]

    @property
    def robot_time(self) -> float:
        return float(sum(t.duration for t in self.trajectories))

    @property
    def final_positions(self) -> np.ndarray:
        return self.trajectories[-1].positions[-1].copy()


@dataclass(frozen=True)
class FoldPlan(_PlannedSteps):
    """Everything the cell sends for one fold, in order, plus what it expects to see after it."""

    category: str
    fold_index: int
    fold_name: str
    arms: tuple[str, ...]                              # grasping arm per grasp point
    grasp_points: tuple[tuple[float, float], ...]      # table frame, m, same order as arms
    place_points: tuple[tuple[float, float], ...]
    fold_line: FoldLine
    expected_outline: Landmarks


@dataclass(frozen=True)
class PullPlan(_PlannedSteps):
    """The garment dragged along the table by `offset` (table frame, m), towards the turn-table,
    before fold `fold_index` (0-based) whose points lay out of reach."""

    category: str
    fold_index: int
    arms: tuple[str, ...]
    grasp_points: tuple[tuple[float, float], ...]
    offset: tuple[float, float]
    why: str                                           # the fold's point that lay out of reach

    @property
    def distance(self) -> float:
        return float(np.hypot(*self.offset))


# A towel has no top or bottom: the cell may name it turned half round (the fold line stays, the other
# side is laid over), whichever lets both arms fold it
HALF_TURNS: dict[str, dict[str, str]] = {
    "towel": {"bottom-left": "top-right", "bottom-right": "top-left",
              "top-right": "bottom-left", "top-left": "bottom-right"},
}


class FoldPlanner:
    """Plans folds; caches the motion planner (model, collision objects, IK)."""

    def __init__(self, motion: MotionPlanner | None = None, table: TableConfig | None = None,
                 recipes: dict[str, Recipe] | None = None):
        self.motion = motion or default_motion_planner()
        self.table = table or default_table_config()
        self.config = self.motion.config
        self._recipes = dict(recipes or {})
        self.robot = self.motion.robot
        self.arm_names = tuple(a.name for a in self.robot.arms)
        # which side of the turn-table each arm is mounted (world y of its base at ext_axis = 0)
        q0 = np.zeros(len(self.robot.joint_names))
        self.arm_side = {a: float(self.motion.kin.fk(q0, f"{a}_base_link")[1, 3]) for a in self.arm_names}
        # no TCP gets farther from the turn-table axis than its shoulder's distance, the wrist's reach
        # and the tool (a bound that spares IK on points no arm can reach)
        shoulder = max(float(np.linalg.norm(self.motion.kin.fk(q0, f"{a}_link_s")[:2, 3]))
                       for a in self.arm_names)
        self.outer_reach = shoulder + self.config.max_wrist_reach + self.config.wrist_offset

    def recipe(self, category: str) -> Recipe:
        if category not in self._recipes:
            self._recipes[category] = load_recipe(category)
        return self._recipes[category]

    # ---- geometry helpers -------------------------------------------------------------------
    def _world(self, xy: np.ndarray, dz: float) -> np.ndarray:
        w = self.table.table_to_world(xy)[0]
        w[2] += dz
        return w

    def _key_poses(self, G: np.ndarray, P: np.ndarray, lift_fraction: float, yaw: float,
                   inward: np.ndarray | None = None, crease_allowance: float = 0.0,
                   pull: bool = False) -> dict[str, np.ndarray]:
        """A fold's key poses; a `pull` drags the grasped point to P along the table instead (the
        fingers go in along `inward`, whichever way the garment is pulled)."""
        g = self.config.grasp
        d = P - G
        heading = inward if pull and inward is not None else d
        base = math.atan2(heading[1], heading[0]) + yaw
        dxy = np.array([math.cos(base), math.sin(base)])
        approach = np.array([dxy[0] * math.cos(g.pitch), dxy[1] * math.cos(g.pitch), -math.sin(g.pitch)])
        R = look_rotation(approach)
        h = lift_fraction * float(np.linalg.norm(d))
        # The gripper holds the cloth point under its TCP, `depth` inside the edge; that point must
        # land on its mirror image across the fold line (the bisector of G->P), not beside P.
        # the TCP closes `depth` inside the cloth (the lower finger under it), into the corner
        grasp_xy = G + g.depth * (dxy if inward is None else inward)
        # and `crease_allowance` beyond it: the crease's bend draws the flap back that much on release
        if pull:
            place_xy = grasp_xy + d
            back = dxy      # the fingers come out the way they went in
        else:
            # (a grasp on the fold line does not move: G->P sets no line to mirror across)
            moves = float(np.linalg.norm(d)) >= 1e-9
            mirror = FoldLine.from_move(G, P).reflect(grasp_xy)[0] if moves else grasp_xy
            place_xy = mirror + crease_allowance * d / max(float(np.linalg.norm(d)), 1e-9)
            back = (place_xy - grasp_xy) / max(float(np.linalg.norm(place_xy - grasp_xy)), 1e-9)
        pts = {
            "pregrasp": self._world(G - g.approach_distance * dxy, g.height + g.approach_lift),
            "grasp": self._world(grasp_xy, g.height),
            "apex": self._world((grasp_xy + place_xy) / 2.0, g.height + h),
            "place": self._world(place_xy, g.release_height),
            "retreat": self._world(place_xy - g.retreat_distance * back, g.release_height + g.retreat_lift),
        }
        out = {}
        for k, p in pts.items():
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = p
            out[k] = T
        return out

    def _solve_keys(self, arm: str, poses: dict[str, np.ndarray],
                    q_base: np.ndarray) -> tuple[np.ndarray | None, str, str]:
        """IK of the key poses in order, each seeded from the previous; returns the grasp-time config
        of the pre-grasp, or the failing key and reason."""
        shoulder = self.motion.kin.fk(q_base, f"{arm}_link_s")[:3, 3]
        for key in ("pregrasp", "grasp", "apex", "place", "retreat"):
            T = poses[key]
            wrist = T[:3, 3] - self.config.wrist_offset * T[:3, 2]
            if np.linalg.norm(wrist - shoulder) > self.config.max_wrist_reach:
                return None, key, "out of reach"
        idx = self.motion.arm_indices[arm]
        coll = self.motion.collision
        fail_key, fail_why = "pregrasp", "no IK solution (out of reach)"
        # each seed starts a chain pregrasp -> ... -> retreat, every key solved from the previous one
        # and free of collisions; the first complete chain wins
        for s in self.config.ik_seeds:
            q = q_base.copy()
            q[idx] = s
            q_pre = None
            for key in ("pregrasp", "grasp", "apex", "place", "retreat"):
                r = self.motion.ik.solve(arm, poses[key], q)
                if not r.success:
                    fail_key, fail_why = key, "no IK solution (out of reach)"
                    break
                if coll.in_collision(r.q, allow_finger_contact=True):
                    fail_key, fail_why = key, "collision at every IK solution tried"
                    break
                q = r.q
                if q_pre is None:
                    q_pre = q.copy()
            else:
                return q_pre, "", ""
        return None, fail_key, fail_why

    # ---- public -----------------------------------------------------------------------------
    def reachable(self, point_xy: tuple[float, float], arm: str | None = None) -> bool:
        """Can some arm (or `arm`) grasp at this table point with some approach yaw and turn-table
        angle (IK only, toward the table centre)?"""
        centre = np.array([self.table.size_x / 2.0, self.table.size_y / 2.0])
        G = np.asarray(point_xy, dtype=float)
        P = centre if np.linalg.norm(centre - G) > 0.05 else G + np.array([0.1, 0.0])
        for theta in self.config.grasp.turntable_angles:
            q = self.motion.perceive.copy()
            q[self.motion.ext_index] = theta
            for a in ([arm] if arm else self.arm_names):
                for yaw in self.config.grasp.yaw_offsets:
                    poses = self._key_poses(G, P, 0.3, yaw)
                    idx = self.motion.arm_indices[a]
                    seeds = []
                    for s in self.config.ik_seeds:
                        qs = q.copy()
                        qs[idx] = s
                        seeds.append(qs)
                    if self.motion.ik.solve_multi(a, poses["grasp"], seeds).success:
                        return True
        return False

    def plan_fold(self, category: str, fold_index: int, landmarks: Mapping[str, tuple[float, float]],
                  q_current: np.ndarray, include_perceive: bool = True) -> FoldPlan:
        """Plan fold `fold_index` (0-based) of `category` from the current landmarks and joints.

        A garment with no top or bottom (`HALF_TURNS`) may be named turned half round: when the
        naming given leaves the fold to one arm (or to none), the turned one is planned too (the
        same fold line, the other side laid over) and taken if more arms can fold it."""
        _require_table(landmarks)
        recipe = self.recipe(category)
        turn = HALF_TURNS.get(category)
        if turn is not None and isinstance(fold_index, int) and 0 <= fold_index < len(recipe.folds):
            spec = recipe.folds[fold_index]
            needed = set(spec.grasp + spec.toward + spec.hold)
            turned_names = {turn.get(name, name): point for name, point in landmarks.items()}
            if not needed <= set(landmarks) and needed <= set(turned_names):
                # named as it lies, after a first fold planned turned half round: go on in that naming
                landmarks = turned_names
        plan, unreachable = self._plan_or_unreachable(category, fold_index, landmarks, q_current,
                                                      include_perceive)
        wanted = len(recipe.folds[fold_index].grasp)
        if turn is not None and set(landmarks) == set(turn) and (plan is None or len(plan.arms) < wanted):
            turned = {turn[name]: point for name, point in landmarks.items()}
            other, _ = self._plan_or_unreachable(category, fold_index, turned, q_current, include_perceive)
            if other is not None and (plan is None or len(other.arms) > len(plan.arms)):
                log.info("%s fold %d: planned on the %s named turned half round (%d arm(s) reach it so)",
                         category, fold_index + 1, category, len(other.arms))
                return other
        if plan is None:
            assert unreachable is not None
            raise unreachable
        return plan

    def _plan_or_unreachable(self, category: str, fold_index: int,
                             landmarks: Mapping[str, tuple[float, float]],
                             q_current: np.ndarray, include_perceive: bool
                             ) -> tuple[FoldPlan | None, Unreachable | None]:
        try:
            return self._plan_named(category, fold_index, landmarks, q_current, include_perceive), None
        except Unreachable as exc:
            return None, exc

    def _plan_named(self, category: str, fold_index: int, landmarks: Mapping[str, tuple[float, float]],
                    q_current: np.ndarray, include_perceive: bool) -> FoldPlan:
        recipe = self.recipe(category)
        if not isinstance(fold_index, int) or not 0 <= fold_index < len(recipe.folds):
            raise PlanningInputError(
                f"fold_index must be 0..{len(recipe.folds) - 1} for {category}, got {fold_index!r}")
        q_current = np.asarray(q_current, dtype=float)
        if q_current.shape != (len(self.robot.joint_names),) or not np.all(np.isfinite(q_current)):
            raise PlanningInputError(f"q_current must be {len(self.robot.joint_names)} finite joint values")
        spec = recipe.folds[fold_index]
        names, pts = _check_landmarks(landmarks)
        G, P = fold_moves(landmarks, spec)
        line = fold_line(G, P)
        outline = fold_outline(names, pts, line, fold_index + 1, self.config.merge_distance)
        try:
            steps, arms, Gu, Pu = self._plan_held(spec, landmarks, names, pts, q_current, include_perceive)
        except Unreachable as exc:
            if not spec.hold:
                raise
            # the points that set the line are the second choice: the same fold, the sleeve left to hang
            try:
                by_line = dataclasses.replace(spec, hold=())
                steps, arms, Gu, Pu = self._plan_held(by_line, landmarks, names, pts, q_current,
                                                      include_perceive)
            except Unreachable:
                raise exc from None
            log.info("%s fold %d: holding %s cannot be planned (%s); holding %s instead", category,
                     fold_index + 1, ", ".join(spec.hold), exc.reason, ", ".join(spec.grasp))
        return FoldPlan(steps=tuple(steps), category=category, fold_index=fold_index, fold_name=spec.name,
                        arms=tuple(arms), grasp_points=_pairs(Gu), place_points=_pairs(Pu),
                        fold_line=line, expected_outline=outline)

    def _plan_held(self, spec: FoldSpec, landmarks: Mapping[str, tuple[float, float]], names: list[str],
                   pts: np.ndarray, q_current: np.ndarray, include_perceive: bool
                   ) -> tuple[list[PlanStep], list[str], np.ndarray, np.ndarray]:
        """The arm motions of a fold holding `spec.held`."""
        G, P = fold_moves(landmarks, spec)
        for k in range(len(G)):
            for what, pt in (("grasp point", G[k]), ("place point", P[k])):
                if not self.table.contains(pt[None, :])[0]:
                    raise Unreachable(pt, "outside the table top", what)
        inward = inward_directions(names, pts, spec.held)
        return self._plan_motions(G, P, inward, spec.lift_fraction, spec.crease_allowance, q_current,
                                  include_perceive, outline=pts)

    def plan_fold_or_pull(self, category: str, fold_index: int, landmarks: Mapping[str, tuple[float, float]],
                          q_current: np.ndarray, pulls_done: int, include_perceive: bool = True
                          ) -> FoldPlan | PullPlan:
        """Fold `fold_index` (0-based), or, when it is out of reach, first a pull of the garment into
        reach (`plan_pull`, at most `max_pulls` per fold, `pulls_done` made). Raises Unreachable when
        neither helps."""
        try:
            plan = self.plan_fold(category, fold_index, landmarks, q_current, include_perceive)
        except Unreachable as exc:
            if pulls_done >= self.config.max_pulls:
                raise Unreachable(exc.point, f"{exc.reason} (after {pulls_done} pull(s) into reach)",
                                  exc.what) from exc
            try:
                return self.plan_pull(category, fold_index, landmarks, q_current, include_perceive)
            except Unreachable as why_not:
                raise Unreachable(exc.point, f"{exc.reason}; no pull helps: {why_not.reason}",
                                  exc.what) from exc
        return plan

    def plan_pull(self, category: str, fold_index: int, landmarks: Mapping[str, tuple[float, float]],
                  q_current: np.ndarray, include_perceive: bool = True) -> PullPlan:
        """The garment pulled towards reach of fold `fold_index` (0-based), the paper's proposed fix:
        the grippers close on its outline where it lies nearest the turn-table and an arm reaches it
        (two points far enough apart, or one) and drag them straight along the table towards its
        axis, until every grasp and place point of the fold is `pull_margin` inside `reach_radius`,
        by `max_pull` at most and no farther than the table's edge allows (the cell pulls again if the
        fold is still out of reach). Raises Unreachable when no pull helps: the fold's points already
        lie within reach (what fails is not distance), or the table leaves no room."""
        recipe = self.recipe(category)
        if not isinstance(fold_index, int) or not 0 <= fold_index < len(recipe.folds):
            raise PlanningInputError(
                f"fold_index must be 0..{len(recipe.folds) - 1} for {category}, got {fold_index!r}")
        _, pts = _check_landmarks(landmarks)
        G, P = fold_moves(landmarks, recipe.folds[fold_index])
        axis = self.table.world_to_table(np.zeros((1, 3)))[0]
        goal = self.config.reach_radius - self.config.pull_margin
        towards = axis - pts.mean(axis=0)
        towards = towards / max(float(np.linalg.norm(towards)), 1e-9)
        needed = np.vstack([G, P])
        farthest = needed[int(np.argmax(np.linalg.norm(needed - axis, axis=1)))]
        why = (f"the fold's point at table ({farthest[0]:.3f}, {farthest[1]:.3f}) m lies "
               f"{float(np.linalg.norm(farthest - axis)):.2f} m from the turn-table axis")
        distance = _distance_into_circle(needed - axis, towards, goal)
        if distance is not None and distance < 1e-3:
            raise Unreachable(farthest, f"every point of the fold is within {goal:.2f} m of the turn-table "
                                        "axis already: a pull cannot help", "point")
        room = _room_along(pts, towards, self.table)
        distance = min(self.config.max_pull if distance is None else distance, self.config.max_pull, room)
        if distance < self.config.pull_margin:
            raise Unreachable(farthest, f"{why}; the table's edge leaves {room:.2f} m to pull it towards "
                                        "the robot", "point")
        offset = distance * towards
        chosen, inward = self._pull_grasps(pts, axis)
        steps, arms, Gu, _ = self._plan_motions(chosen, chosen + offset, inward, 0.0, 0.0, q_current,
                                                include_perceive, outline=pts, pull=True)
        return PullPlan(steps=tuple(steps), category=category, fold_index=fold_index, arms=tuple(arms),
                        grasp_points=_pairs(Gu), offset=(float(offset[0]), float(offset[1])), why=why)

    def _pull_grasps(self, pts: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where to drag the garment by (k, 2) and the fingers' way in (k, 2): points of its outline
        (`pull_grasp_spacing` apart along each edge), the nearest the turn-table an arm reaches and,
        beside it, the nearest at least `pull_arm_spacing` away (one point when none is)."""
        candidates, inward = _outline_points(pts, self.config.pull_grasp_spacing)
        distances = np.linalg.norm(self.table.table_to_world(candidates)[:, :2], axis=1)
        order = [i for i in np.argsort(distances) if distances[i] <= self.outer_reach]
        if not order:
            raise Unreachable(candidates[int(np.argmin(distances))], "no point of the garment's outline is "
                              f"within {self.outer_reach:.2f} m of the turn-table axis to pull it by",
                              "grasp point")
        first: int | None = None
        for i in (int(i) for i in order):
            far_enough = first is None or np.linalg.norm(candidates[i] - candidates[first]) >= \
                self.config.pull_arm_spacing
            if far_enough and self.reachable((float(candidates[i][0]), float(candidates[i][1]))):
                if first is not None:
                    return candidates[[first, i]], inward[[first, i]]
                first = i
        if first is None:
            raise Unreachable(candidates[order[0]], "no point of the garment's outline is within reach "
                              "to pull it by", "grasp point")
        return candidates[[first]], inward[[first]]

    def _assignments(self, G: np.ndarray, P: np.ndarray, inward: np.ndarray,
                     outline: np.ndarray | None = None
                     ) -> list[tuple[tuple[str, ...], np.ndarray, np.ndarray, np.ndarray]]:
        """(arms, G, P) to try in order: two arms both ways round, and one arm at the midpoints
        (first when the grasp points are too close for two grippers; not at all when the midpoint is
        farther than `one_arm_edge_distance` from the `outline`: nothing to grasp there)."""
        by_side = sorted(self.arm_names, key=lambda a: -self.arm_side[a])   # +y side first

        def single(g: np.ndarray, p: np.ndarray, i: np.ndarray) -> list:
            gy = self.table.table_to_world(g)[0][1]
            near = by_side if gy >= 0 else by_side[::-1]
            return [((arm,), g[None, :], p[None, :], i[None, :]) for arm in near[:2]]

        if len(G) == 1:
            return single(G[0], P[0], inward[0])
        gy = [self.table.table_to_world(x)[0][1] for x in G]
        first = tuple(by_side if gy[0] >= gy[1] else by_side[::-1])
        two = [(first, G, P, inward), (first[::-1], G, P, inward)]
        mean_in = inward.mean(axis=0)
        mean_in = mean_in / max(float(np.linalg.norm(mean_in)), 1e-9)
        one = single(G.mean(axis=0), P.mean(axis=0), mean_in)
        edge = _edge_distance(G.mean(axis=0), outline) if outline is not None else 0.0
        if edge > self.config.one_arm_edge_distance:
            return two
        if np.linalg.norm(G[0] - G[1]) < self.config.min_two_arm_spacing:
            return one + two
        return two + one

    def _plan_motions(self, G: np.ndarray, P: np.ndarray, inward: np.ndarray, lift: float,
                      crease_allowance: float, q_current: np.ndarray, include_perceive: bool,
                      outline: np.ndarray | None = None, pull: bool = False
                      ) -> tuple[list[PlanStep], list[str], np.ndarray, np.ndarray]:
        mp = self.motion
        g = self.config.grasp
        failures: list[tuple[np.ndarray, str, str]] = []
        # turn-table candidates nearest the direction of the garment's moves first
        centre = self.table.table_to_world(np.vstack([G, P]).mean(axis=0))[0]
        heading = math.atan2(centre[1], centre[0])
        thetas = sorted(g.turntable_angles, key=lambda t: abs(t - heading))
        # Each (assignment, turn-table angle) block: per arm the first two approach yaws whose key
        # poses solve (`_ArmOptions`), then their combinations built in order; the first build that
        # succeeds is the plan. The arms' yaws are solved only as far as the builds need them (a
        # block where one arm has none builds nothing, whatever the other arm has); a block that
        # fails is searched in full before the fold is reported unreachable, so `failures` holds
        # what the full search finds, in its order.
        failed_blocks: list[tuple[list[_ArmOptions], list[tuple[np.ndarray, str, str]]]] = []
        for arms, grasps, places, inward_k in self._assignments(G, P, inward, outline):
            # per arm and approach yaw: the key poses (the same at every turn-table angle)
            poses = [[self._key_poses(grasps[k], places[k], lift, yaw, inward_k[k], crease_allowance, pull)
                      for yaw in g.yaw_offsets] for k in range(len(arms))]
            for theta in thetas:
                q_base = mp.perceive.copy()
                q_base[mp.ext_index] = theta
                searches = [_ArmOptions(self, arm, grasps[k], places[k], q_base, poses[k])
                            for k, arm in enumerate(arms)]
                build_failures: list[tuple[np.ndarray, str, str]] = []
                failed_blocks.append((searches, build_failures))
                if not all(s.need(1) for s in searches):
                    continue
                for combo in _combinations(searches):
                    try:
                        steps = self._build(arms, combo, grasps, places, theta, q_current, include_perceive)
                        return steps, list(arms), grasps, places
                    except _SegmentFailed as exc:
                        build_failures.append((exc.point, exc.reason, exc.what))
        for searches, build_failures in failed_blocks:
            for s in searches:
                s.need(2)
                failures += s.failures
            failures += build_failures
        if not failures:
            raise PlanningError("no arm assignment to try")
        # report the failure that got furthest (a collision or path problem beats plain reach)
        rank = {"out of reach": 0, "no IK solution (out of reach)": 1}
        pt, reason, what = max(
            failures, key=lambda f: next((v for k, v in rank.items() if f[1].endswith(k)), 2))
        raise Unreachable(pt, f"{reason} (tried {len(failures)} arm/approach/turn-table combinations)", what)

    def _build(self, arms: tuple[str, ...], combo: list, G: np.ndarray, P: np.ndarray, theta: float,
               q_current: np.ndarray, include_perceive: bool) -> list[PlanStep]:
        mp = self.motion
        g = self.config.grasp
        q_pre = mp.perceive.copy()
        q_pre[mp.ext_index] = theta
        for arm, (_, qa) in zip(arms, combo, strict=True):
            idx = mp.arm_indices[arm]
            q_pre[idx] = qa[idx]
        if not mp.valid(q_pre):
            pairs = mp.collision.colliding_pairs(q_pre)[:2]
            raise _SegmentFailed(G[0], f"collision at pre-grasp: {pairs}", "grasp point")
        phases = (("approach", ("pregrasp", "grasp")), ("fold", ("grasp", "apex", "place")),
                  ("retreat", ("place", "retreat")))
        paths = []
        q = q_pre
        for label, keys in phases:
            targets: dict[str, list[np.ndarray]] = {}
            for arm, (poses, _) in zip(arms, combo, strict=True):
                seq: list[np.ndarray] = []
                for a, b in itertools.pairwise(keys):
                    seq += interpolate_poses(poses[a], poses[b], g.cartesian_step)
                targets[arm] = seq
            n = max(len(v) for v in targets.values())
            for arm in targets:   # equal lengths: resample the shorter one's index
                seq = targets[arm]
                targets[arm] = [seq[min(len(seq) - 1, round(i * (len(seq) - 1) / max(n - 1, 1)))]
                                for i in range(n)]
            path = mp.cartesian_path(q, targets, allow_finger_contact=True)
            if isinstance(path, CartesianFailure):
                k = arms.index(path.arm)
                pt = G[k] if label == "approach" else P[k]
                raise _SegmentFailed(pt, f"{path.arm} {label}: {path.reason}",
                                     "grasp point" if label == "approach" else "place point")
            paths.append((label, path))
            q = path[-1]
        steps: list[PlanStep] = [GripperAction(a, "open") for a in arms]
        try:
            steps.append(mp.free_move(q_current, q_pre, "to-pregrasp"))
            for label, path in paths:
                steps.append(mp.cartesian_move(path, label, allow_finger_contact=True))
                if label == "approach":
                    steps += [GripperAction(a, "close") for a in arms]
                elif label == "fold":
                    steps += [GripperAction(a, "open") for a in arms]
            if include_perceive:
                steps.append(mp.perceive_move(paths[-1][1][-1]))
        except PlanningError as exc:
            raise _SegmentFailed(G[0], str(exc), "grasp point") from exc
        return steps


class _ArmOptions:
    """One arm's key-pose solutions at one turn-table angle (`q_base`): the approach yaws tried in
    order, the first two that solve kept; solved lazily, as far as `need` asks. `failures`: the yaws
    that did not solve, in order."""

    def __init__(self, planner: FoldPlanner, arm: str, grasp: np.ndarray, place: np.ndarray,
                 q_base: np.ndarray, yaw_poses: list[dict[str, np.ndarray]]):
        self.planner, self.arm, self.grasp, self.place, self.q_base = planner, arm, grasp, place, q_base
        self.options: list[tuple[dict[str, np.ndarray], np.ndarray]] = []
        self.failures: list[tuple[np.ndarray, str, str]] = []
        self._yaw_poses = iter(yaw_poses)   # key poses per approach yaw, in the order tried

    def need(self, n: int) -> bool:
        """Are there `n` (1 or 2) options?"""
        while len(self.options) < n:
            poses = next(self._yaw_poses, None)
            if poses is None:
                return False
            q_pre, key, why = self.planner._solve_keys(self.arm, poses, self.q_base)
            if q_pre is None:
                at_grasp = key in ("pregrasp", "grasp")
                self.failures.append((self.grasp if at_grasp else self.place, f"{self.arm} {key}: {why}",
                                      "grasp point" if at_grasp else "place point"))
            else:
                self.options.append((poses, q_pre))
        return True


def _combinations(searches: list[_ArmOptions]) -> Iterator[list[tuple[dict[str, np.ndarray], np.ndarray]]]:
    """The arms' options combined, in order (first arm's first option with each of the second's,
    ...), each solved when first needed."""
    first = searches[0]
    for i in range(2):
        if not first.need(i + 1):
            return
        if len(searches) == 1:
            yield [first.options[i]]
            continue
        second = searches[1]
        for j in range(2):
            if not second.need(j + 1):
                break
            yield [first.options[i], second.options[j]]


class _SegmentFailed(Exception):
    def __init__(self, point: np.ndarray, reason: str, what: str):
        super().__init__(reason)
        self.point, self.reason, self.what = point, reason, what


__all__ = ["FoldPlan", "FoldPlanner", "FoldSpec", "GripperAction",
           "PlanStep", "Recipe", "fold_line", "fold_moves", "fold_outline", "load_recipe"]
