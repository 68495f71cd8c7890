"""Garment category recognition: which category an outline shows, with a probability for each.

The matching costs of models with different vertex counts are not comparable (a 4-vertex towel
model fits almost anything cheaply), and a model learned on one world is narrow on another; so
the category is decided by a small classifier on evidence that does not depend on where, how big
or how turned the garment lies:

- the outline's shape (`shape_features`): solidity (area / convex hull area), the depths and
  areas of its deepest convexity defects (a crotch, two armpits, slits beside hanging sleeves),
  how alike the two deepest are, the elongation and fill of its minimum-area rectangle and the
  roundness of its hull;
- each category's matching cost per model vertex (`cost_feature`), which enters that category's
  score only, so a recogniser still ranks any subset of the categories it knows.

The classifier is multinomial logistic regression (`fit_recogniser`), its parameters data in
`config/perception/recognition.yaml` written by `foldcell models learn-recognition`. Training outlines
are augmented (`augment_contour`: any rotation, one end stretched, wrinkled borders, an end
folded over) so that what photographs show and the simulator does not (any angle, long legs,
wide bodies, wrinkles, folds) is covered. Nothing here depends on landmark names.
"""

from __future__ import annotations

import functools
import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize

from drivers.common.configfile import ConfigError, Fields, load_yaml

from .errors import ModelError, NoGarmentFound

SHAPE_FEATURES: tuple[str, ...] = (
    "solidity", "elongation", "rectangularity", "hull_roundness",
    "defect_depth_1", "defect_depth_2", "defect_depth_3",
    "defect_area_1", "defect_area_2", "defect_area_3", "defect_balance",
)
DEFECTS = 3                      # the deepest convexity defects described
_NORMAL_SIDE = 1024.0            # outlines are scaled to this sqrt(area) before measuring (integer hull)
# the balance of the two deepest defects divides by at least this (of sqrt(hull area)), so on a convex
# outline (a towel) the pixel noise of its tiny defects does not swing it between 0 and 1
_MIN_DEPTH = 0.05


@dataclass(frozen=True)
class Recognition:
    """The recognised category, its probability, and the probability of every category ranked."""

    category: str
    confidence: float
    probabilities: dict[str, float]


@dataclass(frozen=True)
class Recogniser:
    """Multinomial logistic regression over standardised shape features and each category's own
    matching cost: score_c = bias_c + shape_weights_c . z(shape) + cost_weight_c * z(cost_c)."""

    categories: tuple[str, ...]
    feature_names: tuple[str, ...]
    feature_mean: NDArray            # (F,) standardisation of the shape features
    feature_scale: NDArray           # (F,)
    cost_mean: float                 # standardisation of the per-vertex cost feature
    cost_scale: float
    bias: NDArray                    # (C,)
    shape_weights: NDArray           # (C, F)
    cost_weights: NDArray            # (C,)
    models_fingerprint: str = ""     # of the garment models whose costs it learned (empty: unknown)
    provenance: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        c, f = len(self.categories), len(self.feature_names)
        shapes = {"feature_mean": (f,), "feature_scale": (f,), "bias": (c,), "shape_weights": (c, f),
                  "cost_weights": (c,)}
        for name, shape in shapes.items():
            if np.shape(getattr(self, name)) != shape:
                raise ModelError(f"recogniser: {name} must have shape {shape}, "
                                 f"got {np.shape(getattr(self, name))}")
        if tuple(self.feature_names) != SHAPE_FEATURES:
            raise ModelError(f"recogniser: feature_names must be {list(SHAPE_FEATURES)} (learn it again with "
                             f"`foldcell models learn-recognition`), got {list(self.feature_names)}")
        if len(set(self.categories)) != c or c < 2:
            raise ModelError(f"recogniser: needs two or more distinct categories, "
                             f"got {list(self.categories)}")
        if np.any(np.asarray(self.feature_scale) <= 0) or self.cost_scale <= 0:
            raise ModelError("recogniser: feature scales must be > 0")

    def scores(self, shape: NDArray, costs: Mapping[str, float]) -> dict[str, float]:
        """The score of every category that has a cost (those matched)."""
        z = (np.asarray(shape, float) - self.feature_mean) / self.feature_scale
        out = {}
        for i, category in enumerate(self.categories):
            if category in costs:
                zc = (costs[category] - self.cost_mean) / self.cost_scale
                out[category] = float(self.bias[i] + self.shape_weights[i] @ z + self.cost_weights[i] * zc)
        return out

    def to_dict(self) -> dict[str, Any]:
        def floats(values: NDArray) -> list[float]:
            return [float(f"{v:.6g}") for v in np.ravel(values)]

        return {
            "provenance": dict(self.provenance),
            "models_fingerprint": self.models_fingerprint,
            "categories": list(self.categories),
            "features": [{"name": n, "mean": m, "scale": s} for n, m, s in
                         zip(self.feature_names, floats(self.feature_mean), floats(self.feature_scale),
                             strict=True)],
            "cost": {"mean": float(f"{self.cost_mean:.6g}"), "scale": float(f"{self.cost_scale:.6g}")},
            "classes": [{"category": c, "bias": floats(self.bias[i:i + 1])[0],
                         "cost_weight": floats(self.cost_weights[i:i + 1])[0],
                         "shape_weights": floats(self.shape_weights[i])}
                        for i, c in enumerate(self.categories)],
        }


def recogniser_from_fields(fields: Fields) -> Recogniser:
    """A recogniser from its file's fields (`Recogniser.to_dict`)."""
    fields.reject_unknown({"provenance", "models_fingerprint", "categories", "features", "cost", "classes"})
    names, means, scales = [], [], []
    for feature in fields.items("features"):
        feature.reject_unknown({"name", "mean", "scale"})
        names.append(feature.str("name"))
        means.append(feature.float("mean"))
        scales.append(feature.float("scale", positive=True))
    cost = fields.sub("cost")
    cost.reject_unknown({"mean", "scale"})
    categories, bias, cost_weights, shape_weights = [], [], [], []
    for cls in fields.items("classes"):
        cls.reject_unknown({"category", "bias", "cost_weight", "shape_weights"})
        categories.append(cls.str("category"))
        bias.append(cls.float("bias"))
        cost_weights.append(cls.float("cost_weight"))
        weights = cls.floats("shape_weights")
        if len(weights) != len(names):
            raise cls.error("shape_weights",
                            f"has {len(weights)} entries, expected {len(names)} (one per feature)")
        shape_weights.append(weights)
    listed = fields.strs("categories")
    if tuple(listed) != tuple(categories):
        raise fields.error("categories", f"{list(listed)} differ from the classes {categories}")
    provenance = fields.raw("provenance", {})
    if not isinstance(provenance, dict):
        raise fields.error("provenance", f"must be a mapping, got {provenance!r}")
    try:
        return Recogniser(tuple(categories), tuple(names), np.asarray(means), np.asarray(scales),
                          cost.float("mean"), cost.float("scale", positive=True), np.asarray(bias),
                          np.asarray(shape_weights, float).reshape(len(categories), len(names)),
                          np.asarray(cost_weights), fields.str("models_fingerprint", ""), provenance)
    except ModelError as exc:
        raise ConfigError(fields.file, "classes", str(exc)) from exc


def load_recogniser(path: Path) -> Recogniser:
    """The recogniser in a file (`recognition.model` of the perception config), read once per file
    version."""
    try:
        stamp = path.stat().st_mtime_ns
    except OSError:
        stamp = 0            # load_yaml names the missing file
    return _read_recogniser(path, stamp)


@functools.lru_cache(maxsize=8)
def _read_recogniser(path: Path, stamp: int) -> Recogniser:
    return recogniser_from_fields(load_yaml(path))


def models_fingerprint(models: Mapping[str, Any]) -> str:
    """A short digest of garment models (anything with `to_dict`): the costs a recogniser learned
    are those models' costs, so it is learned again when they change."""
    text = json.dumps({c: models[c].to_dict() for c in sorted(models)}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


# --- evidence ------------------------------------------------------------------------------------

def _normalised(contour: NDArray) -> NDArray:
    """The outline centred and scaled to sqrt(area) = `_NORMAL_SIDE`, as int32 points."""
    points = np.asarray(contour, float).reshape(-1, 2)
    if len(points) < 3:
        raise NoGarmentFound(f"the garment outline has only {len(points)} points")
    points = points - points.mean(axis=0)
    area = abs(cv2.contourArea(points.astype(np.float32)))
    if area <= 0:
        raise NoGarmentFound("the garment outline encloses no area")
    return np.round(points * (_NORMAL_SIDE / np.sqrt(area))).astype(np.int32)


def _pocket_areas(points: NDArray, defects: NDArray) -> NDArray:
    """The area between each defect's hull edge and the outline (start .. end along the outline)."""
    x, y = points[:, 0].astype(float), points[:, 1].astype(float)
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y          # edge i -> i+1
    prefix = np.concatenate([[0.0], np.cumsum(cross)])
    total = prefix[-1]
    out = []
    for start, end in defects[:, :2]:
        chain = prefix[end] - prefix[start] if end >= start else total - prefix[start] + prefix[end]
        chain += x[end] * y[start] - x[start] * y[end]        # the hull edge closes the pocket
        out.append(abs(0.5 * chain))
    return np.asarray(out)


def shape_features(contour: NDArray) -> NDArray:
    """The outline's shape features (`SHAPE_FEATURES` order); invariant to position, scale, rotation
    and mirroring."""
    points = _normalised(contour)
    area = abs(cv2.contourArea(points))
    hull_index = cv2.convexHull(points, returnPoints=False).ravel()
    hull = points[hull_index]
    hull_area = max(abs(cv2.contourArea(hull)), 1.0)
    side = np.sqrt(hull_area)
    depths, pockets = np.zeros(DEFECTS), np.zeros(DEFECTS)
    if len(hull_index) >= 3:
        try:
            found = cv2.convexityDefects(points, np.sort(hull_index).astype(np.int32)[:, None])
        except cv2.error:        # a self-touching outline: no defects measured
            found = None
        if found is not None and len(found):
            rows = found.reshape(-1, 4)
            order = np.argsort(-rows[:, 3])[:DEFECTS]
            depths[:len(order)] = rows[order, 3] / 256.0 / side
            pockets[:len(order)] = _pocket_areas(points, rows[order]) / hull_area
    (_, _), (width, height), _ = cv2.minAreaRect(hull)
    long_side, short_side = max(width, height, 1.0), max(min(width, height), 1.0)
    roundness = 4.0 * np.pi * hull_area / max(cv2.arcLength(hull, True), 1.0) ** 2
    balance = depths[1] / max(depths[0], _MIN_DEPTH)
    return np.array([area / hull_area, np.log(long_side / short_side), area / (long_side * short_side),
                     roundness, *depths, *pockets, balance])


def cost_feature(cost: float, vertices: int) -> float:
    """A model's matching cost made comparable across models: per model vertex, compressed (asinh)
    so a model that does not fit at all does not dominate."""
    return float(np.arcsinh(cost / vertices))


# --- classification ------------------------------------------------------------------------------

def recognise(recogniser: Recogniser, shape: NDArray, costs: Mapping[str, float]) -> Recognition:
    """Probabilities over the categories in `costs` (category -> `cost_feature`) that the recogniser
    knows; the most probable is the recognised category."""
    scores = recogniser.scores(shape, costs)
    if not scores:
        raise ModelError(f"the recogniser knows none of the categories {', '.join(costs)} "
                         f"(it knows {', '.join(recogniser.categories)})")
    names = list(scores)
    values = np.array([scores[n] for n in names])
    probabilities = np.exp(values - values.max())
    probabilities /= probabilities.sum()
    ranked = sorted(zip(names, probabilities.tolist(), strict=True), key=lambda item: -item[1])
    return Recognition(ranked[0][0], ranked[0][1], dict(ranked))


def recognise_matched(contour: NDArray, costs: Mapping[str, float], vertices: Mapping[str, int],
                      recogniser: Recogniser) -> Recognition:
    """The category of a garment border matched to several models (`costs`: category -> matching
    cost, `vertices`: category -> its model's vertex count)."""
    evidence = {category: cost_feature(cost, vertices[category]) for category, cost in costs.items()}
    return recognise(recogniser, shape_features(contour), evidence)


@dataclass(frozen=True)
class TrainingSet:
    """Evidence of labelled outlines: shape features (n, F), cost features (n, C), labels (n,)
    indexing `categories`."""

    categories: tuple[str, ...]
    shapes: NDArray
    costs: NDArray
    labels: NDArray


def fit_recogniser(data: TrainingSet, regularisation: float, provenance: Mapping[str, Any] | None = None,
                   fingerprint: str = "") -> Recogniser:
    """Maximum-likelihood logistic regression with an L2 penalty `regularisation` (per sample) on
    the weights; features standardised on the training set."""
    shapes, costs = np.asarray(data.shapes, float), np.asarray(data.costs, float)
    labels = np.asarray(data.labels)
    count, n_features = shapes.shape
    n_classes = len(data.categories)
    if count == 0 or costs.shape != (count, n_classes) or labels.shape != (count,):
        raise ModelError(f"training set: {count} samples, costs {costs.shape}, labels {labels.shape} "
                         f"do not agree with {n_classes} categories")
    missing = [c for i, c in enumerate(data.categories) if not np.any(labels == i)]
    if missing:
        raise ModelError(f"training set: no example of {', '.join(missing)}")
    mean, scale = shapes.mean(axis=0), shapes.std(axis=0)
    scale = np.where(scale > 1e-9, scale, 1.0)
    z = (shapes - mean) / scale
    cost_mean, cost_scale = float(costs.mean()), float(costs.std()) or 1.0
    zc = (costs - cost_mean) / cost_scale
    onehot = np.eye(n_classes)[labels]
    # class weights balance categories of unequal counts
    weights = (count / (n_classes * onehot.sum(axis=0)))[labels]

    def unpack(theta: NDArray) -> tuple[NDArray, NDArray, NDArray]:
        bias = theta[:n_classes]
        shape_w = theta[n_classes:n_classes * (1 + n_features)].reshape(n_classes, n_features)
        return bias, shape_w, theta[n_classes * (1 + n_features):]

    def loss(theta: NDArray) -> tuple[float, NDArray]:
        bias, shape_w, cost_w = unpack(theta)
        scores = bias + z @ shape_w.T + zc * cost_w
        scores -= scores.max(axis=1, keepdims=True)
        log_p = scores - np.log(np.exp(scores).sum(axis=1, keepdims=True))
        nll = -float((weights * (onehot * log_p).sum(axis=1)).sum()) / count
        residual = (np.exp(log_p) - onehot) * weights[:, None] / count
        grad = np.concatenate([residual.sum(axis=0), (residual.T @ z + regularisation * shape_w).ravel(),
                               (residual * zc).sum(axis=0) + regularisation * cost_w])
        penalty = 0.5 * regularisation * float((shape_w ** 2).sum() + (cost_w ** 2).sum())
        return nll + penalty, grad

    theta0 = np.zeros(n_classes * (2 + n_features))
    result = minimize(loss, theta0, jac=True, method="L-BFGS-B", options={"maxiter": 2000})
    bias, shape_w, cost_w = unpack(result.x)
    return Recogniser(tuple(data.categories), SHAPE_FEATURES, mean, scale, cost_mean, cost_scale,
                      bias, shape_w, cost_w, fingerprint, dict(provenance or {}))


def training_set(categories: Sequence[str], labelled: Sequence[tuple[str, NDArray, Mapping[str, float]]]
                 ) -> TrainingSet:
    """Stack (category, shape features, category -> cost feature) examples."""
    index = {c: i for i, c in enumerate(categories)}
    shapes = np.array([s for _, s, _ in labelled], float).reshape(len(labelled), len(SHAPE_FEATURES))
    costs = np.array([[c[name] for name in categories] for _, _, c in labelled], float)
    labels = np.array([index[category] for category, _, _ in labelled], int)
    return TrainingSet(tuple(categories), shapes, costs.reshape(len(labelled), len(categories)), labels)
