"""Perception scored against a CloPeMa-format dataset (`foldcell eval`).

Every annotated image is perceived with its category given; the error of a landmark is its
distance (input pixels) to the annotated one. Perception names a garment as if it lay face up, so
the annotation of one lying face down (`facing: back`) is compared with its names mirrored; when
the file does not say which side is up, the better of the two namings counts. A folded garment is
matched with the model its annotated fold history gives (`replay_folds`, from the flat landmarks,
foldcell's extension of the format), scored on the landmarks both name and on each fold line's
two ends (the dataset's `fold_<k>` pair); folded images without a history are skipped. A towel
turned by 180 degrees (a square one by 90) looks the same, so its landmarks are scored under the
best of its namings (`SYMMETRIC_SHIFTS`; the wrong quarter turns of an oblong towel score badly and
are never the best); the errors as named are kept beside.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from cell.perception.annotations import Annotation, AnnotationError, Point
from cell.perception.config import PerceptionConfig
from cell.perception.errors import ImageError, ModelError, PerceptionError
from cell.perception.folded import derive_folded_model, fold_names, folded_polygon, group_moves
from cell.perception.models import PolygonalModel
from cell.perception.pipeline import perceive
from cell.perception.table_model import TableModel
from drivers.common.garments import LANDMARKS, mirror_name
from drivers.common.plane import perimeter

log = logging.getLogger(__name__)

# cyclic relabellings under which a category's shape is the same (in landmark-array shifts)
SYMMETRIC_SHIFTS: dict[str, tuple[int, ...]] = {"towel": (0, 1, 2, 3)}

STAGES = ("segment", "simplify", "match", "total")


@dataclass(frozen=True)
class ImageResult:
    """One image: its landmark errors (px) and match cost, or why perception failed on it."""

    file: str
    category: str                     # the category, "<category> (folded)" for a folded garment
    mean_px: float | None = None
    max_px: float | None = None
    cost: float | None = None
    error: str | None = None


@dataclass(frozen=True)
class ErrorSummary:
    median: float
    mean: float
    std: float

    @classmethod
    def of(cls, errors: list[float]) -> ErrorSummary:
        values = np.asarray(errors) if errors else np.asarray([np.nan])
        return cls(float(np.median(values)), float(np.mean(values)), float(np.std(values)))


@dataclass(frozen=True)
class CategoryResult:
    images: int                       # perceived or failed
    failures: list[str]               # perception errors
    errors_px: ErrorSummary           # landmark errors, under the category's symmetry
    errors_as_named_px: ErrorSummary  # landmark errors under the names perception gave
    median_timings_s: dict[str, float | None]   # per stage and in total; None without an image
    symmetric_scoring: bool

    @property
    def failure_rate(self) -> float:
        return len(self.failures) / self.images if self.images else 0.0


@dataclass(frozen=True)
class EvaluationReport:
    categories: dict[str, CategoryResult]
    images: list[ImageResult]
    skipped_folded: int               # folded images without a fold history, or whose folds do not replay
    unreadable: list[str]             # annotation files whose image cannot be read


@dataclass
class _Tally:
    """What one category's images add up to."""

    errors_px: list[float] = field(default_factory=list)
    errors_as_named_px: list[float] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)
    timings_s: list[dict[str, float]] = field(default_factory=list)

    def result(self, symmetric: bool) -> CategoryResult:
        medians = {stage: float(np.median([t[stage] for t in self.timings_s])) if self.timings_s else None
                   for stage in STAGES}
        return CategoryResult(len(self.timings_s) + len(self.failures), self.failures,
                              ErrorSummary.of(self.errors_px), ErrorSummary.of(self.errors_as_named_px),
                              medians, symmetric)


def replay_folds(model: PolygonalModel, annotation: Annotation, merge_fraction: float) -> PolygonalModel:
    """The folded model after the annotation's fold history, from its flat landmarks."""
    flat = annotation.flat_landmarks or {}
    if annotation.mirrored:
        flat = {mirror_name(name): point for name, point in flat.items()}
    missing = [name for name in model.names if name not in flat]
    if missing:
        raise AnnotationError(f"{annotation.image}: node_names_flat lacks {', '.join(missing)}")
    points = np.asarray([flat[name] for name in model.names])
    for fold_index, (grasp, place) in enumerate(group_moves(annotation.moves), start=1):
        merge_distance = merge_fraction * perimeter(points)
        folded = derive_folded_model(model, points, (grasp, place), fold_index, merge_fraction)
        polygon, names = folded_polygon(points, model.names, grasp, place, fold_index, merge_distance)
        model, points = folded, np.asarray([polygon[names.index(name)] for name in folded.names])
    return model


def fold_ends(annotation: Annotation, estimate: Mapping[str, Point]) -> dict[str, Point]:
    """Each fold line's two ends (the annotation's `fold_<k>` pair) under the folded model's names
    `fold<k>-from`/`fold<k>-to`, where the estimate has both: the dataset does not say which end is
    which, so the pairing nearer the estimate."""
    ends: dict[str, Point] = {}
    for k, (first, second) in annotation.fold_lines.items():
        start, end = fold_names(k)
        if start not in estimate or end not in estimate:
            continue
        straight = math.dist(estimate[start], first) + math.dist(estimate[end], second)
        crossed = math.dist(estimate[start], second) + math.dist(estimate[end], first)
        ends.update({start: first, end: second} if straight <= crossed else {start: second, end: first})
    return ends


def best_naming(estimate: Mapping[str, Point], truth: Mapping[str, Point], names: Sequence[str],
                category: str, facing_known: bool) -> dict[str, str]:
    """The renaming of the estimate's landmarks `names` under the category's symmetries and, when the
    facing is not known, its mirror, that puts them nearest the truth's (estimate name -> truth name)."""
    truth_points = np.asarray([truth[n] for n in names], float)
    namings: list[Callable[[str], str]] = [lambda n: n]
    if not facing_known:
        namings.append(mirror_name)
    best: tuple[float, dict[str, str]] | None = None
    for rename in namings:
        if not all(rename(n) in names for n in names):
            continue
        for shift in SYMMETRIC_SHIFTS.get(category, (0,)):
            # the estimate's name k takes the truth name `shift` places further round the outline
            naming = {n: names[(names.index(rename(n)) + shift) % len(names)] for n in names}
            renamed = {naming[n]: estimate[n] for n in names}
            total = float(np.linalg.norm(np.asarray([renamed[n] for n in names], float) - truth_points,
                                         axis=1).sum())
            if best is None or total < best[0]:
                best = (total, naming)
    assert best is not None   # the names as they are always count
    return best[1]


def landmark_errors(estimate: Mapping[str, Point], truth: Mapping[str, Point], names: Sequence[str],
                     category: str, facing_known: bool) -> tuple[NDArray, NDArray]:
    """Distances (px) of the estimated landmarks to the annotated ones over `names`: under the
    `best_naming`, and as named."""
    truth_points = np.asarray([truth[n] for n in names], float)
    as_named = np.linalg.norm(np.asarray([estimate[n] for n in names], float) - truth_points, axis=1)
    naming = best_naming(estimate, truth, names, category, facing_known)
    renamed = {naming[n]: estimate[n] for n in names}
    best = np.asarray([renamed[n] for n in names], float)
    return np.linalg.norm(best - truth_points, axis=1), as_named


def evaluate(dataset: Iterable[tuple[Path, Annotation]], load_image: Callable[[Path], NDArray],
             table_model: TableModel, models: Mapping[str, PolygonalModel],
             config: PerceptionConfig, category_given: bool = True) -> EvaluationReport:
    """Perceive every annotated image of `dataset` ((annotation file, annotation) pairs) and score it.

    `load_image(path)` reads an image; one that raises `ImageError` is listed as unreadable and the
    evaluation goes on. Without `category_given` a flat garment's category is recognised among all
    `models` and a wrong one counts as a failure of that image (folded ones keep their category).
    """
    tallies: dict[str, _Tally] = {}
    images: list[ImageResult] = []
    unreadable: list[str] = []
    skipped = 0
    for path, annotation in dataset:
        key, use_models, names = annotation.category, models, LANDMARKS[annotation.category]
        if annotation.shape == "folded":
            if annotation.flat_landmarks is None or not annotation.moves:
                skipped += 1        # no fold history to replay
                continue
            try:
                folded_model = replay_folds(models[annotation.category], annotation, config.merge_fraction)
            except ModelError as exc:
                log.warning("%s: cannot replay its folds: %s", path, exc)
                skipped += 1
                continue
            use_models = {annotation.category: folded_model}
            scored = set(annotation.landmarks_as_seen()) | {
                name for k in annotation.fold_lines for name in fold_names(k)}
            names = tuple(name for name in folded_model.names if name in scored)
            key = f"{annotation.category} (folded)"
        try:
            image = load_image(path.parent / annotation.image)
        except ImageError as exc:  # one broken file does not end the evaluation
            log.warning("%s: %s", path, exc)
            unreadable.append(path.name)
            continue
        tally = tallies.setdefault(key, _Tally())
        try:
            given = annotation.category if category_given or annotation.shape == "folded" else None
            observation = perceive(image, table_model, use_models, config, given)
            if observation.category != annotation.category:
                raise PerceptionError(f"recognised as {observation.category}")
        except PerceptionError as exc:
            tally.failures.append(str(exc))
            images.append(ImageResult(path.name, key, error=str(exc)))
            continue
        truth = {**annotation.landmarks_as_seen(), **fold_ends(annotation, observation.landmarks)}
        names = tuple(name for name in names if name in truth)
        if not names:
            skipped += 1        # nothing both name: a later fold carried every scored point
            continue
        errors, as_named = landmark_errors(observation.landmarks, truth, names,
                                            annotation.category, annotation.facing is not None)
        tally.errors_as_named_px.extend(as_named.tolist())
        tally.errors_px.extend(errors.tolist())
        tally.timings_s.append({**observation.timings_s, "total": observation.total_s})
        images.append(ImageResult(path.name, key, float(errors.mean()), float(errors.max()),
                                  float(observation.cost)))
    categories = {key: tally.result(key in SYMMETRIC_SHIFTS) for key, tally in tallies.items()}
    return EvaluationReport(categories, images, skipped, unreadable)
