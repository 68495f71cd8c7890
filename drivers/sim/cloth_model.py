"""What a simulated world's cloth is to the world: one interface, two kinds.

`GarmentWorld` keeps the account of the folds (the landmarks by the fold convention, the dataset's
annotation, the history, the garment's flat pose); a `ClothModel` keeps the cloth itself: where it
lies, what the grippers hold, what a grasp-to-release did to it. The geometric model
(`drivers.sim.geometric_model`) folds planar layers at once on the gripper events; the physics model
(`drivers.sim.physics_model`) simulates a cloth mesh along the grippers' recorded path when somebody
looks. A grasp-to-release comes back to the world as a `Handling`: a slide of the whole garment along
the table or a fold, already done to the cloth, for the world to account for.

Frames: everything in `table` (m); a gripper's position is its table x, y and its height above the
table top.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from drivers.common.plane import FoldLine
from drivers.sim.config import FoldRulesConfig
from drivers.sim.folding import Layer
from drivers.sim.physics.garment import GarmentCloth

Move = tuple[np.ndarray, np.ndarray]   # (grasp xy, place xy) in the table frame
Motion = Callable[[np.ndarray], np.ndarray]   # points moved as the garment slid (table frame)

# resolution of silhouettes and IoU (m per cell)
SILHOUETTE_RESOLUTION = 0.001


@dataclass(frozen=True)
class GraspResult:
    arm: str
    grasped: bool
    point: np.ndarray | None      # the cloth point taken (table frame), None when missed
    reason: str


@dataclass(frozen=True)
class Handling:
    """A grasp-to-release the cloth model has carried out. Never lifted, the garment slid as it lay:
    `slide` is its rigid move (rotation, shift: x -> rotation x + shift); else it was folded along
    `line` by `moves`, `crumpled` when the grippers disagreed, from the outline `before` (None: the
    world's silhouette now). `announce`: log the fold (the simulated world's folds are news)."""

    moves: list[Move]
    slide: tuple[np.ndarray, np.ndarray] | None = None
    line: FoldLine | None = None
    crumpled: bool = False
    before: np.ndarray | None = None
    announce: bool = False


def nonzero_moves(moves: list[Move]) -> list[Move]:
    """The moves (as float arrays) that move their point at all."""
    moves = [(np.asarray(g, dtype=float), np.asarray(p, dtype=float)) for g, p in moves]
    return [(g, p) for g, p in moves if np.linalg.norm(g - p) > 1e-6]


class ClothModel(ABC):
    """The garment's cloth in one kind of simulated world, by the world's fold `rules`."""

    def __init__(self, rules: FoldRulesConfig):
        self.rules = rules

    def never_lifted(self, peak_height: float | None) -> bool:
        """A grasp-to-release whose grippers rose no higher than `peak_height` (m above the table) slid
        the garment; None: only the events were heard, no path (a fold, as events alone always were)."""
        return peak_height is not None and peak_height < self.rules.drag_height

    @property
    @abstractmethod
    def layers(self) -> list[Layer]:
        """The geometric world's layers (the physics world's: the flat garment as it lies)."""

    @property
    def cloth(self) -> GarmentCloth | None:
        """The simulated cloth mesh (None: the world has none)."""
        return None

    @abstractmethod
    def gripper_event(self, arm: str, closed: bool, position: np.ndarray,
                      robot_time: float | None) -> GraspResult | Handling | None:
        """Gripper `arm` closed or opened at `position` (table x, y, height): what it took when the
        model knows at once, or the grasp-to-release it ended."""

    @abstractmethod
    def gripper_heard(self, arm: str, robot_time: float) -> None:
        """Gripper `arm` was heard, unchanged, at `robot_time` (s)."""

    @abstractmethod
    def gripper_motion(self, robot_time: float, positions: dict[str, np.ndarray]) -> None:
        """Every gripper's position (table x, y, height) at `robot_time` (s)."""

    def catch_up(self) -> Iterator[Handling]:
        """Simulate what has been recorded, lazily: each grasp-to-release as it is done (the world
        accounts for one, a slide moving the garment, before the next is simulated)."""
        return iter(())

    @abstractmethod
    def fold(self, moves: list[Move]) -> Handling | None:
        """Fold by the moves (grasp, place; none of zero length) of one or more grippers at once."""

    @abstractmethod
    def slide(self, moved: Motion) -> None:
        """The garment slid along the table as it lay: what the model keeps of it goes along."""

    @abstractmethod
    def holding(self) -> dict[str, np.ndarray]:
        """Arms holding cloth and the point each took (table frame)."""

    def grasp_results(self) -> list[GraspResult]:
        """Every gripper closing simulated so far, and what it took (none told apart: empty)."""
        return []

    def landmark_vertices(self, names: list[str]) -> dict[str, np.ndarray]:
        """Where each flat landmark's cloth vertex is now (table x, y, z), `names` in model order
        (no mesh: empty)."""
        return {}

    @abstractmethod
    def layer_count(self) -> int:
        """The most layers of cloth stacked over one place."""

    @abstractmethod
    def silhouette(self) -> np.ndarray:
        """The current outline, (N, 2) table frame, clockwise seen from above."""

    @abstractmethod
    def visible_layers(self) -> list[Layer]:
        """The garment as planar layers, lowest first."""

    @abstractmethod
    def iou(self, ideal: list[Layer]) -> float:
        """IoU of the cloth as it lies now and the `ideal` layers."""
