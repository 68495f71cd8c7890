"""The perception pipeline: segment -> simplify -> match, with per-stage timings."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.common.configfile import ConfigError, load_yaml

from .config import PerceptionConfig, load_perception_config
from .errors import ModelError, NoGarmentFound, PerceptionError
from .geometry import make_clockwise
from .matching import match
from .models import CATEGORIES, PolygonalModel, model_from_fields
from .segmentation import Segmentation, segment, table_log_likelihood
from .simplify import candidates, simplify_closed
from .table_model import TableModel, check_image, fit_table_model, table_model_from_fields

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Observation:
    category: str
    landmarks: dict[str, tuple[float, float]]
    polygon: NDArray                      # (N, 2) clockwise simplified contour, input pixels
    cost: float
    timings_ms: dict[str, float]
    costs: dict[str, float] = field(default_factory=dict)   # every model tried -> its cost
    contour: NDArray | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "category": self.category,
            "landmarks": {k: [round(v[0], 2), round(v[1], 2)] for k, v in self.landmarks.items()},
            "polygon": [[round(float(x), 2), round(float(y), 2)] for x, y in self.polygon],
            "cost": float(self.cost),
            "timings_ms": {k: round(v, 3) for k, v in self.timings_ms.items()},
            "costs": {k: float(v) for k, v in self.costs.items()},
        }


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
    by, bx = max(int(round(fraction * h)), 1), max(int(round(fraction * w)), 1)
    ring = np.ones((h, w), bool)
    ring[by:h - by, bx:w - bx] = False
    return ring


def describes_border(image_bgr: NDArray, table_model: TableModel, config: PerceptionConfig) -> float:
    """The part of the image's border ring that `table_model` does not call surely garment."""
    w, h = config.segmentation.work_size
    small = cv2.resize(check_image(image_bgr), (w, h), interpolation=cv2.INTER_AREA)
    ring = border_ring((h, w), config.table_fallback.border_fraction)
    return float(np.mean(table_log_likelihood(small, table_model)[ring] >= table_model.threshold_fg))


def segment_garment(image_bgr: NDArray, table_model: TableModel, config: PerceptionConfig) -> Segmentation:
    """The garment's segmentation; when it fails, the table model is checked against the image.

    The border of an image whose garment does not touch it is all table. If the model calls most
    of it surely garment (another table, a change of light: segmentation then finds no table or a
    "garment" reaching the border), a model is fitted to that ring, the image segmented with it,
    and the model fitted again to every pixel away from that garment (so the table's brightness
    field is learned over the whole image), with a warning. An image the model fits costs nothing
    more.
    """
    try:
        return segment(image_bgr, table_model, config.segmentation)
    except PerceptionError:
        fb = config.table_fallback
        if not fb.enabled:
            raise
        described = describes_border(image_bgr, table_model, config)
        if described >= fb.min_table_fraction:
            raise
    log.warning("the table model describes only %.0f %% of the image border: fitting one to this image",
                100.0 * described)
    img = check_image(image_bgr)
    ring_model = fit_table_model([img], [border_ring(img.shape[:2], fb.border_fraction)], config)
    first = segment(img, ring_model, config.segmentation)
    margin = 2 * config.table.annotation_margin_px + 1
    near = cv2.dilate(first.mask.astype(np.uint8), np.ones((margin, margin), np.uint8)) > 0
    return segment(img, fit_table_model([img], [~near], config), config.segmentation)


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


def perceive(image_bgr: NDArray, table_model: TableModel, models: Mapping[str, PolygonalModel],
             config: PerceptionConfig, category: str | None = None) -> Observation:
    """Category, named landmarks (input pixels), polygon, cost and stage timings of one image."""
    if category is not None and category not in models:
        raise ModelError(f"no model for category {category!r} (have: {', '.join(models)})")
    chosen = {category: models[category]} if category is not None else dict(models)
    t0 = time.perf_counter()
    seg = segment_garment(image_bgr, table_model, config)
    t1 = time.perf_counter()
    polys: dict[int, NDArray] = {}
    for m in chosen.values():
        if m.simplify_vertices not in polys:
            polys[m.simplify_vertices] = simplify_contour(seg.contour, m.simplify_vertices, config)
    t2 = time.perf_counter()
    results = {name: match(polys[m.simplify_vertices], m, config.matching) for name, m in chosen.items()}
    t3 = time.perf_counter()
    best = min(results, key=lambda k: results[k].cost)
    r = results[best]
    timings = {"segment": (t1 - t0) * 1e3, "simplify": (t2 - t1) * 1e3, "match": (t3 - t2) * 1e3,
               "total": (t3 - t0) * 1e3}
    log.debug("perceived %s cost %.2f in %.1f ms", best, r.cost, timings["total"])
    return Observation(best, r.landmarks, r.points, r.cost, timings,
                       {k: v.cost for k, v in results.items()}, seg.contour)
