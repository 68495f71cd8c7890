"""The event-driven simulated garment world: one garment on the table, grasped and folded by grippers.

The cloth itself is a `ClothModel` (`drivers.sim.cloth_model`) of the world's `folding`: the geometric
one (`drivers.sim.geometric_model`: planar layers folded at once when the last holding gripper opens)
or the physics one (`drivers.sim.physics_model`: a cloth mesh simulated along the grippers' recorded
path). Each tells what a grasp, a release or a grasp-to-release did; the world accounts for every fold
and slide. Frames: gripper positions in `world`, everything else in `table` (m).

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
from drivers.robot.table import TableConfig, default_table_config
from drivers.sim.cloth_model import (
    SILHOUETTE_RESOLUTION,
    ClothModel,
    GraspResult,
    Handling,
    Move,
    nonzero_moves,
)
from drivers.sim.config import SimConfig, default_sim_config
from drivers.sim.errors import SimInputError
from drivers.sim.folding import Layer, fold_landmarks, fold_layers, fold_line_of_moves, outline_of_union
from drivers.sim.garments import Garment, make_garment
from drivers.sim.geometric_model import GeometricCloth
from drivers.sim.geometry import fold_line_ends, nearest_edge
from drivers.sim.physics.config import PhysicsConfig, load_physics_config
from drivers.sim.physics.garment import GarmentCloth
from drivers.sim.physics_model import PhysicsCloth
from drivers.sim.render import SceneRenderer, choose_appearance

log = logging.getLogger(__name__)

PLACEMENTS: tuple[str, ...] = ("cell", "table")

__all__ = ["PLACEMENTS", "SILHOUETTE_RESOLUTION", "FoldRecord", "GarmentWorld", "GraspResult", "Move"]


@dataclass
class FoldRecord:
    moves: list[Move]
    crumpled: bool
    line: FoldLine


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
        self.names, self.points = self._as_seen_face_up()
        self._annotated_names: list[str] = list(self.garment.node_names)
        self._annotated_points: np.ndarray = self.garment.nodes()
        self.merge_distance = self.config.fold_rules.merge_fraction * perimeter(self.garment.landmarks)
        self.cloth_model = self._cloth_model(np.random.default_rng(phys_ss))
        self.history: list[FoldRecord] = []
        appearance = choose_appearance(self.config.palette(self.category), self.config.render,
                                       self.garment.shape == "wrinkled", np.random.default_rng(look_ss))
        self.appearance = appearance
        self._renderer = SceneRenderer(self.config.render, self.table, appearance,
                                       int(np.random.default_rng(light_ss).integers(2**31)), self.camera)

    def _cloth_model(self, rng: np.random.Generator) -> ClothModel:
        """The cloth of the world's `folding`, the flat garment's (`rng` crumples geometric folds)."""
        if self.folding == "physics":
            if self.physics is None:
                self.physics = load_physics_config()
            return PhysicsCloth(self.garment, self.names, self.points, self.physics, self.config.fold_rules)
        if self.folding == "geometric":
            return GeometricCloth(self.garment.outline, self.config.fold_rules, rng)
        raise SimInputError(f"folding: must be physics or geometric, got {self.folding!r}")

    @property
    def cloth(self) -> GarmentCloth | None:
        """Physics world: the simulated cloth (None: the geometric world)."""
        return self.cloth_model.cloth

    @property
    def layers(self) -> list[Layer]:
        """Geometric world: the garment's layers, lowest first (physics: the flat garment as it lies)."""
        return self.cloth_model.layers

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
        position = np.array([xy[0], xy[1], pos[2] - self.table.height])
        outcome = self.cloth_model.gripper_event(arm, closed, position, robot_time)
        if isinstance(outcome, Handling):
            self._account(outcome)
            return None
        return outcome

    def gripper_heard(self, arm: str, robot_time: float) -> None:
        """Gripper `arm` was heard, unchanged, at `robot_time` (s): the physics world may simulate up to
        then (its events come apart from the joint states, and may come later)."""
        self.cloth_model.gripper_heard(arm, robot_time)

    def gripper_motion(self, robot_time: float, tcp_positions_world: dict[str, np.ndarray]) -> None:
        """Where every gripper's TCP is (m, world) at `robot_time` (s): the path the cloth follows
        while held (physics world; the geometric world keeps only how high a held point went)."""
        table = {}
        for arm, position in tcp_positions_world.items():
            xy = self.table.world_to_table(np.asarray(position, dtype=float))[0]
            table[arm] = np.array([xy[0], xy[1], float(position[2]) - self.table.height])
        self.cloth_model.gripper_motion(robot_time, table)

    def catch_up(self) -> list[FoldRecord]:
        """Physics world: simulate what has been recorded; the folds completed (empty: geometric)."""
        records: list[FoldRecord] = []
        for handling in self.cloth_model.catch_up():
            record = self._account(handling)
            if record is not None:
                records.append(record)
        return records

    def _account(self, handling: Handling) -> FoldRecord | None:
        """A grasp-to-release the cloth model has done: the garment slid, or a fold, accounted for by
        the fold convention and the dataset's annotation."""
        if handling.slide is not None:
            self._slide(*handling.slide)
            return None
        assert handling.line is not None   # a fold
        line, moves = handling.line, handling.moves
        fold_number = len(self.history) + 1
        self._annotate_fold(line, fold_number, handling.before)
        self.names, self.points = fold_landmarks(self.names, self.points, line, fold_number,
                                                 self.merge_distance)
        record = FoldRecord(moves=moves, crumpled=handling.crumpled, line=line)
        self.history.append(record)
        if handling.announce:
            log.info("fold %d simulated: %s", fold_number, "; ".join(
                f"({g[0]:.3f}, {g[1]:.3f}) -> ({p[0]:.3f}, {p[1]:.3f})" for g, p in moves))
        return record

    def _slide(self, rotation: np.ndarray, shift: np.ndarray) -> None:
        """The garment slid along the table as it lay (x -> rotation x + shift, table frame): its flat
        pose, its landmarks by the fold convention, the folds done so far and the cloth go with it."""
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
        self.cloth_model.slide(moved)
        for record in self.history:
            record.moves = [(moved(grasp), moved(place)) for grasp, place in record.moves]
            record.line = FoldLine(moved(record.line.point), rotation @ record.line.normal)

    def grasp_results(self) -> list[GraspResult]:
        """Physics world: every gripper closing simulated so far, and what it took."""
        return self.cloth_model.grasp_results()

    def landmark_vertices(self) -> dict[str, np.ndarray]:
        """Physics world: where each flat landmark's cloth vertex is now (table x, y, z, m), named as
        the cell names the flat garment."""
        self.catch_up()
        names, _ = self._as_seen_face_up()
        return self.cloth_model.landmark_vertices(names)

    def layer_count(self) -> int:
        """The most layers of cloth stacked over one place (physics: the mesh; geometric: the layers)."""
        self.catch_up()
        return self.cloth_model.layer_count()

    def holding(self) -> dict[str, np.ndarray]:
        """Arms currently holding cloth and the point each took (table frame)."""
        self.catch_up()
        return self.cloth_model.holding()

    # --- folding -----------------------------------------------------------------------------
    def apply_fold(self, moves: list[Move]) -> FoldRecord | None:
        """Fold by the moves (grasp, place) of one or more grippers at once."""
        moves = nonzero_moves(moves)
        if not moves:
            return None
        self.catch_up()
        handling = self.cloth_model.fold(moves)
        return None if handling is None else self._account(handling)

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
        self.catch_up()
        return self.cloth_model.silhouette()

    def layer_polygons(self) -> list[np.ndarray]:
        return [la.polygon.copy() for la in self.visible_layers()]

    def visible_layers(self) -> list[Layer]:
        """The garment as planar layers, lowest first (physics: pieces of the mesh facing alike)."""
        self.catch_up()
        return self.cloth_model.visible_layers()

    def _ideal_layers(self, folds: list[list[Move]] | None) -> list[Layer]:
        """The flat garment's layers after perfect folds (default: the folds applied so far, as their
        moves asked)."""
        layers = [Layer(self.garment.outline.copy())]
        for moves in folds if folds is not None else [r.moves for r in self.history]:
            layers = fold_layers(layers, fold_line_of_moves(moves))
        return layers

    def ideal_folded_silhouette(self, folds: list[list[Move]] | None = None) -> np.ndarray:
        """Outline of the flat garment after perfect folds; each fold is a list of (grasp, place)
        moves sharing one line. Default: the folds applied so far, as their moves asked."""
        return outline_of_union([la.polygon for la in self._ideal_layers(folds)], SILHOUETTE_RESOLUTION)

    def silhouette_iou(self, folds: list[list[Move]] | None = None) -> float:
        """IoU of the current silhouette and the ideal folded one."""
        layers = self._ideal_layers(folds)
        self.catch_up()
        return self.cloth_model.iou(layers)

    # --- images ------------------------------------------------------------------------------
    def render(self, camera_pose_world: np.ndarray | None = None) -> np.ndarray:
        """BGR uint8 image of the scene from the configured camera or the given 4x4 optical pose."""
        assert self.camera is not None   # set in __post_init__
        cam = self.camera if camera_pose_world is None else CameraModel(
            self.camera.config, pose_in_world=camera_pose_world, table=self.table)
        return self._renderer.render(self.visible_layers(), cam)

    def render_empty_table(self) -> np.ndarray:
        return self._renderer.render([], self.camera)
