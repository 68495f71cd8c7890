"""Learning the category recogniser (`recognition.py`) from labelled garment outlines.

Each training outline (a segmentation border of an annotated image, or any garment border in
pixels) is used as it is and in `RecognitionConfig.augmentations` varied copies
(`augment_contour`); every copy is simplified and matched to each garment model as perception
would, and its shape features and per-vertex costs are the classifier's evidence.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from .annotations import Annotation
from .config import AugmentConfig, PerceptionConfig
from .errors import ImageError, NoGarmentFound, PerceptionError
from .folded import group_moves
from .matching import match
from .models import PolygonalModel
from .pipeline import outline_of_contour, segment_garment
from .recognition import (
    Recogniser,
    cost_feature,
    fit_recogniser,
    models_fingerprint,
    shape_features,
    training_set,
)
from .table_model import TableModel

log = logging.getLogger(__name__)

Example = tuple[str, NDArray]        # (category, garment border in pixels)


def _rotation(angle: float) -> NDArray:
    return np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])


def _principal_axes(points: NDArray) -> NDArray:
    """Rows: the outline's major and minor axis directions."""
    centred = points - points.mean(axis=0)
    _, vectors = np.linalg.eigh(centred.T @ centred)
    return vectors[:, ::-1].T


def _outer_contour(mask: NDArray) -> NDArray:
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise NoGarmentFound("the augmented outline vanished")
    return max(contours, key=cv2.contourArea).reshape(-1, 2)


def _canvas(points: NDArray, margin: int = 8) -> tuple[NDArray, NDArray]:
    """An empty mask holding `points`, and the pixel position of its origin."""
    origin = np.floor(points.min(axis=0)) - margin
    size = np.ceil(points.max(axis=0) - origin).astype(int) + margin
    return np.zeros((size[1], size[0]), np.uint8), origin


def _fill(mask: NDArray, polygon: NDArray, origin: NDArray) -> None:
    cv2.fillPoly(mask, [np.round((polygon - origin) * 16).astype(np.int32)], 1, shift=4)


def fold_over(contour: NDArray, point: NDArray, normal: NDArray) -> NDArray:
    """The outline after folding the part on the `normal` side of the line through `point` over
    the line, as a pixel contour: on the other side, the garment united with its mirror image
    (the mirror of the moving part lands there; the mirror of the rest lands beyond, cut off)."""
    points = np.asarray(contour, float)
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    mirrored = points - 2.0 * np.outer((points - point) @ n, n)
    mask, origin = _canvas(np.vstack([points, mirrored]))
    _fill(mask, points, origin)
    _fill(mask, mirrored, origin)
    height, width = mask.shape
    rows, cols = np.mgrid[0:height, 0:width]
    moving_side = (cols + origin[0] - point[0]) * n[0] + (rows + origin[1] - point[1]) * n[1] > 0
    mask[moving_side] = 0
    return _outer_contour(mask) + origin


def augment_contour(contour: NDArray, rng: np.random.Generator, config: AugmentConfig) -> NDArray:
    """A varied copy of a garment outline (pixels, the same size): turned by any angle, one end
    stretched along a principal axis (long legs, long bodies, wide shoulders), its border waved
    (wrinkles), sometimes an end folded over; rasterised and traced again like a segmentation."""
    points = np.asarray(contour, float).reshape(-1, 2)
    centre = points.mean(axis=0)
    points = points - centre
    axes = _principal_axes(points)
    axis = axes[int(rng.integers(2))] * (1.0 if rng.random() < 0.5 else -1.0)
    along = points @ axis
    low, high = along.min(), along.max()
    start = low + rng.uniform(*config.stretch_from) * (high - low)
    factor = rng.uniform(*config.stretch)
    beyond = np.maximum(along - start, 0.0)
    points = points + np.outer(beyond * (factor - 1.0), axis)
    # waves along the border, normal to it
    tangent = np.roll(points, -1, axis=0) - np.roll(points, 1, axis=0)
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])
    phase = 2.0 * np.pi * arc / max(arc[-1], 1e-9)
    side = np.sqrt(abs(cv2.contourArea(points.astype(np.float32))))
    wave = np.zeros(len(points))
    for _ in range(3):
        waves = int(rng.integers(config.wrinkle_waves[0], config.wrinkle_waves[1] + 1))
        wave += np.sin(waves * phase + rng.uniform(0, 2 * np.pi))
    points = points + normal * (wave * rng.uniform(*config.wrinkle_amplitude) * side / 3.0)[:, None]
    points = points @ _rotation(rng.uniform(0.0, 2.0 * np.pi)).T + centre
    if rng.random() < config.fold_probability:
        axis = _principal_axes(points)[int(rng.integers(2))] * (1.0 if rng.random() < 0.5 else -1.0)
        along = (points - centre) @ axis
        depth = rng.uniform(*config.fold_depth) * (along.max() - along.min())
        return fold_over(points, centre + axis * (along.max() - depth), axis)
    mask, origin = _canvas(points)
    _fill(mask, points, origin)
    return _outer_contour(mask) + origin


def evidence(contour: NDArray, models: Mapping[str, PolygonalModel], config: PerceptionConfig
             ) -> tuple[NDArray, dict[str, float]]:
    """What the recogniser sees of a border: its shape features and each model's cost feature."""
    outline = outline_of_contour(contour, config, models.values())
    costs = {category: cost_feature(match(outline.polygon_for(model), model, config.matching).cost,
                                    model.size)
             for category, model in models.items()}
    return shape_features(contour), costs


def fold_count(annotation: Annotation) -> int | None:
    """How many folds the annotation's history holds (None: folded, with no history)."""
    if annotation.shape != "folded":
        return 0
    return len(group_moves(annotation.moves)) if annotation.moves else None


def examples_from_dataset(dataset: Iterable[tuple[Path, Annotation]], load_image: Callable[[Path], NDArray],
                          table_model: TableModel, config: PerceptionConfig) -> list[Example]:
    """The segmented border of every annotated image, labelled with its category. Folded images
    whose fold history is longer than `recognition.max_folds` are left out (a garment folded
    again and again becomes a rectangle whatever it was); unreadable images and failed
    segmentations are logged and passed over."""
    out = []
    for path, annotation in dataset:
        folds = fold_count(annotation)
        if folds is not None and folds > config.recognition.max_folds:
            continue
        try:
            image = load_image(path.parent / annotation.image)
            out.append((annotation.category, segment_garment(image, table_model, config).contour))
        except (ImageError, PerceptionError) as exc:
            log.warning("%s: left out: %s", path, exc)
    return out


def learn_recogniser(examples: Sequence[Example], models: Mapping[str, PolygonalModel],
                     config: PerceptionConfig,
                     provenance: Mapping[str, Any] | None = None,
                     progress: Callable[[Iterable[Example]], Iterable[Example]] = iter) -> Recogniser:
    """Fit the recogniser to the examples and their augmented copies, with the costs of `models`
    (the categories are the models'). `progress` wraps the loop over examples (a progress bar)."""
    learning = config.recognition
    rng = np.random.default_rng(learning.seed)
    labelled = []
    for category, contour in progress(examples):
        if category not in models:
            raise PerceptionError(f"an example of {category!r}, which has no model")
        variants = [np.asarray(contour)]
        variants += [augment_contour(contour, rng, learning.augment) for _ in range(learning.augmentations)]
        for variant in variants:
            try:
                shape, costs = evidence(variant, models, config)
            except PerceptionError as exc:     # an augmented copy too small or thin to match
                log.debug("a %s variant left out: %s", category, exc)
                continue
            labelled.append((category, shape, costs))
    counts = {c: sum(1 for label, _, _ in labelled if label == c) for c in models}
    record = {**(provenance or {}), "examples": len(examples), "samples": counts,
              "augmentations": learning.augmentations, "seed": learning.seed}
    return fit_recogniser(training_set(tuple(models), labelled), learning.regularisation, record,
                          models_fingerprint(models))
