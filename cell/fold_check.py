"""After a fold: what the garment should look like, and whether what the camera sees is that.

Pure functions of the perceptions before and after the fold and of the plan (no devices). Two
frames are in play on purpose: perception (models, folded models, the expected landmarks' names)
works in the image where the garment was seen, and comparisons across images work on the table,
because the next image may come from another camera pose (a wrist camera).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cell.config import CellConfig
from cell.evaluation.fold_success import FoldScore, SuccessCriteria, score_seen
from cell.evaluation.ideal_fold import Grid, IdealFold, fold_mask
from cell.perception.errors import PerceptionError
from cell.perception.folded import derive_folded_model, folded_polygon
from cell.perception.models import PolygonalModel
from cell.planning.folds import FoldPlan
from cell.reports import PerceptionReport
from drivers.common.landmarks import TABLE, Landmarks
from drivers.common.outcomes import FoldOutcome
from drivers.common.plane import FoldLine, mask_iou, perimeter, signed_area

Points = NDArray[np.float64]


@dataclass(frozen=True)
class FoldExpectation:
    """The model to match after the fold, and where each of its landmarks should lie (table, m);
    `landmarks_table` is None when the fold's outline cannot be predicted."""

    model: PolygonalModel
    landmarks_table: Landmarks | None


def expect_fold(model: PolygonalModel, before: PerceptionReport, plan: FoldPlan, fold_index: int,
                merge_fraction: float) -> FoldExpectation:
    """The folded model (paper Sec. III-F) and the expected landmarks, from the garment as matched in
    the image before the fold and the plan's first grasp and place points. Raises PerceptionError
    when no folded model can be derived."""
    grasp_px, place_px = before.camera.table_to_pixel(np.array([plan.grasp_points[0], plan.place_points[0]]))
    matched_px = np.array([before.landmarks_px[n] for n in model.names], dtype=float)
    folded = derive_folded_model(model, matched_px, (grasp_px, place_px), fold_index, merge_fraction)
    merge_distance = merge_fraction * perimeter(matched_px)
    try:
        polygon_px, names = folded_polygon(matched_px, list(model.names), grasp_px, place_px, fold_index,
                                           merge_distance)
    except PerceptionError:
        return FoldExpectation(folded, None)
    table = before.camera.pixel_to_table(np.asarray(polygon_px, dtype=float))
    return FoldExpectation(folded, Landmarks(TABLE, names, table))


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
def _grid(points: Points, resolution: float) -> Grid:
    """A raster at `resolution` units per cell over `points`, a cell to spare round them."""
    origin = points.min(axis=0) - resolution
    size = np.ceil((points.max(axis=0) + resolution - origin) / resolution).astype(int) + 1
    return Grid(origin, resolution, (int(size[1]), int(size[0])))


def polygon_iou(a: Points, b: Points, resolution: float) -> float:
    """IoU of two polygons (same units) rasterised at `resolution` units per cell."""
    grid = _grid(np.vstack([a, b]), resolution)
    return mask_iou(grid.fill([a]), grid.fill([b]))


def folded_outline_iou(before: Points, after: Points, line: FoldLine, resolution: float) -> float:
    """IoU of the outline seen after a fold against the one seen before, folded ideally along the line.

    The part of `before` on the line's moving side is reflected across it and laid on the rest
    (`ideal_fold.fold_mask`): what a perfect fold shows, sleeves sticking out and all.
    """
    grid = _grid(np.vstack([before, after, line.reflect(before)]), resolution)
    return mask_iou(fold_mask(grid.fill([before]), IdealFold.of(line), grid), grid.fill([after]))


def measure_seen(fold_index: int, before_landmarks: Mapping[str, tuple[float, float]],
                 expected: Landmarks | None, after: PerceptionReport, after_table: Points,
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
    fold = IdealFold.of(line)
    return score_seen(fold_index, before_landmarks, expected, after.landmarks_table, fold, ratio, criteria)


@dataclass(frozen=True)
class FoldCheck:
    """`iou`: the outline after against the one before folded ideally. `unchanged_iou`: the outline
    after against the one before as it was (only measured when the fold looks wrong). `measure`: the
    fold-success measure on the landmarks seen (None: it could not be worked out). `cause`: why the
    verdict is not `done`, in an operator's words."""

    iou: float
    unchanged_iou: float | None
    verdict: FoldOutcome  # DONE | IMPERFECT | DID_NOT_TAKE
    cause: str = ""
    measure: FoldScore | None = None


def check_fold(before_table: Points, after_table: Points, line: FoldLine, config: CellConfig,
               measure: FoldScore | None = None) -> FoldCheck:
    """Did the fold happen as planned (done: the outline as folded), not at all (did not take: the
    outline is unchanged, a grasp took no cloth), or otherwise (imperfect: the cloth moved, not as
    planned)? `measure` (the fold-success measure on the landmarks seen) is reported beside the
    verdict, not in it: it reads the folded model's names, and a corner the match misnames (a
    shirt's armpit 10 cm off with the outline perfect) would call a good fold bad."""
    iou = folded_outline_iou(before_table, after_table, line, config.verify_resolution_m)
    if iou >= config.verify_min_iou:
        return FoldCheck(iou, None, FoldOutcome.DONE, "", measure)
    unchanged = polygon_iou(before_table, after_table, config.verify_resolution_m)
    if unchanged >= config.unchanged_min_iou:
        return FoldCheck(iou, unchanged, FoldOutcome.DID_NOT_TAKE,
                         f"the outline is unchanged (IoU {unchanged:.2f} with the one before): the grasp "
                         "took no cloth", measure)
    return FoldCheck(iou, unchanged, FoldOutcome.IMPERFECT,
                     f"the outline differs from the fold as planned (IoU {iou:.2f}, "
                     f"{config.verify_min_iou:.2f} needed)", measure)
