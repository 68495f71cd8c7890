"""The physics world's cloth: a mesh the grippers drag and fold along their recorded path.

The gripper events and positions are recorded as they come (`drivers.sim.physics.garment`) and
simulated when somebody looks (`catch_up`); what a gripper took is known once simulated. A
grasp-to-release that moved cloth is a fold, its line from where the grippers closed and opened,
unless the grippers never rose above `fold_rules.drag_height`: then the garment slid as its cloth
moved.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator

import numpy as np

from drivers.common.plane import mask_iou
from drivers.robot.config import load_robot_config
from drivers.sim.cloth_model import SILHOUETTE_RESOLUTION, ClothModel, GraspResult, Handling, Motion, Move
from drivers.sim.config import FoldRulesConfig
from drivers.sim.errors import SimInputError
from drivers.sim.folding import Layer, fold_line_of_moves, recipe_moves
from drivers.sim.garments import Garment
from drivers.sim.geometry import is_clockwise, rigid_fit
from drivers.sim.physics.cloth import polygon_mask
from drivers.sim.physics.config import PhysicsConfig
from drivers.sim.physics.garment import Episode, GarmentCloth

log = logging.getLogger(__name__)


class PhysicsCloth(ClothModel):
    """The cloth of `garment` (its landmarks `points`, named `names` as the cell names them) by
    `physics`; `rules` tell a drag from a fold."""

    def __init__(self, garment: Garment, names: list[str], points: np.ndarray, physics: PhysicsConfig,
                 rules: FoldRulesConfig):
        super().__init__(rules)
        self.physics = physics
        # the flat garment as it lies (slid along with it): the area the cloth stays in follows it
        self._flat = Layer(garment.outline.copy())
        arms = tuple(arm.name for arm in load_robot_config().arms)
        landmark_at = [int(np.argmin(np.linalg.norm(garment.outline - p, axis=1))) for p in garment.landmarks]
        creases = tuple(fold_line_of_moves(moves) for moves in recipe_moves(
            garment.category, dict(zip(names, points, strict=True)))) if physics.cloth.crease_lines else ()
        self._cloth = GarmentCloth(garment.outline, physics, arms, landmark_at, creases)
        mesh_points = self._cloth.mesh.points
        self._landmark_vertices = np.array([int(np.argmin(np.linalg.norm(mesh_points - p, axis=1)))
                                            for p in points])

    @property
    def cloth(self) -> GarmentCloth:
        return self._cloth

    @property
    def layers(self) -> list[Layer]:
        return [self._flat]

    def gripper_event(self, arm: str, closed: bool, position: np.ndarray,
                      robot_time: float | None) -> GraspResult | Handling | None:
        """Recorded: what the gripper took is known once `catch_up` has simulated it."""
        if robot_time is None:
            raise SimInputError("robot_time: the physics world needs the time of a gripper event")
        self._cloth.record_gripper(robot_time, arm, closed, position)
        return None

    def gripper_heard(self, arm: str, robot_time: float) -> None:
        """The world may simulate up to then (its events come apart from the joint states, and may
        come later)."""
        self._cloth.record_heard(arm, robot_time)

    def gripper_motion(self, robot_time: float, positions: dict[str, np.ndarray]) -> None:
        """The path the cloth follows while held."""
        self._cloth.record_motion(robot_time, positions)

    def catch_up(self) -> Iterator[Handling]:
        while self._cloth.busy():
            before = None if self._cloth.holding() else self._outline()
            episode = self._cloth.catch_up()
            if episode is None:
                break
            handling = self._handling(episode, before)
            if handling is not None:
                yield handling

    def _handling(self, episode: Episode, before: np.ndarray | None) -> Handling | None:
        """A simulated grasp-to-release that moved cloth: its line from where the grippers closed and
        opened, or the garment's slide as its cloth moved."""
        moves = [(g, p) for g, p in episode.moves if np.linalg.norm(g - p) > 1e-6]
        for pinch in episode.pinches:
            log.info("%s closed at robot time %.3f s at table (%.3f, %.3f, %.3f) m: %d cloth vertices",
                     pinch.arm, pinch.time, *pinch.position, len(pinch.vertices))
        if not moves:
            log.info("a grasp-to-release moved no cloth")
            return None
        if self.never_lifted(episode.peak_height):
            # the garment slid along the table (a pull into reach), as its cloth moved
            return Handling(moves, slide=rigid_fit(episode.start_xy, self._cloth.vertices[:, :2]))
        return Handling(moves, line=fold_line_of_moves(moves), before=before, announce=True)

    def fold(self, moves: list[Move]) -> Handling | None:
        """The grippers take the cloth at the grasps and lay it at the places (the world has caught up)."""
        before = self._outline()
        episode = self._cloth.fold_along(moves, self.physics.gripper.lift_fraction,
                                         self.physics.gripper.grasp_height)
        return None if episode is None else self._handling(episode, before)

    def slide(self, moved: Motion) -> None:
        self._flat = Layer(moved(self._flat.polygon), self._flat.flipped)

    def holding(self) -> dict[str, np.ndarray]:
        return self._cloth.holding()

    def grasp_results(self) -> list[GraspResult]:
        return [GraspResult(p.arm, bool(p.vertices), p.position[:2].copy() if p.vertices else None,
                            f"pinched {len(p.vertices)} cloth vertices" if p.vertices else
                            f"nothing under the fingers ({p.position[2]:.3f} m above the table)")
                for p in self._cloth.pinch_log]

    def landmark_vertices(self, names: list[str]) -> dict[str, np.ndarray]:
        vertices = self._cloth.vertices
        return {name: vertices[v].copy() for name, v in zip(names, self._landmark_vertices, strict=True)}

    def layer_count(self) -> int:
        return self._cloth.layer_count(*self._area())

    def _area(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """A table area that holds the cloth whatever is done to it (its flat outline grown by its
        own size)."""
        outline = self._flat.polygon
        low, high = outline.min(axis=0), outline.max(axis=0)
        grow = float(np.max(high - low))
        return (float(low[0] - grow), float(low[1] - grow)), (float(high[0] - low[0] + 2 * grow),
                                                              float(high[1] - low[1] + 2 * grow))

    def silhouette(self) -> np.ndarray:
        return self._outline()

    def _outline(self) -> np.ndarray:
        """The cloth's outline as simulated so far (no catching up)."""
        polygon = self._cloth.silhouette(*self._area()).polygon
        return polygon if is_clockwise(polygon) else polygon[::-1]

    def visible_layers(self) -> list[Layer]:
        """Pieces of the mesh facing alike."""
        return self._cloth.render_layers(SILHOUETTE_RESOLUTION * 2)

    def iou(self, ideal: list[Layer]) -> float:
        seen = self._cloth.silhouette(*self._area())
        mask = np.zeros_like(seen.mask)
        for layer in ideal:
            mask |= polygon_mask(layer.polygon, seen)
        return mask_iou(seen.mask, mask)
