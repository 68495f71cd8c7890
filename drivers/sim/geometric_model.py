"""The geometric world's cloth: planar layers, folded at once when the last holding gripper opens.

Grasp: a gripper that closes at most `fold_rules.grasp_height` above the table top and within
`fold_rules.grasp_edge_distance` of the cloth's outline takes the cloth point under it (or the nearest
outline point when it closed just outside); otherwise it takes nothing. Release: when the last holding
gripper opens, the moves fold the layers along the line they imply; two grippers whose moves disagree
on one fold line (beyond `agree_angle`/`agree_offset`) give a crumpled, wrong fold. Grippers that never
rose above `drag_height` while holding slid the garment instead. Fast: for unit tests and datasets.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from drivers.common.plane import FoldLine
from drivers.sim.cloth_model import (
    SILHOUETTE_RESOLUTION,
    ClothModel,
    GraspResult,
    Handling,
    Motion,
    Move,
    nonzero_moves,
)
from drivers.sim.config import FoldRulesConfig
from drivers.sim.folding import (
    Layer,
    crumpled_fold_layers,
    fold_layers,
    fold_line_of_moves,
    iou,
    lines_agree,
    outline_of_union,
)
from drivers.sim.geometry import point_segment_distance, points_in_polygon, rigid_fit

log = logging.getLogger(__name__)


@dataclass
class _Hold:
    point: np.ndarray
    place: np.ndarray | None = None
    peak: float | None = None   # m above the table: the highest the gripper went while holding
                                # (None: no motion heard, only the events)


class GeometricCloth(ClothModel):
    """The garment as planar layers (flat: its `outline`), folded by `rules`; `rng` crumples."""

    def __init__(self, outline: np.ndarray, rules: FoldRulesConfig, rng: np.random.Generator):
        super().__init__(rules)
        self._layers = [Layer(outline.copy())]
        self._rng = rng
        self._holds: dict[str, _Hold] = {}

    @property
    def layers(self) -> list[Layer]:
        return self._layers

    def gripper_event(self, arm: str, closed: bool, position: np.ndarray,
                      robot_time: float | None) -> GraspResult | Handling | None:
        xy, height = position[:2], position[2]
        hold = self._holds.get(arm)
        if closed:
            if hold is not None and hold.place is None:
                return None                      # already closed on the cloth
            return self._grasp(arm, xy, height)
        if hold is None or hold.place is not None:
            return None
        hold.place = xy
        if not all(h.place is not None for h in self._holds.values()):
            return None
        moves = [(h.point, h.place) for h in self._holds.values() if h.place is not None]
        peaks = [h.peak for h in self._holds.values()]
        self._holds.clear()
        if all(self.never_lifted(peak) for peak in peaks):
            # slid along the table (a pull into reach), as the held points moved
            return Handling(moves, slide=rigid_fit(np.array([g for g, _ in moves]),
                                                   np.array([p for _, p in moves])))
        moves = nonzero_moves(moves)
        return self.fold(moves) if moves else None

    def gripper_heard(self, arm: str, robot_time: float) -> None:
        """Nothing to simulate: the events alone fold."""

    def gripper_motion(self, robot_time: float, positions: dict[str, np.ndarray]) -> None:
        """Keeps only how high a held point went."""
        for arm, position in positions.items():
            hold = self._holds.get(arm)
            if hold is not None and hold.place is None:
                height = float(position[2])
                hold.peak = height if hold.peak is None else max(hold.peak, height)

    def _grasp(self, arm: str, xy: np.ndarray, height: float) -> GraspResult:
        ph = self.rules
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

    def fold(self, moves: list[Move]) -> Handling:
        lines = [FoldLine.from_move(g, p) for g, p in moves]
        ph = self.rules
        agree = lines_agree(lines, ph.agree_angle, ph.agree_offset)
        line = fold_line_of_moves(moves)
        before = self.silhouette()
        if agree:
            self._layers = fold_layers(self._layers, line)
        else:
            log.info("grippers disagree on the fold line: the fold crumples")
            self._layers = crumpled_fold_layers(self._layers, moves, ph.crumple, ph.crumple_noise, self._rng)
        return Handling(moves, line=line, crumpled=not agree, before=before)

    def slide(self, moved: Motion) -> None:
        self._layers = [Layer(moved(layer.polygon), layer.flipped) for layer in self._layers]

    def holding(self) -> dict[str, np.ndarray]:
        return {a: h.point.copy() for a, h in self._holds.items() if h.place is None}

    def layer_count(self) -> int:
        return len(self._layers)

    def silhouette(self) -> np.ndarray:
        """The union of the layers."""
        if len(self._layers) == 1:
            return self._layers[0].polygon.copy()
        return outline_of_union([la.polygon for la in self._layers], SILHOUETTE_RESOLUTION)

    def visible_layers(self) -> list[Layer]:
        return list(self._layers)

    def iou(self, ideal: list[Layer]) -> float:
        return iou([la.polygon for la in self._layers], [la.polygon for la in ideal], SILHOUETTE_RESOLUTION)
