"""The perception pipeline: the garment's outline in an image (segment, simplify:
`extract_outline`), the polygonal models matched to it and, when several are, the category
recognised (`match_outline`); `perceive` is the two in a row. Stage timings in seconds."""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.common.configfile import ConfigError, load_yaml
from drivers.common.garments import CATEGORIES
from drivers.common.landmarks import IMAGE, Landmarks
from drivers.common.plane import perimeter

from .config import (
    PerceptionConfig,
    RecognitionConfig,
    TableFallbackConfig,
    TableFitConfig,
    load_perception_config,
)
from .errors import ModelError, NoGarmentFound, PerceptionError
from .geometry import make_clockwise
from .matching import MatchResult, match
from .models import PolygonalModel, model_from_fields
from .recognition import Recogniser, load_recogniser, recognise_matched
from .segmentation import Segmentation, segment
from .simplify import candidates, simplify_closed, with_points_near
from .table_model import (
    TableModel,
    check_image,
    fit_table_model,
    normalise,
    table_model_from_fields,
)

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Outline:
    """The garment's outline in one image (input pixels): the segmentation's border and its
    simplifications, one per vertex count the models to match ask for (`outline_vertices`)."""

    contour: NDArray                   # (K, 2) int outer border of the segmentation
    polygons: Mapping[int, NDArray]    # vertex count -> (N, 2) clockwise simplified contour
    timings_s: Mapping[str, float]     # segment, simplify

    def polygon_for(self, model: PolygonalModel) -> NDArray:
        count = outline_vertices(model)
        if count not in self.polygons:
            raise ModelError(f"model {model.category!r} needs the outline simplified to {count} vertices; "
                             f"it was simplified to {sorted(self.polygons)}")
        return self.polygons[count]


@dataclass(frozen=True)
class Observation:
    """The garment perceived in one image: its category (given, or recognised among several
    models), the named landmarks and the polygon they were matched on (input pixels), stage
    timings in seconds. `confidence` and `probabilities` (category -> probability, most probable
    first) are the recognition's; None and empty when the category was given (one model)."""

    category: str
    landmarks: Landmarks               # image frame
    polygon: NDArray                   # (N, 2) clockwise polygon the landmarks were matched on
    cost: float
    costs: dict[str, float]            # every model tried -> its cost
    contour: NDArray                   # the segmentation's border
    timings_s: dict[str, float]        # segment, simplify, match (and recognise when recognised)
    confidence: float | None = None
    probabilities: dict[str, float] = field(default_factory=dict)

    @property
    def total_s(self) -> float:
        return float(sum(self.timings_s.values()))

    def doubt(self, config: RecognitionConfig) -> str | None:
        """Why this may be no garment at all (None when it looks like one): the matched model fits
        badly, or the recognition is unsure."""
        reasons = []
        if self.cost > config.max_fit_cost:
            reasons.append(f"the {self.category} model fits it badly (cost {self.cost:.1f} > "
                           f"recognition.max_fit_cost {config.max_fit_cost:g})")
        if self.confidence is not None and self.confidence < config.unsure_below:
            reasons.append(f"the recognition is unsure (confidence {self.confidence:.2f} < "
                           f"recognition.unsure_below {config.unsure_below:g})")
        return "; ".join(reasons) or None


def load_garment_model(category: str, config: PerceptionConfig | None = None,
                       path: str | Path | None = None) -> PolygonalModel:
    cfg = config or load_perception_config()
    p = Path(path) if path is not None else cfg.garments_dir / f"{category}.yaml"
    model = model_from_fields(load_yaml(p))
    if path is None and model.category != category:
        raise ConfigError(p, "category", f"is {model.category!r}, expected {category!r}")
    return model


def load_garment_models(config: PerceptionConfig | None = None) -> dict[str, PolygonalModel]:
    return {c: load_garment_model(c, config) for c in CATEGORIES}


def load_table_model(path: str | Path | None = None, config: PerceptionConfig | None = None) -> TableModel:
    cfg = config or load_perception_config()
    return table_model_from_fields(load_yaml(Path(path) if path is not None else cfg.table_model))


def border_ring(shape: tuple[int, int], fraction: float) -> NDArray:
    """A bool mask of the pixels within `fraction` of the width/height from the image border."""
    h, w = shape
    ring_rows, ring_cols = max(round(fraction * h), 1), max(round(fraction * w), 1)
    ring = np.ones((h, w), bool)
    ring[ring_rows:h - ring_rows, ring_cols:w - ring_cols] = False
    return ring


def describes_border(image_bgr: NDArray, table_model: TableModel, config: PerceptionConfig) -> float:
    """The part of the image's border ring that `table_model` does not call surely garment."""
    w, h = config.segmentation.work_size
    small = cv2.resize(check_image(image_bgr), (w, h), interpolation=cv2.INTER_AREA)
    return _ring_described(small, border_ring((h, w), config.table_fallback.border_fraction), table_model)


def _ring_described(small: NDArray, ring: NDArray, table_model: TableModel) -> float:
    likelihood = table_model.terms.log_likelihood(normalise(small, table_model.gain)[ring])
    return float(np.mean(likelihood >= table_model.threshold_fg))


def fallback_fit(config: PerceptionConfig) -> TableFitConfig:
    """How the fallback fits a table model to one image's border ring: `table`, made fast."""
    fb = config.table_fallback
    return replace(config.table, em_iterations=fb.em_iterations, samples=fb.samples,
                   trim_fraction=fb.trim_fraction, outlier_mahalanobis=fb.outlier_mahalanobis)


def segment_garment(image_bgr: NDArray, table_model: TableModel, config: PerceptionConfig) -> Segmentation:
    """The garment's segmentation; when it fails, the table model is checked against the image.

    The border of an image whose garment does not touch it is all table. If the model calls most
    of it surely garment (another table, a change of light: segmentation then finds no table or a
    "garment" reaching the border), a model is fitted to that ring (at the working size, few EM
    iterations, its least likely pixels left out: a garment may come close to the border; the
    table's brightness over the middle extrapolated from the ring, which the segmentation's own
    light correction refines) and the image segmented with it, with a warning. An image the
    model fits costs nothing more. A segmentation by the ring's model says when it is in doubt
    (`Segmentation.doubt`, also logged): the garment lies in the ring the model was fitted to,
    or the table around the garment is unlike the ring's.
    """
    try:
        return segment(image_bgr, table_model, config.segmentation)
    except PerceptionError:
        fb = config.table_fallback
        if not fb.enabled:
            raise
        img = check_image(image_bgr)
        w, h = config.segmentation.work_size
        small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
        ring = border_ring((h, w), fb.border_fraction)
        described = _ring_described(small, ring, table_model)
        if described >= fb.min_table_fraction:
            raise
    log.warning("the table model describes only %.0f %% of the image border: fitting one to this image",
                100.0 * described)
    image_model = fit_table_model([small], [ring], config, fit=fallback_fit(config))
    segmentation = segment(img, image_model, config.segmentation)
    doubt = _ring_fit_doubt(segmentation, ring, fb)
    if doubt is not None:
        log.warning("segmentation with the table model fitted to the image border is in doubt: %s", doubt)
    return replace(segmentation, doubt=doubt)


def _ring_fit_doubt(segmentation: Segmentation, ring: NDArray, fb: TableFallbackConfig) -> str | None:
    """Why a segmentation by a table model fitted to the border `ring` (work size) may be wrong."""
    h, w = ring.shape
    garment = cv2.resize(segmentation.mask.view(np.uint8), (w, h), interpolation=cv2.INTER_AREA) > 0
    in_ring = float(garment[ring].mean())
    if in_ring > fb.max_ring_garment:
        return f"the garment covers {100.0 * in_ring:.1f} % of the border the table model was fitted to"
    # the table around the garment, past the garment's blurred edge
    table = cv2.dilate(garment.view(np.uint8), np.ones((5, 5), np.uint8)) == 0
    unexplained = float((segmentation.trimap[table] == 2).mean()) if table.any() else 1.0
    if unexplained > fb.max_table_unexplained:
        return (f"{100.0 * unexplained:.1f} % of the table around the garment is unlike the table at the "
                f"border (another surface, uneven light)")
    return None


def simplify_contour(contour: NDArray, n_vertices: int, config: PerceptionConfig) -> NDArray:
    cand = candidates(contour, config.simplify.candidate_tolerance_px,
                      max(config.simplify.max_candidates, n_vertices))
    if len(cand) < n_vertices:
        # a simple outline (a towel) has fewer corners than N: add evenly spaced contour points
        if len(contour) < n_vertices:
            raise NoGarmentFound(f"the garment outline has only {len(contour)} pixels")
        extra = np.linspace(0, len(contour), 2 * n_vertices, endpoint=False).astype(int)
        cand = np.unique(np.concatenate([cand, extra]))
    poly, _ = simplify_closed(np.asarray(contour, float), min(n_vertices, len(cand)), cand)
    return make_clockwise(poly)[0]


def outline_vertices(model: PolygonalModel) -> int:
    """The vertex count of the outline matched to `model`: its own, and at least two more than its
    landmarks (a folded model gains vertices; the matching needs a choice of contour points)."""
    return max(model.simplify_vertices, model.size + 2)


def extract_outline(image_bgr: NDArray, table_model: TableModel, config: PerceptionConfig,
                    models: Iterable[PolygonalModel]) -> Outline:
    """Segment the garment and simplify its border to the vertex count each of `models` asks for."""
    start = time.perf_counter()
    segmentation = segment_garment(image_bgr, table_model, config)
    segmented = time.perf_counter()
    outline = outline_of_contour(segmentation.contour, config, models)
    return Outline(outline.contour, outline.polygons,
                   {"segment": segmented - start, "simplify": outline.timings_s["simplify"]})


def outline_of_contour(contour: NDArray, config: PerceptionConfig,
                       models: Iterable[PolygonalModel]) -> Outline:
    """A garment border (pixels) simplified to the vertex count each of `models` (and its collared
    variant) asks for."""
    start = time.perf_counter()
    polygons: dict[int, NDArray] = {}
    for model in (m for each in models for m in (each, each.collared) if m is not None):
        count = outline_vertices(model)
        if count not in polygons:
            polygons[count] = simplify_contour(contour, count, config)
    return Outline(contour, polygons, {"simplify": time.perf_counter() - start})


def _expected_positions(model: PolygonalModel, expected_px: Mapping[str, Sequence[float]] | None
                        ) -> NDArray | None:
    """`expected_px` in the model's vertex order when it names exactly the model's vertices."""
    if expected_px is None or set(expected_px) != set(model.names):
        return None
    return np.array([expected_px[name] for name in model.names], dtype=float)


def with_collar(outline: Outline, model: PolygonalModel, own: MatchResult, config: PerceptionConfig
                ) -> MatchResult:
    """`own` (the model's match), or the match of the model's collared variant (a shirt's) when that
    fits better per vertex, its landmarks named as the model's: a collar standing above the neckline
    fits the variant, which does not take the collar's corners for shoulders; a plain neckline fits
    the model."""
    if model.collared is None:
        return own
    variant = match(outline.polygon_for(model.collared), model.collared, config.matching)
    if variant.cost / model.collared.size >= own.cost / model.size:
        return own
    return MatchResult(variant.cost, variant.mapping, variant.points,
                       Landmarks(IMAGE, model.names, variant.landmarks.array(model.names)))


def match_outline(outline: Outline, models: Mapping[str, PolygonalModel], config: PerceptionConfig,
                  expected_px: Mapping[str, Sequence[float]] | None = None,
                  recogniser: Recogniser | None = None) -> Observation:
    """Match every model to the outline; with several, the recogniser (default: the configured
    one, `load_recogniser`) names the garment and says how sure it is. The recognised garment's
    landmarks come from its model or, better fitting, its collared variant (`with_collar`).

    `expected_px` (landmark name -> pixel, e.g. where a fold should have put them) applies to a
    model whose vertices it names exactly: the contour points nearest to those positions become
    polygon vertices (a landmark may lie on a nearly straight stretch, where the simplification
    puts none), and the matching adds its position term (the model alone is matched then).
    """
    if not models:
        raise ModelError("no garment model to match")
    start = time.perf_counter()
    contour = outline.contour.astype(float)
    min_gap = config.simplify.expected_vertex_gap * perimeter(contour)
    results, expected = {}, {}
    for name, model in models.items():
        polygon = outline.polygon_for(model)
        expected[name] = positions = _expected_positions(model, expected_px)
        if positions is not None:
            polygon = with_points_near(polygon, contour, positions, min_gap)
        results[name] = match(polygon, model, config.matching, positions)
    matched = time.perf_counter()
    costs = {name: r.cost for name, r in results.items()}
    timings = {**outline.timings_s, "match": matched - start}
    recognition = None
    if len(models) == 1:
        (category,) = models
    else:
        recognition = recognise_matched(outline.contour, costs, {name: m.size for name, m in models.items()},
                                        recogniser or load_recogniser(config.recognition.model))
        category = recognition.category
        timings["recognise"] = time.perf_counter() - matched
    result = results[category]
    if expected[category] is None:
        collared_from = time.perf_counter()
        result = with_collar(outline, models[category], result, config)
        timings["match"] += time.perf_counter() - collared_from
    if recognition is None:
        return Observation(category, result.landmarks, result.points, result.cost, costs, outline.contour,
                           timings)
    return Observation(category, result.landmarks, result.points, result.cost, costs, outline.contour,
                       timings, recognition.confidence, recognition.probabilities)


def perceive(image_bgr: NDArray, table_model: TableModel, models: Mapping[str, PolygonalModel],
             config: PerceptionConfig, category: str | None = None,
             recogniser: Recogniser | None = None) -> Observation:
    """Category (given, or recognised among `models` by `recogniser`, default the configured one),
    named landmarks (input pixels), polygon, cost and stage timings of one image."""
    if category is not None and category not in models:
        raise ModelError(f"no model for category {category!r} (have: {', '.join(models)})")
    chosen = {category: models[category]} if category is not None else dict(models)
    outline = extract_outline(image_bgr, table_model, config, chosen.values())
    observation = match_outline(outline, chosen, config, recogniser=recogniser)
    log.debug("perceived %s (confidence %s) cost %.2f in %.1f ms", observation.category,
              observation.confidence, observation.cost, observation.total_s * 1e3)
    return observation
