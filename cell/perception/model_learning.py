"""Learning the polygonal models of every category from flat annotated garments (paper Sec. III-C):
each category's model, and for a shirt annotated with its neckline and collar, its collared variant."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cell.perception.annotations import Annotation
from cell.perception.models import PolygonalModel, learn_model
from drivers.common.garments import ANNOTATED_NODES, CATEGORIES, LANDMARKS

log = logging.getLogger(__name__)

# vertices of the simplified contour a model is matched on (a model file may set its own)
SIMPLIFY_VERTICES = {"towel": 10, "pants": 14, "short-sleeve": 18, "long-sleeve": 18}
# a shirt's collared variant: its four neckline and collar vertices take the place of two spare ones
COLLARED_SIMPLIFY_VERTICES = {"short-sleeve": 20, "long-sleeve": 20}


@dataclass(frozen=True)
class LearnedModel:
    model: PolygonalModel
    polygons: int   # flat annotations it was learned from
    collared: int   # of them, those with a neckline and collar that taught the collared variant


def learn_models(annotations: Iterable[tuple[Path, Annotation]], floors: Mapping[str, float],
                 vertices: Mapping[str, tuple[int, int | None]] | None = None) -> dict[str, LearnedModel]:
    """The model of every category with flat annotations among `annotations` ((file, annotation)
    pairs; folded ones are passed over, a polygon that cannot be read is logged and skipped).
    `floors`: the least variance of angles and lengths; `vertices`: category -> (simplify vertices,
    collared simplify vertices), the defaults above where not given."""
    polygons: dict[str, list[np.ndarray]] = {c: [] for c in CATEGORIES}
    collared: dict[str, list[np.ndarray]] = {c: [] for c in CATEGORIES}
    for path, annotation in annotations:
        if annotation.shape == "folded":
            continue
        try:
            polygons[annotation.category].append(annotation.model_points())
        except ValueError as exc:
            log.warning("skipping %s: %s", path, exc)
            continue
        nodes = ANNOTATED_NODES[annotation.category]
        if nodes != LANDMARKS[annotation.category] and set(nodes) <= set(annotation.landmarks):
            collared[annotation.category].append(annotation.model_points(nodes))
    learned = {}
    for category in CATEGORIES:
        if not polygons[category]:
            continue
        count, collared_count = (vertices or {}).get(
            category, (SIMPLIFY_VERTICES[category], COLLARED_SIMPLIFY_VERTICES.get(category)))
        model = learn_model(category, polygons[category], LANDMARKS[category], count, floors)
        if collared[category] and collared_count is not None:
            model = dataclasses.replace(model, collared=learn_model(
                category, collared[category], ANNOTATED_NODES[category], collared_count, floors))
        learned[category] = LearnedModel(model, len(polygons[category]),
                                         len(collared[category]) if model.collared is not None else 0)
    return learned
