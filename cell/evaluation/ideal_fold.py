"""The ideal result of folding a garment, from its true flat landmarks: the reference a fold is scored by.

Written from the fold recipes' intent, in words, and sharing no code with the planner or the
simulated world but the plane geometry all of them use (`drivers.common.plane`: a reflection across
a line), so a wrong recipe geometry or a wrong fold in the world does not move the reference with
it. Each fold is a line across the garment and the side that moves: everything on that side is
reflected across the line onto the rest (a perfect flat fold, sleeves and all).

- towel: the bottom half onto the top (the line through the middles of the left and right
  edges), then the left half onto the right.
- pants: the left leg onto the right (the centre line, through the middle of the waist and the
  middle between the two outer hems), then the hems onto the waist, stopping 5 % short.
- shirts: the left side with its sleeve folds in along the line a quarter of the way from the left
  side to the right side; the right side with its sleeve goes 70 % of the way to that first line;
  then the bottom onto the top, 95 % of the way from the bottom edge to the shoulders.

Landmarks are in the table frame (m); the outline is the garment's true flat outline there.

A recipe names sides, and the cell can only name them as it sees them: a towel has no top (any of
its corners may be called `bottom-left`, a quarter turn of the names as good as another), and a
garment lying face down is seen mirrored (its left side is folded where a face-up one's right side
would be). Each of these namings is an ideal fold as good as the others: the score is the best.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.common.garments import LANDMARKS, mirror_name
from drivers.common.plane import FoldLine, mask_iou

Points = NDArray[np.float64]


@dataclass(frozen=True)
class IdealFold:
    """A straight fold: `normal` (unit) points from the side that moves to the side that stays, the
    way the fold carries it (the reverse of its `line`'s, a `FoldLine` whose normal points to the
    side that moves)."""

    point: Points
    normal: Points

    @staticmethod
    def of(line: FoldLine) -> IdealFold:
        """The fold along a `FoldLine` (a planned one)."""
        return IdealFold(np.asarray(line.point, dtype=float), -np.asarray(line.normal, dtype=float))

    @property
    def line(self) -> FoldLine:
        """The fold's line: `side` > 0 on the side that moves, `reflect` across it."""
        return FoldLine(np.asarray(self.point, dtype=float), -np.asarray(self.normal, dtype=float))


def _fold_between(moving: Points, target: Points, share: float) -> IdealFold:
    """The fold that carries `moving` `share` of the way to `target` (the line halfway there)."""
    direction = target - moving
    length = float(np.linalg.norm(direction))
    if length < 1e-9:
        raise ValueError("the side to fold and its target coincide")
    return IdealFold(moving + 0.5 * share * direction, direction / length)


def _crossing(fold: IdealFold, a: Points, b: Points) -> Points:
    """Where the fold line crosses the line through a and b."""
    along = b - a
    denominator = float(np.dot(along, fold.normal))
    if abs(denominator) < 1e-12:
        raise ValueError("the fold line runs along the edge it should cross")
    return a + along * float(np.dot(fold.point - a, fold.normal)) / denominator


def towel_folds(lm: Mapping[str, Points]) -> list[IdealFold]:
    left_middle = (lm["bottom-left"] + lm["top-left"]) / 2
    right_middle = (lm["bottom-right"] + lm["top-right"]) / 2
    bottom = (lm["bottom-left"] + lm["bottom-right"]) / 2
    top = (lm["top-left"] + lm["top-right"]) / 2
    first = _fold_between(bottom, top, 1.0)
    # the top half that is left: its left edge (top-left to the middle of the left edge) onto its right
    second = _fold_between((lm["top-left"] + left_middle) / 2, (lm["top-right"] + right_middle) / 2, 1.0)
    return [first, second]


def pants_folds(lm: Mapping[str, Points]) -> list[IdealFold]:
    left = (lm["top-left"] + lm["left-leg-outer"]) / 2
    right = (lm["top-right"] + lm["right-leg-outer"]) / 2
    first = _fold_between(left, right, 1.0)
    waist_middle = _crossing(first, lm["top-left"], lm["top-right"])
    hem = (lm["right-leg-outer"] + lm["right-leg-inner"]) / 2
    waist = (lm["top-right"] + waist_middle) / 2
    return [first, _fold_between(hem, waist, 0.95)]


def shirt_folds(lm: Mapping[str, Points]) -> list[IdealFold]:
    left_side = (lm["bottom-left"] + lm["left-shoulder"]) / 2
    right_side = (lm["bottom-right"] + lm["right-shoulder"]) / 2
    first = _fold_between(left_side, right_side, 0.5)
    bottom_edge = (lm["bottom-left"], lm["bottom-right"])
    shoulder_line = (lm["left-shoulder"], lm["right-shoulder"])
    first_bottom, first_top = _crossing(first, *bottom_edge), _crossing(first, *shoulder_line)
    second = _fold_between(right_side, (first_bottom + first_top) / 2, 0.7)
    second_bottom, second_top = _crossing(second, *bottom_edge), _crossing(second, *shoulder_line)
    third = _fold_between((first_bottom + second_bottom) / 2, (first_top + second_top) / 2, 0.95)
    return [first, second, third]


FOLDS_OF = {
    "towel": towel_folds,
    "pants": pants_folds,
    "short-sleeve": shirt_folds,
    "long-sleeve": shirt_folds,
}


def ideal_folds(category: str, landmarks: Mapping[str, Sequence[float] | Points]) -> list[IdealFold]:
    """Every fold of the category's recipe, from the true flat landmarks."""
    if category not in FOLDS_OF:
        raise ValueError(f"category: no ideal folds for {category!r} (have {', '.join(FOLDS_OF)})")
    return FOLDS_OF[category]({n: np.asarray(p, dtype=float) for n, p in landmarks.items()})


@dataclass(frozen=True)
class Grid:
    """A raster over the table: cell (row, col) covers origin + (col, row) * resolution."""

    origin: Points
    resolution: float
    shape: tuple[int, int]

    @staticmethod
    def around(outline: Points, resolution: float) -> Grid:
        """Room for the outline and anything a fold can reflect out of it."""
        low, high = outline.min(axis=0), outline.max(axis=0)
        margin = high - low
        size = np.ceil((high - low + 2 * margin) / resolution).astype(int) + 1
        return Grid(low - margin, resolution, (int(size[1]), int(size[0])))

    def fill(self, polygons: Sequence[Points]) -> NDArray[np.bool_]:
        mask = np.zeros(self.shape, np.uint8)
        for polygon in polygons:
            cells = np.round((np.asarray(polygon, dtype=float) - self.origin) / self.resolution)
            cv2.fillPoly(mask, [cells.astype(np.int32)], 1)
        return mask.astype(bool)


def fold_mask(mask: NDArray[np.bool_], fold: IdealFold, grid: Grid) -> NDArray[np.bool_]:
    """The mask after one perfect fold: the moving side reflected across the line onto the rest."""
    rows, cols = np.nonzero(mask)
    centres = np.column_stack([cols, rows]) * grid.resolution + grid.origin
    line = fold.line
    moving = line.side(centres) > 0
    out = np.zeros_like(mask)
    out[rows[~moving], cols[~moving]] = True
    reflected = line.reflect(centres[moving])
    cells = np.round((reflected - grid.origin) / grid.resolution).astype(int)
    rows_count, cols_count = grid.shape
    inside = ((cells[:, 0] >= 0) & (cells[:, 0] < cols_count)
              & (cells[:, 1] >= 0) & (cells[:, 1] < rows_count))
    out[cells[inside, 1], cells[inside, 0]] = True
    # a reflected raster leaves pinholes where rounding skips a cell
    closed = cv2.morphologyEx(out.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    return closed.astype(bool)


def relabellings(category: str) -> list[dict[str, str]]:
    """The ways the cell may name a garment's landmarks (see above), each as label -> true name."""
    names = LANDMARKS[category]
    if category == "towel":
        return [{name: names[(i + turn) % 4] for i, name in enumerate(names)} for turn in range(4)]
    return [{name: name for name in names}, {mirror_name(name): name for name in names}]


def namings(category: str, landmarks: Mapping[str, Sequence[float] | Points]) -> list[dict[str, Points]]:
    """The true landmarks under each of the `relabellings`, each as good as the others."""
    points = {n: np.asarray(p, dtype=float) for n, p in landmarks.items()}
    return [{label: points[true] for label, true in labels.items() if true in points}
            for labels in relabellings(category)]


def ideal_fold_iou(category: str, landmarks: Mapping[str, Sequence[float]], outline: Points,
                   folds_done: int, seen: Sequence[Points], resolution: float = 0.001) -> float:
    """IoU of what is seen (polygons, table frame, e.g. a garment's layers) with the true flat
    garment folded perfectly `folds_done` times by its category's recipe (under the best naming)."""
    every_fold = len(ideal_folds(category, landmarks))
    if not 0 <= folds_done <= every_fold:
        raise ValueError(f"folds_done: must be 0..{every_fold} for {category}, got {folds_done}")
    flat = np.asarray(outline, dtype=float)
    grid = Grid.around(flat, resolution)
    actual = grid.fill(seen)
    best = 0.0
    for named in namings(category, landmarks):
        ideal = grid.fill([flat])
        for fold in ideal_folds(category, named)[:folds_done]:
            ideal = fold_mask(ideal, fold, grid)
        best = max(best, mask_iou(ideal, actual))
    return best
