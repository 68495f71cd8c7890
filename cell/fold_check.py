"""After a fold: what the garment should look like, and whether what the camera sees is that.

Pure functions of the perceptions before and after the fold and of the plan (no devices). Two
frames are in play on purpose: perception (models, folded models, the expected landmarks' names)
works in the image where the garment was seen, and comparisons across images work on the table,
because the next image may come from another camera pose (a wrist camera).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from cell.config import CellConfig
from cell.evaluation.fold_success import FoldScore, SuccessCriteria, score_seen
from cell.evaluation.ideal_fold import IdealFold
from cell.perception.errors import PerceptionError
from cell.perception.folded import derive_folded_model, folded_polygon
from cell.perception.geometry import polygon_edge_lengths, signed_area
from cell.perception.models import PolygonalModel
from cell.planning.folds import FoldLine, FoldPlan
from cell.reports import PerceptionReport

Points = NDArray[np.float64]


@dataclass(frozen=True)
class FoldExpectation:
    """The model to match after the fold, and where each of its landmarks should lie (table, m);
    `landmarks_table` is None when the fold's outline cannot be predicted."""

    model: PolygonalModel
    landmarks_table: dict[str, Points] | None


def expect_fold(model: PolygonalModel, before: PerceptionReport, plan: FoldPlan, fold_index: int,
                merge_fraction: float) -> FoldExpectation:
    """The folded model (paper Sec. III-F) and the expected landmarks, from the garment as matched in
    the image before the fold and the plan's first grasp and place points. Raises PerceptionError
    when no folded model can be derived."""
    grasp_px, place_px = before.camera.table_to_pixel(np.array([plan.grasp_points[0], plan.place_points[0]]))
    matched_px = np.array([before.landmarks_px[n] for n in model.names], dtype=float)
    folded = derive_folded_model(model, matched_px, (grasp_px, place_px), fold_index, merge_fraction)
    merge_distance = merge_fraction * float(polygon_edge_lengths(matched_px).sum())
    try:
        polygon_px, names = folded_polygon(matched_px, list(model.names), grasp_px, place_px, fold_index,
                                           merge_distance)
    except PerceptionError:
        return FoldExpectation(folded, None)
    table = before.camera.pixel_to_table(np.asarray(polygon_px, dtype=float))
    return FoldExpectation(folded, dict(zip(names, table, strict=True)))


@dataclass(frozen=True)
class FoldToCheck:
    """A fold whose grippers closed on the cloth, as its check needs it: what the fold should leave,
    and the outline and landmarks seen before it and its line (table, m). The job file keeps it until
    the fold is checked, so a restarted cell checks the fold its grippers were making."""

    expectation: FoldExpectation
    before_outline: Points
    before_landmarks: dict[str, tuple[float, float]]
    line: FoldLine


# --------------------------------------------------------------------------------- outlines on the table
def _raster(polygons: list[Points], origin: Points, size: NDArray[np.int_],
            resolution: float) -> NDArray[np.bool_]:
    mask = np.zeros((size[1], size[0]), np.uint8)
    for polygon in polygons:
        cv2.fillPoly(mask, [np.round((polygon - origin) / resolution).astype(np.int32)], 1)
    return mask.astype(bool)


def polygon_iou(a: Points, b: Points, resolution: float) -> float:
    """IoU of two polygons (same units) rasterised at `resolution` units per cell."""
    points = np.vstack([a, b])
    origin = points.min(axis=0) - resolution
    size = np.ceil((points.max(axis=0) + resolution - origin) / resolution).astype(int) + 1
    mask_a, mask_b = _raster([a], origin, size, resolution), _raster([b], origin, size, resolution)
    union = np.logical_or(mask_a, mask_b).sum()
    return float(np.logical_and(mask_a, mask_b).sum() / union) if union else 0.0


def folded_outline_iou(before: Points, after: Points, line: FoldLine, resolution: float) -> float:
    """IoU of the outline seen after a fold against the one seen before, folded ideally along the line.

    The part of `before` behind the line (against its normal) is reflected across it and laid on
    the rest: what a perfect fold shows, sleeves sticking out and all.
    """
    point, normal = np.asarray(line.point, dtype=float), np.asarray(line.normal, dtype=float)
    reflected = before - 2.0 * ((before - point) @ normal)[:, None] * normal
    points = np.vstack([before, after, reflected])
    origin = points.min(axis=0) - resolution
    size = np.ceil((points.max(axis=0) + resolution - origin) / resolution).astype(int) + 1
    previous = _raster([before], origin, size, resolution)
    rows, cols = np.nonzero(previous)
    cells = np.column_stack([cols, rows]) * resolution + origin
    side = (cells - point) @ normal
    moving = side < 0
    expected = np.zeros_like(previous)
    expected[rows[~moving], cols[~moving]] = True
    flipped = cells[moving] - 2.0 * side[moving][:, None] * normal
    index = np.round((flipped - origin) / resolution).astype(int)
    inside = (index[:, 0] >= 0) & (index[:, 0] < size[0]) & (index[:, 1] >= 0) & (index[:, 1] < size[1])
    expected[index[inside, 1], index[inside, 0]] = True
    # a reflected raster leaves pinholes where rounding skips a cell
    closed = cv2.morphologyEx(expected.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    expected = closed.astype(bool)
    seen = _raster([after], origin, size, resolution)
    union = np.logical_or(expected, seen).sum()
    return float(np.logical_and(expected, seen).sum() / union) if union else 0.0


def measure_seen(fold_index: int, before_landmarks: dict[str, tuple[float, float]],
                 expected: dict[str, Points] | None, after: PerceptionReport, after_table: Points,
                 line: FoldLine, criteria: SuccessCriteria) -> FoldScore | None:
    """The fold-success measure (cell/evaluation/fold_success.py) on the landmarks the camera saw:
    those matched after fold `fold_index` against where the plan's fold should have put the ones
    matched before it, the area of the outline seen against the expected one's (None: no expected
    outline to judge by)."""
    if not expected:
        return None
    expected_area = abs(signed_area(np.array(list(expected.values()), dtype=float)))
    if expected_area <= 0.0:
        return None
    ratio = abs(signed_area(after_table)) / expected_area
    fold = IdealFold(np.asarray(line.point, dtype=float), np.asarray(line.normal, dtype=float))
    return score_seen(fold_index, before_landmarks, expected, after.landmarks_table, fold, ratio, criteria)


@dataclass(frozen=True)
class FoldCheck:
    """`iou`: the outline after against the one before folded ideally. `unchanged_iou`: the outline
    after against the one before as it was (only measured when the fold looks wrong). `measure`: the
    fold-success measure on the landmarks seen (None: it could not be worked out)."""

    iou: float
    unchanged_iou: float | None
    verdict: str  # done | imperfect | did not take
    measure: FoldScore | None = None

    def outcome(self) -> str:
        return "done" if self.verdict == "done" else f"done, imperfect (IoU {self.iou:.2f})"


def check_fold(before_table: Points, after_table: Points, line: FoldLine, config: CellConfig,
               measure: FoldScore | None = None) -> FoldCheck:
    """Did the fold happen as planned (done: the outline as folded), not at all (did not take: the
    outline is unchanged, a grasp took no cloth), or otherwise (imperfect: the cloth moved, not as
    planned)? `measure` (the fold-success measure on the landmarks seen) is reported beside the
    verdict, not in it: it reads the folded model's names, and a corner the match misnames (a
    shirt's armpit 10 cm off with the outline perfect) would call a good fold bad."""
    iou = folded_outline_iou(before_table, after_table, line, config.verify_resolution_m)
    if iou >= config.verify_min_iou:
        return FoldCheck(iou, None, "done", measure)
    unchanged = polygon_iou(before_table, after_table, config.verify_resolution_m)
    verdict = "did not take" if unchanged >= config.unchanged_min_iou else "imperfect"
    return FoldCheck(iou, unchanged, verdict, measure)
