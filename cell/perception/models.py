"""Polygonal garment models (paper Sec. III-C): vertices, angle and edge-length distributions.

A model's vertices are stored in clockwise order on screen. Vertex m has an inner-angle
distribution N(angle_mean[m], angle_var[m]); edge m runs from vertex m to vertex m+1 (cyclic)
and has a relative-length distribution N(length_mean[m], length_var[m]) (length divided by the
perimeter). Vertices (edges) with the same entry in `angle_groups` (`length_groups`) share one
distribution, learned from the pooled samples, by the garment's left-right/top-bottom symmetry.

A shirt's model may carry a `collared` variant: the same garment with the dataset's neckline and
collar nodes as vertices, learned from the annotations that have them (polos, shirts). A collar
standing out above the neckline has corners as sharp as a shoulder's; the variant knows them, so
perception matches both and keeps the better fit (`cell.perception.pipeline.match_model`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.common.garments import LANDMARKS, mirror_name

from .errors import ModelError
from .geometry import make_clockwise, polygon_angles, relative_edge_lengths


def symmetry_groups(names: Sequence[str]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Angle and edge groups from left-right mirroring of names; towels also share top/bottom.

    Vertex names pair with their mirror; edge (a, b) pairs with edge (mirror b, mirror a).
    """
    def left_side(name: str) -> str:
        return mirror_name(name) if "right" in name else name

    def towel_corner(name: str) -> str:
        return left_side(name.replace("top", "bottom"))

    is_towel = set(names) == set(LANDMARKS["towel"])
    canonical = towel_corner if is_towel else left_side
    vertex_keys = [canonical(name) for name in names]
    count = len(names)
    edge_keys: list[tuple[str, ...]] = []
    for i in range(count):
        start, end = names[i], names[(i + 1) % count]
        if is_towel:
            # top and bottom edges share, left and right edges share
            same_side = start.split("-")[0] == end.split("-")[0]
            pair: tuple[str, ...] = ("horizontal",) if same_side else ("vertical",)
        else:
            pair = tuple(sorted((canonical(start), canonical(end))))
        # an edge and its mirror image have the same pair of canonical names
        edge_keys.append(pair)
    return _group_ids(vertex_keys), _group_ids(edge_keys)


def _group_ids(keys: Sequence[Any]) -> tuple[int, ...]:
    seen: dict[Any, int] = {}
    return tuple(seen.setdefault(k, len(seen)) for k in keys)


@dataclass(frozen=True)
class PolygonalModel:
    category: str
    names: tuple[str, ...]
    angle_mean: tuple[float, ...]
    angle_var: tuple[float, ...]
    length_mean: tuple[float, ...]
    length_var: tuple[float, ...]
    angle_groups: tuple[int, ...]
    length_groups: tuple[int, ...]
    simplify_vertices: int
    collared: PolygonalModel | None = None   # the garment with its neckline and collar as vertices

    def __post_init__(self) -> None:
        count = len(self.names)
        if count < 3:
            raise ModelError(f"model {self.category!r}: needs at least 3 vertices, got {count}")
        for field in ("angle_mean", "angle_var", "length_mean", "length_var",
                      "angle_groups", "length_groups"):
            if len(getattr(self, field)) != count:
                raise ModelError(f"model {self.category!r}: {field} has {len(getattr(self, field))} "
                                 f"entries, expected {count} (one per vertex)")
        for field in ("angle_var", "length_var"):
            if min(getattr(self, field)) <= 0:
                raise ModelError(f"model {self.category!r}: {field} must be > 0")
        if len(set(self.names)) != count:
            raise ModelError(f"model {self.category!r}: vertex names repeat")
        if self.simplify_vertices < count:
            raise ModelError(f"model {self.category!r}: simplify_vertices {self.simplify_vertices} "
                             f"< number of vertices {count}")
        if self.collared is not None:
            variant = self.collared
            if variant.category != self.category or variant.collared is not None:
                raise ModelError(f"model {self.category!r}: its collared variant must be a model of the "
                                 f"same category without a variant of its own")
            # the variant adds vertices between the model's and keeps their order
            if [name for name in variant.names if name in self.names] != list(self.names):
                raise ModelError(f"model {self.category!r}: its collared variant must hold the vertices "
                                 f"{', '.join(self.names)} in this order")

    @property
    def size(self) -> int:
        return len(self.names)

    def to_dict(self, exact: bool = False) -> dict[str, Any]:
        """The model as `model_from_fields` reads it; rounded for a model file people read, unless
        `exact` (a cell's job file reads back the model it wrote)."""
        mean = (lambda v: float(v)) if exact else (lambda v: round(float(v), 6))
        var = (lambda v: float(v)) if exact else (lambda v: float(f"{v:.6g}"))
        variant = {} if self.collared is None else {"collared": self.collared.to_dict(exact)}
        return {
            "category": self.category,
            "simplify_vertices": self.simplify_vertices,
            "vertices": [
                {"name": n, "angle_mean": mean(self.angle_mean[i]),
                 "angle_var": var(self.angle_var[i]), "angle_group": self.angle_groups[i],
                 "edge_length_mean": mean(self.length_mean[i]),
                 "edge_length_var": var(self.length_var[i]),
                 "edge_group": self.length_groups[i]}
                for i, n in enumerate(self.names)
            ],
            **variant,
        }


def model_from_fields(fields: Any) -> PolygonalModel:
    """Build a model from a `drivers.common.configfile.Fields` mapping; `recipe` is ignored."""
    from drivers.common.configfile import ConfigError

    fields.reject_unknown({"category", "simplify_vertices", "vertices", "recipe", "comment", "collared"})
    category = fields.str("category")
    simplify_vertices = fields.int("simplify_vertices", min=3, max=60)
    names: list[str] = []
    angle_mean, angle_var, length_mean, length_var = [], [], [], []
    angle_groups, length_groups = [], []
    for vertex in fields.items("vertices"):
        vertex.reject_unknown({"name", "angle_mean", "angle_var", "angle_group", "edge_length_mean",
                               "edge_length_var", "edge_group"})
        names.append(vertex.str("name"))
        angle_mean.append(vertex.float("angle_mean", min=0.0, max=2 * np.pi))
        angle_var.append(vertex.float("angle_var", positive=True))
        angle_groups.append(vertex.int("angle_group", min=0))
        length_mean.append(vertex.float("edge_length_mean", min=0.0, max=1.0))
        length_var.append(vertex.float("edge_length_var", positive=True))
        length_groups.append(vertex.int("edge_group", min=0))
    try:
        model = PolygonalModel(category, tuple(names), tuple(angle_mean), tuple(angle_var),
                               tuple(length_mean), tuple(length_var), tuple(angle_groups),
                               tuple(length_groups), simplify_vertices)
    except ModelError as exc:
        raise ConfigError(fields.file, fields.path("vertices"), str(exc)) from exc
    if not fields.has("collared"):
        return model
    try:
        return replace(model, collared=model_from_fields(fields.sub("collared")))
    except ModelError as exc:
        raise ConfigError(fields.file, fields.path("collared"), str(exc)) from exc


def learn_model(category: str, polygons: Sequence[NDArray], names: Sequence[str],
                simplify_vertices: int, min_var: Mapping[str, float] | None = None) -> PolygonalModel:
    """Fit a model from annotated polygons (each (M, 2) in the order of `names`).

    Each polygon is put in clockwise order (reversing names alongside where the data run
    counter-clockwise; the majority decides the stored order). Shared groups pool their samples.
    """
    if not polygons:
        raise ModelError(f"no annotated polygons for {category!r}")
    names = list(names)
    polys = [np.asarray(p, float) for p in polygons]
    reversed_count = sum(1 for p in polys if make_clockwise(p)[1])
    if reversed_count * 2 > len(polys):
        names = names[::-1]
        polys = [p[::-1] for p in polys]
    angles = np.array([polygon_angles(p) for p in polys])  # (K, M)
    lengths = np.array([relative_edge_lengths(p) for p in polys])
    angle_groups, length_groups = symmetry_groups(names)
    floors = dict(min_var or {})

    def pooled(values: NDArray, groups: tuple[int, ...], var_floor: float) -> tuple[list[float], list[float]]:
        means, variances = [0.0] * len(groups), [0.0] * len(groups)
        for group in set(groups):
            cols = [i for i, of in enumerate(groups) if of == group]
            sample = values[:, cols].ravel()
            mean = float(sample.mean())
            variance = float(sample.var()) if sample.size > 1 else var_floor
            for c in cols:
                means[c], variances[c] = mean, max(variance, var_floor)
        return means, variances

    angle_mean, angle_var = pooled(angles, angle_groups, floors.get("angle", 1e-4))
    length_mean, length_var = pooled(lengths, length_groups, floors.get("length", 1e-6))
    return PolygonalModel(category, tuple(names), tuple(angle_mean), tuple(angle_var), tuple(length_mean),
                          tuple(length_var), angle_groups, length_groups, simplify_vertices)
