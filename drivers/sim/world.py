"""The event-driven simulated garment world: one garment on the table, grasped and folded by grippers.

Grasp: a gripper that closes at most `fold_rules.grasp_height` above the table top and within
`fold_rules.grasp_edge_distance` of the cloth's outline takes the cloth point under it (or the nearest
outline point when it closed just outside); otherwise it takes nothing. Release: when the last holding
gripper opens, the world applies the fold implied by where the points were taken and released; two
grippers whose moves disagree on one fold line (beyond `agree_angle`/`agree_offset`) give a crumpled,
wrong fold. Frames: gripper positions in `world`, everything else in `table` (m).

The world keeps two accounts of where the landmarks are. `truth_polygon` follows the cell's fold
convention (paper Sec. III-F: a fold replaces the moving vertices by its ends `fold<k>-from/-to`) and
names the landmarks as the cell does, as if the garment lay face up (mirrored when it lies face
down), which is what the cell perceives and is scored against. `annotated_nodes` is how the CloPeMa
dataset annotates the same state: every node of the flat garment where it now lies (carried ones too) and each
fold line's two ends, both named `fold_<k>`; it is not an outline.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np

from drivers.camera.model import CameraModel, default_camera_config
from drivers.common.garments import CATEGORIES, FACINGS, LANDMARKS, mirror_name
from drivers.common.plane import FoldLine, perimeter
from drivers.robot.config import load_robot_config
from drivers.robot.table import TableConfig, default_table_config
from drivers.sim.config import SimConfig, default_sim_config
from drivers.sim.errors import SimInputError
from drivers.sim.folding import (
    Layer,
    crumpled_fold_layers,
    fold_landmarks,
    fold_layers,
    fold_line_of_moves,
    iou,
    lines_agree,
    outline_of_union,
    recipe_moves,
)
from drivers.sim.garments import Garment, make_garment
from drivers.sim.geometry import (
    fold_line_ends,
    is_clockwise,
    nearest_edge,
    point_segment_distance,
    points_in_polygon,
    rigid_fit,
)
from drivers.sim.physics.cloth import iou as mask_iou
from drivers.sim.physics.cloth import polygon_mask
from drivers.sim.physics.config import PhysicsConfig, load_physics_config
from drivers.sim.physics.garment import Episode, GarmentCloth
from drivers.sim.render import SceneRenderer, choose_appearance

log = logging.getLogger(__name__)

PLACEMENTS: tuple[str, ...] = ("cell", "table")

Move = tuple[np.ndarray, np.ndarray]   # (grasp xy, place xy) in the table frame

# resolution of silhouettes and IoU (m per cell)
SILHOUETTE_RESOLUTION = 0.001


@dataclass(frozen=True)
class GraspResult:
    arm: str
    grasped: bool
    point: np.ndarray | None      # the cloth point taken (table frame), None when missed
    reason: str


@dataclass
class FoldRecord:
    moves: list[Move]
    crumpled: bool
    line: FoldLine


@dataclass
class _Hold:
    point: np.ndarray
    place: np.ndarray | None = None
    peak: float | None = None   # m above the table: the highest the gripper went while holding
                                # (None: no motion heard, only the events)


@dataclass
class GarmentWorld:
    """One scene: a garment of `category` from `seed`, its layered state, its renderer."""

    seed: int
    category: str | None = None
    shape: str | None = None
    facing: str | None = None         # "front": face up; "back": face down (mirror image); None: drawn
    placement: str = "cell"           # "cell": within `pose.cell_area` of config; "table": anywhere in view
    config: SimConfig = field(default_factory=default_sim_config)
    camera: CameraModel | None = None
    table: TableConfig = field(default_factory=default_table_config)
    # "geometric": fast, for unit tests and datasets; "physics": the cloth (the camera process's world
    # takes config/sim.yaml's `folding`)
    folding: str = "geometric"
    physics: PhysicsConfig | None = None   # the cloth's (default: config/physics.yaml)
    collared: bool = False            # a shirt's collar stands above its neckline (a polo, a shirt)

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise SimInputError(f"seed: must be a non-negative integer, got {self.seed!r}")
        ss = np.random.SeedSequence(int(self.seed))
        shape_ss, look_ss, light_ss, phys_ss = ss.spawn(4)
        shape_rng = np.random.default_rng(shape_ss)
        if self.category is None:
            self.category = CATEGORIES[int(shape_rng.integers(len(CATEGORIES)))]
        if self.category not in CATEGORIES:
            raise SimInputError(f"category: must be one of {', '.join(CATEGORIES)}, got {self.category!r}")
        if self.facing is None:
            self.facing = FACINGS[int(shape_rng.random() < self.config.pose.face_down)]
        if self.placement not in PLACEMENTS:
            raise SimInputError(f"placement: must be one of {', '.join(PLACEMENTS)}, got {self.placement!r}")
        cell_area = self.config.pose.cell_area
        area = None
        if self.placement == "cell" and cell_area is not None:
            bounds = np.array(cell_area).T          # rows: low corner, high corner (table x, y)
            area = (bounds[0], bounds[1])
        if self.camera is None:
            # the fixed pose places garments in view and draws datasets; with a wrist mount it stands for
            # the arm's perceiving configuration, and render() takes the actual pose
            cam_cfg = default_camera_config()
            self.camera = CameraModel(cam_cfg, pose_in_world=cam_cfg.fixed_pose_in_world, table=self.table)
        w, h = self.camera.config.width, self.camera.config.height
        corners = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]])
        self.view_polygon = self.camera.pixel_to_table(corners)
        self.garment: Garment = make_garment(self.category, shape_rng, self.config, self.view_polygon,
                                             self.shape, self.facing, area, self.collared)
        self.shape = self.garment.shape
        self.layers: list[Layer] = [Layer(self.garment.outline.copy())]
        self.names, self.points = self._as_seen_face_up()
        self._annotated_names: list[str] = list(self.garment.node_names)
        self._annotated_points: np.ndarray = self.garment.nodes()
        self.merge_distance = self.config.fold_rules.merge_fraction * perimeter(self.garment.landmarks)
        self.cloth: GarmentCloth | None = None
        if self.folding == "physics":
            if self.physics is None:
                self.physics = load_physics_config()
            arms = tuple(arm.name for arm in load_robot_config().arms)
            landmark_at = [int(np.argmin(np.linalg.norm(self.garment.outline - p, axis=1)))
                           for p in self.garment.landmarks]
            creases = tuple(fold_line_of_moves(moves) for moves in recipe_moves(
                self.category, dict(zip(self.names, self.points, strict=True)))) \
                if self.physics.cloth.crease_lines else ()
            self.cloth = GarmentCloth(self.garment.outline, self.physics, arms, landmark_at, creases)
            self._landmark_vertices = self._nearest_vertices(self.points)
        elif self.folding != "geometric":
            raise SimInputError(f"folding: must be physics or geometric, got {self.folding!r}")
        self.history: list[FoldRecord] = []
        self._holds: dict[str, _Hold] = {}
        self._phys_rng = np.random.default_rng(phys_ss)
        appearance = choose_appearance(self.config.palette(self.category), self.config.render,
                                       self.garment.shape == "wrinkled", np.random.default_rng(look_ss))
        self.appearance = appearance
        self._renderer = SceneRenderer(self.config.render, self.table, appearance,
                                       int(np.random.default_rng(light_ss).integers(2**31)), self.camera)

    # --- events ------------------------------------------------------------------------------
    def gripper_event(self, arm: str, closed: bool, tcp_position_world: np.ndarray,
                      robot_time: float | None = None) -> GraspResult | None:
        """A gripper `arm` closed or opened with its TCP at `tcp_position_world` (m, world) at
        `robot_time` (s; the physics world needs it: the cloth follows the recorded path in time,
        and what the gripper took is known once `catch_up` has simulated it)."""
        pos = np.asarray(tcp_position_world, dtype=float).reshape(-1)
        if pos.shape != (3,) or not np.all(np.isfinite(pos)):
            raise SimInputError(f"tcp_position_world: must be 3 finite numbers (m, world), got {pos!r}")
        xy = self.table.world_to_table(pos)[0]
        height = pos[2] - self.table.height
        if self.cloth is not None:
            if robot_time is None:
                raise SimInputError("robot_time: the physics world needs the time of a gripper event")
            self.cloth.record_gripper(robot_time, arm, closed, np.array([xy[0], xy[1], height]))
            return None
        hold = self._holds.get(arm)
        if closed:
            if hold is not None and hold.place is None:
                return None                      # already closed on the cloth
            return self._grasp(arm, xy, height)
        if hold is None or hold.place is not None:
            return None
        hold.place = xy
        if all(h.place is not None for h in self._holds.values()):
            moves = [(h.point, h.place) for h in self._holds.values() if h.place is not None]
            peaks = [h.peak for h in self._holds.values()]
            self._holds.clear()
            if all(self._never_lifted(peak) for peak in peaks):
                # slid along the table (a pull into reach), as the held points moved
                self._slide(*rigid_fit(np.array([g for g, _ in moves]), np.array([p for _, p in moves])))
            else:
                self.apply_fold(moves)
        return None

    def gripper_heard(self, arm: str, robot_time: float) -> None:
        """Gripper `arm` was heard, unchanged, at `robot_time` (s): the physics world may simulate up to
        then (its events come apart from the joint states, and may come later)."""
        if self.cloth is not None:
            self.cloth.record_heard(arm, robot_time)

    def gripper_motion(self, robot_time: float, tcp_positions_world: dict[str, np.ndarray]) -> None:
        """Where every gripper's TCP is (m, world) at `robot_time` (s): the path the cloth follows
        while held (physics world; the geometric world keeps only how high a held point went)."""
        if self.cloth is None:
            for arm, position in tcp_positions_world.items():
                hold = self._holds.get(arm)
                if hold is not None and hold.place is None:
                    height = float(position[2]) - self.table.height
                    hold.peak = height if hold.peak is None else max(hold.peak, height)
            return
        table = {}
        for arm, position in tcp_positions_world.items():
            xy = self.table.world_to_table(np.asarray(position, dtype=float))[0]
            table[arm] = np.array([xy[0], xy[1], float(position[2]) - self.table.height])
        self.cloth.record_motion(robot_time, table)

    def catch_up(self) -> list[FoldRecord]:
        """Physics world: simulate what has been recorded; the folds completed (empty: geometric)."""
        records: list[FoldRecord] = []
        if self.cloth is None:
            return records
        while self.cloth.busy():
            before = None if self.cloth.holding() else self._cloth_outline()
            episode = self.cloth.catch_up()
            if episode is None:
                break
            record = self._record_episode(episode, before)
            if record is not None:
                records.append(record)
        return records

    def _record_episode(self, episode: Episode, before: np.ndarray | None) -> FoldRecord | None:
        """A simulated grasp-to-release that moved cloth, as a fold: its line from where the grippers
        closed and opened; the landmarks by the fold convention."""
        moves = [(g, p) for g, p in episode.moves if np.linalg.norm(g - p) > 1e-6]
        for pinch in episode.pinches:
            log.info("%s closed at robot time %.3f s at table (%.3f, %.3f, %.3f) m: %d cloth vertices",
                     pinch.arm, pinch.time, *pinch.position, len(pinch.vertices))
        if not moves:
            log.info("a grasp-to-release moved no cloth")
            return None
        assert self.cloth is not None   # episodes come from the cloth
        if self._never_lifted(episode.peak_height):
            # the garment slid along the table (a pull into reach), as its cloth moved
            self._slide(*rigid_fit(episode.start_xy, self.cloth.vertices[:, :2]))
            return None
        line = fold_line_of_moves(moves)
        fold_number = len(self.history) + 1
        self._annotate_fold(line, fold_number, before)
        self.names, self.points = fold_landmarks(self.names, self.points, line, fold_number,
                                                 self.merge_distance)
        record = FoldRecord(moves=moves, crumpled=False, line=line)
        self.history.append(record)
        log.info("fold %d simulated: %s", fold_number, "; ".join(
            f"({g[0]:.3f}, {g[1]:.3f}) -> ({p[0]:.3f}, {p[1]:.3f})" for g, p in moves))
        return record

    def _never_lifted(self, peak_height: float | None) -> bool:
        """A grasp-to-release whose grippers rose no higher than this (m above the table) slid the
        garment; None: only the events were heard, no path (a fold, as events alone always were)."""
        return peak_height is not None and peak_height < self.config.fold_rules.drag_height

    def _slide(self, rotation: np.ndarray, shift: np.ndarray) -> None:
        """The garment slid along the table as it lay (x -> rotation x + shift, table frame): its flat
        pose, its landmarks by the fold convention and the folds done so far go with it."""
        def moved(points: np.ndarray) -> np.ndarray:
            return np.asarray(points, dtype=float) @ rotation.T + shift

        turn = float(np.arctan2(rotation[1, 0], rotation[0, 0]))
        log.info("the garment was dragged (%.3f, %.3f) m along the table, turned %.1f deg", *shift,
                 np.degrees(turn))
        g = self.garment
        self.garment = dataclasses.replace(
            g, landmarks=moved(g.landmarks), outline=moved(g.outline), centre=moved(g.centre),
            rotation=g.rotation + turn)
        self.points = moved(self.points)
        self._annotated_points = moved(self._annotated_points)
        self.layers = [Layer(moved(layer.polygon), layer.flipped) for layer in self.layers]
        for record in self.history:
            record.moves = [(moved(grasp), moved(place)) for grasp, place in record.moves]
            record.line = FoldLine(moved(record.line.point), rotation @ record.line.normal)

    def grasp_results(self) -> list[GraspResult]:
        """Physics world: every gripper closing simulated so far, and what it took."""
        if self.cloth is None:
            return []
        return [GraspResult(p.arm, bool(p.vertices), p.position[:2].copy() if p.vertices else None,
                            f"pinched {len(p.vertices)} cloth vertices" if p.vertices else
                            f"nothing under the fingers ({p.position[2]:.3f} m above the table)")
                for p in self.cloth.pinch_log]

    def _nearest_vertices(self, points: np.ndarray) -> np.ndarray:
        assert self.cloth is not None
        mesh_points = self.cloth.mesh.points
        return np.array([int(np.argmin(np.linalg.norm(mesh_points - p, axis=1))) for p in points])

    def landmark_vertices(self) -> dict[str, np.ndarray]:
        """Physics world: where each flat landmark's cloth vertex is now (table x, y, z, m), named as
        the cell names the flat garment."""
        if self.cloth is None:
            return {}
        self.catch_up()
        names, _ = self._as_seen_face_up()
        vertices = self.cloth.vertices
        return {name: vertices[v].copy() for name, v in zip(names, self._landmark_vertices, strict=True)}

    def layer_count(self) -> int:
        """The most layers of cloth stacked over one place (physics: the mesh; geometric: the layers)."""
        if self.cloth is None:
            return len(self.layers)
        self.catch_up()
        origin, size = self._cloth_area()
        return self.cloth.layer_count(origin, size)

    def _cloth_area(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """A table area that holds the cloth whatever is done to it (its flat outline grown by its
        own size)."""
        low, high = self.garment.outline.min(axis=0), self.garment.outline.max(axis=0)
        grow = float(np.max(high - low))
        return (float(low[0] - grow), float(low[1] - grow)), (float(high[0] - low[0] + 2 * grow),
                                                              float(high[1] - low[1] + 2 * grow))

    def _grasp(self, arm: str, xy: np.ndarray, height: float) -> GraspResult:
        ph = self.config.fold_rules
        if height > ph.grasp_height:
            return GraspResult(arm, False, None,
                               f"closed {height:.3f} m above the table (max {ph.grasp_height})")
        outline = self.silhouette()
        dist, near = point_segment_distance(xy[None], outline)
        inside = bool(points_in_polygon(xy[None], outline)[0])
        if dist[0] > ph.grasp_edge_distance:
            where = "inside" if inside else "outside"
            return GraspResult(arm, False, None, f"{dist[0]:.3f} m {where} the cloth's edge "
                                                 f"(max {ph.grasp_edge_distance})")
        point = xy.copy() if inside else near[0].copy()
        self._holds[arm] = _Hold(point)
        log.debug("%s grasped the cloth at %s", arm, point)
        return GraspResult(arm, True, point, "grasped")

    def holding(self) -> dict[str, np.ndarray]:
        """Arms currently holding cloth and the point each took (table frame)."""
        if self.cloth is not None:
            self.catch_up()
            return self.cloth.holding()
        return {a: h.point.copy() for a, h in self._holds.items() if h.place is None}

    # --- folding -----------------------------------------------------------------------------
    def apply_fold(self, moves: list[Move]) -> FoldRecord | None:
        """Fold by the moves (grasp, place) of one or more grippers at once."""
        moves = [(np.asarray(g, dtype=float), np.asarray(p, dtype=float)) for g, p in moves]
        moves = [(g, p) for g, p in moves if np.linalg.norm(g - p) > 1e-6]
        if not moves:
            return None
        if self.cloth is not None:
            assert self.physics is not None
            self.catch_up()
            before = self._cloth_outline()
            episode = self.cloth.fold_along(moves, self.physics.gripper.lift_fraction,
                                            self.physics.gripper.grasp_height)
            return None if episode is None else self._record_episode(episode, before)
        lines = [FoldLine.from_move(g, p) for g, p in moves]
        ph = self.config.fold_rules
        agree = lines_agree(lines, ph.agree_angle, ph.agree_offset)
        line = fold_line_of_moves(moves)
        self._annotate_fold(line, len(self.history) + 1)
        if agree:
            self.layers = fold_layers(self.layers, line)
        else:
            log.info("grippers disagree on the fold line: the fold crumples")
            self.layers = crumpled_fold_layers(self.layers, moves, ph.crumple, ph.crumple_noise,
                                               self._phys_rng)
        self.names, self.points = fold_landmarks(self.names, self.points, line, len(self.history) + 1,
                                                 self.merge_distance)
        record = FoldRecord(moves=moves, crumpled=not agree, line=line)
        self.history.append(record)
        return record

    def _annotate_fold(self, line: FoldLine, fold_number: int, before: np.ndarray | None = None) -> None:
        """The dataset's account of a fold (before it is applied): the fold line's two ends on the
        garment, named `fold_<k>` and put beside the nearest pair of consecutive nodes, then every node
        on the moving side reflected across the line (the fold's crumpling is not followed)."""
        names, points = self._annotated_names, self._annotated_points
        ends = fold_line_ends(self.silhouette() if before is None else before, line)
        # insert from the list's end so the earlier positions stay valid
        places = sorted(((*nearest_edge(points, end), k) for k, end in enumerate(ends)), reverse=True)
        for after, _, k in places:
            names.insert(after + 1, f"fold_{fold_number}")
            points = np.insert(points, after + 1, ends[k], axis=0)
        moving = line.side(points) > 0.0
        points[moving] = line.reflect(points[moving])
        self._annotated_points = points

    def _as_seen_face_up(self) -> tuple[list[str], np.ndarray]:
        """The flat garment's landmarks named as the cell names them, in model order: as if it lay face
        up (the outline cannot tell), so mirrored when it lies face down."""
        named = dict(zip(self.garment.names, self.garment.landmarks, strict=True))
        if self.garment.facing == "back":
            named = {mirror_name(name): point for name, point in named.items()}
        names = list(LANDMARKS[self.garment.category])
        return names, np.array([named[name] for name in names])

    # --- truth -------------------------------------------------------------------------------
    def truth_landmarks(self) -> dict[str, np.ndarray]:
        """Landmark name -> table-frame xy (m) of the current state, by the fold convention, named as
        the cell names them (mirrored for a garment lying face down; `annotated_nodes` has the
        garment's own sides)."""
        return {n: p.copy() for n, p in zip(self.names, self.points, strict=True)}

    def truth_polygon(self) -> tuple[list[str], np.ndarray]:
        """Landmark names and (N, 2) table-frame points in annotation order."""
        return list(self.names), self.points.copy()

    def flat_polygon(self) -> tuple[list[str], np.ndarray]:
        """The garment's landmarks before any fold, named as the cell names them (see `truth_landmarks`)."""
        return self._as_seen_face_up()

    def annotated_nodes(self) -> tuple[list[str], np.ndarray]:
        """The current state as the dataset annotates it (see the module docstring), table frame."""
        return list(self._annotated_names), self._annotated_points.copy()

    def silhouette(self) -> np.ndarray:
        """The current outline (union of the layers), (N, 2) table frame, clockwise seen from above."""
        if self.cloth is not None:
            self.catch_up()
            return self._cloth_outline()
        if len(self.layers) == 1:
            return self.layers[0].polygon.copy()
        return outline_of_union([la.polygon for la in self.layers], SILHOUETTE_RESOLUTION)

    def _cloth_outline(self) -> np.ndarray:
        """The cloth's outline as simulated so far (no catching up)."""
        assert self.cloth is not None
        polygon = self.cloth.silhouette(*self._cloth_area()).polygon
        return polygon if is_clockwise(polygon) else polygon[::-1]

    def layer_polygons(self) -> list[np.ndarray]:
        return [la.polygon.copy() for la in self.visible_layers()]

    def visible_layers(self) -> list[Layer]:
        """The garment as planar layers, lowest first (physics: pieces of the mesh facing alike)."""
        if self.cloth is None:
            return list(self.layers)
        self.catch_up()
        return self.cloth.render_layers(SILHOUETTE_RESOLUTION * 2)

    def ideal_folded_silhouette(self, folds: list[list[Move]] | None = None) -> np.ndarray:
        """Outline of the flat garment after perfect folds; each fold is a list of (grasp, place)
        moves sharing one line. Default: the folds applied so far, as their moves asked."""
        if folds is None:
            folds = [r.moves for r in self.history]
        layers = [Layer(self.garment.outline.copy())]
        for moves in folds:
            layers = fold_layers(layers, fold_line_of_moves(moves))
        return outline_of_union([la.polygon for la in layers], SILHOUETTE_RESOLUTION)

    def silhouette_iou(self, folds: list[list[Move]] | None = None) -> float:
        """IoU of the current silhouette and the ideal folded one."""
        layers = [Layer(self.garment.outline.copy())]
        for moves in folds if folds is not None else [r.moves for r in self.history]:
            layers = fold_layers(layers, fold_line_of_moves(moves))
        if self.cloth is not None:
            self.catch_up()
            seen = self.cloth.silhouette(*self._cloth_area())
            ideal = np.zeros_like(seen.mask)
            for layer in layers:
                ideal |= polygon_mask(layer.polygon, seen)
            return mask_iou(seen.mask, ideal)
        return iou([la.polygon for la in self.layers], [la.polygon for la in layers], SILHOUETTE_RESOLUTION)

    # --- images ------------------------------------------------------------------------------
    def render(self, camera_pose_world: np.ndarray | None = None) -> np.ndarray:
        """BGR uint8 image of the scene from the configured camera or the given 4x4 optical pose."""
        assert self.camera is not None   # set in __post_init__
        cam = self.camera if camera_pose_world is None else CameraModel(
            self.camera.config, pose_in_world=camera_pose_world, table=self.table)
        return self._renderer.render(self.visible_layers(), cam)

    def render_empty_table(self) -> np.ndarray:
        return self._renderer.render([], self.camera)
