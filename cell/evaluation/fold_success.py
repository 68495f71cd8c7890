"""Whether a fold succeeded, in centimetres: where the garment's landmarks end up against the
recipe's ideal folds of the true flat garment (`cell.evaluation.ideal_fold`, written apart from the
planner), whether the rest stayed put, and whether the top-view area is the folded one.

- After each fold: a landmark the fold moves (the ideal, folded open loop, has it on the moving side
  of the fold's line) should lie at its place before the fold reflected across that line; every one
  within `moved_max_m`, their mean within `moved_mean_m`. A landmark that should stay moved at most
  `stay_max_m`. The area is within `area_tolerance` of the ideal folded garment's.
- After the whole recipe: every landmark within `recipe_max_m` of the open-loop ideal (the flat
  landmarks carried through every ideal fold), and the area within `area_tolerance`.

A miss names its cause, the first that holds of: grasp lost (a gripper took no cloth), slipped (the
moved landmarks were carried less than `slipped_progress` of their way), wrong layer (a landmark
that should stay lies near its mirror image: it went with the flap), dragged (one that should stay
moved), short or long (the moved landmarks lie short of or beyond their places across the line;
also the side an area out of tolerance errs to). `unreachable` is the caller's to say (the fold
could not be planned).

Every naming the cell may give the garment (`ideal_fold.namings`) is tried; the score is the best.
Pure: arrays and dataclasses in, a score out.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cell.evaluation.ideal_fold import Grid, IdealFold, fold_mask, ideal_folds, relabellings
from drivers.common.configfile import Fields, config_dir, load_yaml

Points = NDArray[np.float64]
PointsLike = Sequence[float] | NDArray[np.float64]
CONFIG_FILE = "evaluation.yaml"
CAUSES = ("unreachable", "grasp lost", "slipped", "wrong layer", "dragged", "short", "long")


@dataclass(frozen=True)
class SuccessCriteria:
    moved_max_m: float = 0.03
    moved_mean_m: float = 0.02
    stay_max_m: float = 0.02
    area_tolerance: float = 0.15
    recipe_max_m: float = 0.05
    crease_band_m: float = 0.01
    slipped_progress: float = 0.5
    wrong_layer_m: float = 0.03
    area_resolution_m: float = 0.002


def criteria_from_fields(f: Fields) -> SuccessCriteria:
    f.reject_unknown(set(SuccessCriteria.__dataclass_fields__))
    return SuccessCriteria(
        moved_max_m=f.float("moved_max_m", positive=True, max=0.5),
        moved_mean_m=f.float("moved_mean_m", positive=True, max=0.5),
        stay_max_m=f.float("stay_max_m", positive=True, max=0.5),
        area_tolerance=f.float("area_tolerance", positive=True, max=1.0),
        recipe_max_m=f.float("recipe_max_m", positive=True, max=0.5),
        crease_band_m=f.float("crease_band_m", min=0.0, max=0.2),
        slipped_progress=f.float("slipped_progress", min=0.0, max=1.0),
        wrong_layer_m=f.float("wrong_layer_m", positive=True, max=0.5),
        area_resolution_m=f.float("area_resolution_m", positive=True, max=0.05),
    )


def load_success_criteria(path: str | Path | None = None) -> SuccessCriteria:
    """`fold_success:` of config/evaluation.yaml (or of `path`)."""
    fields = load_yaml(Path(path) if path else config_dir() / CONFIG_FILE)
    return criteria_from_fields(fields.sub("fold_success"))


@dataclass(frozen=True)
class FoldScore:
    """One fold (`fold`, 1-based) or the whole recipe (`fold` 0) against its ideal."""

    fold: int
    success: bool
    cause: str | None                   # one of CAUSES when it missed
    detail: str                         # the figure behind the cause, in words
    landmark_errors_m: dict[str, float]  # the landmarks judged by place: to their ideal place
    drift_m: dict[str, float]            # the landmarks that should stay: how far they moved
    area_ratio: float                    # top-view area / the ideal's

    @property
    def max_error_m(self) -> float:
        return max(self.landmark_errors_m.values(), default=0.0)

    @property
    def mean_error_m(self) -> float:
        values = list(self.landmark_errors_m.values())
        return float(np.mean(values)) if values else 0.0

    @property
    def max_drift_m(self) -> float:
        return max(self.drift_m.values(), default=0.0)

    def as_dict(self) -> dict:
        return {
            "fold": self.fold, "success": self.success, "cause": self.cause, "detail": self.detail,
            "landmark_error_cm": {
                "max": round(self.max_error_m * 100, 2), "mean": round(self.mean_error_m * 100, 2),
                "each": {n: round(e * 100, 2) for n, e in self.landmark_errors_m.items()}},
            "drift_cm": {"max": round(self.max_drift_m * 100, 2),
                         "each": {n: round(d * 100, 2) for n, d in self.drift_m.items()}},
            "area_ratio": round(self.area_ratio, 3),
        }


def unreachable(fold: int, detail: str) -> FoldScore:
    """A fold that could not be planned: the arms cannot reach it."""
    return FoldScore(fold, False, "unreachable", detail, {}, {}, float("nan"))


def _carried(points: Points, fold: IdealFold) -> Points:
    """Each point after the perfect fold: reflected when on the moving side, else where it was."""
    line = fold.line
    return np.where((line.side(points) > 0.0)[:, None], line.reflect(points), points)


def open_loop(names: Sequence[str], flat: Points, folds: Sequence[IdealFold]) -> list[Points]:
    """The landmarks (in `names` order) before any fold and after each perfect fold."""
    states = [np.asarray(flat, dtype=float)]
    for fold in folds:
        states.append(_carried(states[-1], fold))
    return states


def ideal_areas(category: str, named: Mapping[str, Points], outline: Points,
                resolution: float) -> list[float]:
    """The top-view area (m²) of the flat garment and after each perfect fold of its recipe."""
    flat = np.asarray(outline, dtype=float)
    grid = Grid.around(flat, resolution)
    mask = grid.fill([flat])
    areas = [float(mask.sum()) * resolution ** 2]
    for fold in ideal_folds(category, named):
        mask = fold_mask(mask, fold, grid)
        areas.append(float(mask.sum()) * resolution ** 2)
    return areas


def _side_error(after: Points, ideal: Points, fold: IdealFold) -> float:
    """Mean signed distance of where the moved landmarks lie past their ideal places, across the
    line (< 0: short of them, on the moving side; > 0: beyond)."""
    return float(np.mean((after - ideal) @ fold.normal)) if len(after) else 0.0


def score_fold(category: str, flat: Mapping[str, PointsLike], outline: Points, fold_index: int,
               before: Mapping[str, PointsLike], after: Mapping[str, PointsLike], area: float,
               criteria: SuccessCriteria, grasped: Mapping[str, bool] | None = None) -> FoldScore:
    """Fold `fold_index` (0-based) of `category`'s recipe: `flat` the true flat landmarks and
    `outline` the flat outline (table frame, m), `before`/`after` the landmarks (xy, m) around this
    fold, `area` the top-view area after it (m²), `grasped` per arm whether it took cloth."""
    if grasped and not all(grasped.values()):
        empty = ", ".join(arm for arm, took in grasped.items() if not took)
        return FoldScore(fold_index + 1, False, "grasp lost", f"{empty} closed on no cloth", {}, {},
                         float("nan"))
    scores = []
    for labels in relabellings(category):
        named = _relabel(flat, labels)
        scores.append(_score_named(category, named, outline, fold_index, _relabel(before, labels),
                                   _relabel(after, labels), area, criteria, labels))
    return min(scores, key=lambda s: (not s.success, s.max_error_m + s.max_drift_m))


def _relabel(points: Mapping[str, PointsLike], labels: Mapping[str, str]) -> dict[str, Points]:
    """`points` (by true name) under the cell's labels."""
    return {label: np.asarray(points[true], dtype=float) for label, true in labels.items() if true in points}


def _in_true_names(score: FoldScore, labels: Mapping[str, str]) -> FoldScore:
    """A score worked out under the cell's labels, reported by the landmarks' true names."""
    return dataclasses.replace(
        score, landmark_errors_m={labels[n]: e for n, e in score.landmark_errors_m.items()},
        drift_m={labels[n]: d for n, d in score.drift_m.items()})


def _score_named(category: str, named: Mapping[str, Points], outline: Points, fold_index: int,
                 before: Mapping[str, Points], after: Mapping[str, Points], area: float,
                 criteria: SuccessCriteria, true_name: Mapping[str, str]) -> FoldScore:
    folds = ideal_folds(category, named)
    if not 0 <= fold_index < len(folds):
        raise ValueError(f"fold_index: must be 0..{len(folds) - 1} for {category}, got {fold_index!r}")
    fold = folds[fold_index]
    names = [n for n in named if n in before and n in after]
    flat = np.array([named[n] for n in names])
    ideal_before = open_loop(names, flat, folds[:fold_index])[-1]
    moves = fold.line.side(ideal_before) > criteria.crease_band_m
    was = np.array([before[n] for n in names], dtype=float)
    now = np.array([after[n] for n in names], dtype=float)
    target = np.where(moves[:, None], fold.line.reflect(was), was)
    ideal_area = ideal_areas(category, named, outline, criteria.area_resolution_m)[fold_index + 1]
    ratio = area / ideal_area if ideal_area > 0 else float("inf")
    # judged under the cell's labels, reported by the landmarks' true names
    return _judge(fold_index + 1, [true_name[n] for n in names], was, now, target, moves, ratio, fold,
                  criteria)


def score_seen(fold_number: int, before: Mapping[str, PointsLike], expected: Mapping[str, PointsLike],
               after: Mapping[str, PointsLike], fold: IdealFold, area_ratio: float,
               criteria: SuccessCriteria) -> FoldScore:
    """The measure on what the camera sees, the cell's own check of fold `fold_number` (1-based): the
    landmarks matched `after` it against where the planned `fold` should have put them (`expected`,
    worked out from those matched `before` it), those it moves judged by place and the rest by drift;
    `area_ratio` the outline's area seen over the expected one's. As in the world's measure, only
    landmarks that were there before count: the fold's new ends lie on the crease, whose loop has no
    sharp corner to place them by. A grasp lost or a wrong layer cannot be told from an outline:
    those come out as slipped or short. The names are the folded model's match: a corner it names
    wrongly is judged where it was named."""
    names = [n for n in expected if n in after and n in before]
    target = np.array([expected[n] for n in names], dtype=float)
    was = np.array([before[n] for n in names], dtype=float)
    now = np.array([after[n] for n in names], dtype=float)
    moves = np.linalg.norm(target - was, axis=1) > criteria.crease_band_m
    return _judge(fold_number, names, was, now, target, moves, area_ratio, fold, criteria)


def _judge(fold_number: int, names: Sequence[str], was: Points, now: Points, target: Points,
           moves: NDArray[np.bool_], ratio: float, fold: IdealFold, criteria: SuccessCriteria) -> FoldScore:
    """The verdict on landmarks `names` that lay at `was`, lie at `now` and should lie at `target`
    (`moves`: those the fold carries across its line), the area `ratio` against the ideal's."""
    errors = np.linalg.norm(now - target, axis=1)
    moved = {n: float(e) for n, e, m in zip(names, errors, moves, strict=True) if m}
    drift = {n: float(e) for n, e, m in zip(names, errors, moves, strict=True) if not m}
    cause, detail = None, "every landmark in place"
    if moves.any():
        way = target[moves] - was[moves]
        progress = float(np.mean(np.sum((now[moves] - was[moves]) * way, axis=1)
                                 / np.maximum(np.sum(way * way, axis=1), 1e-12)))
        off = _side_error(now[moves], target[moves], fold)
    else:
        progress, off = 1.0, 0.0
    stays = ~moves
    near_mirror = np.linalg.norm(now - fold.line.reflect(was), axis=1) < criteria.wrong_layer_m
    far_from_line = np.abs(fold.line.side(was)) > criteria.wrong_layer_m
    went_along = stays & near_mirror & far_from_line
    worst_move = max(moved.values(), default=0.0)
    mean_move = float(np.mean(list(moved.values()))) if moved else 0.0
    if (worst_move > criteria.moved_max_m or mean_move > criteria.moved_mean_m) \
            and progress < criteria.slipped_progress:
        cause, detail = "slipped", f"the moved landmarks were carried {progress:.0%} of their way"
    elif went_along.any():
        which = ", ".join(n for n, w in zip(names, went_along, strict=True) if w)
        cause, detail = "wrong layer", f"{which} should have stayed and lies on its mirror image"
    elif drift and max(drift.values()) > criteria.stay_max_m:
        name = max(drift, key=lambda n: drift[n])
        cause = "dragged"
        detail = f"{name} should have stayed and moved {drift[name] * 100:.1f} cm"
    elif worst_move > criteria.moved_max_m or mean_move > criteria.moved_mean_m:
        name = max(moved, key=lambda n: moved[n])
        cause = "short" if off < 0 else "long"
        detail = (f"{name} {moved[name] * 100:.1f} cm from its place "
                  f"(mean {mean_move * 100:.1f} cm), "
                  f"{abs(off) * 100:.1f} cm {'short of' if off < 0 else 'beyond'} it across the line")
    elif abs(ratio - 1.0) > criteria.area_tolerance:
        # the side the moved landmarks err to; with none moved, more area than the ideal's is less folded
        cause = "short" if (off < 0 if moves.any() else ratio > 1.0) else "long"
        detail = f"top-view area {ratio:.2f} of the ideal's"
    return FoldScore(fold_number, cause is None, cause, detail, moved, drift, ratio)


def score_recipe(category: str, flat: Mapping[str, PointsLike], outline: Points,
                 after: Mapping[str, PointsLike], area: float, criteria: SuccessCriteria) -> FoldScore:
    """The garment after its whole recipe: every landmark within `recipe_max_m` of the open-loop
    ideal, the area within `area_tolerance` of the ideal folded garment's (fold 0 in the score)."""
    best: FoldScore | None = None
    for labels in relabellings(category):
        named = _relabel(flat, labels)
        after_named = _relabel(after, labels)
        folds = ideal_folds(category, named)
        names = [n for n in named if n in after_named]
        ideal = open_loop(names, np.array([named[n] for n in names]), folds)[-1]
        now = np.array([after_named[n] for n in names], dtype=float)
        errors = {n: float(e) for n, e in zip(names, np.linalg.norm(now - ideal, axis=1), strict=True)}
        ideal_area = ideal_areas(category, named, outline, criteria.area_resolution_m)[-1]
        ratio = area / ideal_area if ideal_area > 0 else float("inf")
        cause, detail = None, "every landmark in place"
        worst = max(errors, key=lambda n: errors[n])
        if errors[worst] > criteria.recipe_max_m:
            off = _side_error(now, ideal, folds[-1])
            cause = "short" if off < 0 else "long"
            detail = f"{labels[worst]} {errors[worst] * 100:.1f} cm from its place after the recipe"
        elif abs(ratio - 1.0) > criteria.area_tolerance:
            cause = "short" if ratio > 1.0 else "long"
            detail = f"top-view area {ratio:.2f} of the ideal's"
        score = _in_true_names(FoldScore(0, cause is None, cause, detail, errors, {}, ratio), labels)
        if best is None or (not score.success, score.max_error_m) < (not best.success, best.max_error_m):
            best = score
    assert best is not None
    return best
