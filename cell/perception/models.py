"""Polygonal garment models (paper Sec. III-C): vertices, angle and edge-length distributions.

A model's vertices are stored in clockwise order on screen. Vertex m has an inner-angle
distribution N(angle_mean[m], angle_var[m]); edge m runs from vertex m to vertex m+1 (cyclic)
and has a relative-length distribution N(length_mean[m], length_var[m]) (length divided by the
perimeter). Vertices (edges) with the same entry in `angle_groups` (`length_groups`) share one
distribution, learned from the pooled samples, by the garment's left-right/top-bottom symmetry.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .errors import ModelError
from .geometry import make_clockwise, polygon_angles, relative_edge_lengths

CATEGORIES: tuple[str, ...] = ("towel", "pants", "short-sleeve", "long-sleeve")

# Landmark names of the design page, in its order.
DESIGN_LANDMARKS: dict[str, tuple[str, ...]] = {
    "towel": ("bottom-left", "bottom-right", "top-right", "top-left"),
    "pants": ("left-leg-outer", "left-leg-inner", "crotch", "right-leg-inner", "right-leg-outer",
              "top-right", "top-left"),
    "short-sleeve": ("bottom-left", "left-armpit", "left-sleeve-inner", "left-sleeve-outer",
                     "left-shoulder", "right-shoulder", "right-sleeve-outer", "right-sleeve-inner",
                     "right-armpit", "bottom-right"),
}
DESIGN_LANDMARKS["long-sleeve"] = DESIGN_LANDMARKS["short-sleeve"]

# Dataset `type` values -> category.
TYPE_TO_CATEGORY: dict[str, str] = {
    "towel": "towel", "pants": "pants", "tshirt": "short-sleeve", "polo": "short-sleeve",
    "shirt": "long-sleeve", "sweater": "long-sleeve",
    "short-sleeve": "short-sleeve", "long-sleeve": "long-sleeve",
}


def mirror_name(name: str) -> str:
    """left <-> right (the left-right symmetry used to share distributions)."""
    if "left" in name:
        return name.replace("left", "right")
    if "right" in name:
        return name.replace("right", "left")
    return name


def symmetry_groups(names: Sequence[str]) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """Angle and edge groups from left-right mirroring of names; towels also share top/bottom.

    Vertex names pair with their mirror; edge (a, b) pairs with edge (mirror b, mirror a).
    """
    def canon(n: str) -> str:
        n = mirror_name(n) if "right" in n else n
        return n

    def towel_canon(n: str) -> str:
        return canon(n.replace("top", "bottom"))

    is_towel = set(names) == set(DESIGN_LANDMARKS["towel"])
    key = towel_canon if is_towel else canon
    vkeys = [key(n) for n in names]
    m = len(names)
    ekeys: list[Any] = []
    for i in range(m):
        a, b = names[i], names[(i + 1) % m]
        if is_towel:
            # top and bottom edges share, left and right edges share
            pair = ("horizontal",) if a.split("-")[0] == b.split("-")[0] else ("vertical",)
        else:
            pair = tuple(sorted((key(a), key(b))))
        # an edge and its mirror image have the same pair of canonical names
        ekeys.append(pair)
    return _group_ids(vkeys), _group_ids(ekeys)


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

    def __post_init__(self) -> None:
        m = len(self.names)
        if m < 3:
            raise ModelError(f"model {self.category!r}: needs at least 3 vertices, got {m}")
        for field in ("angle_mean", "angle_var", "length_mean", "length_var",
                      "angle_groups", "length_groups"):
            if len(getattr(self, field)) != m:
                raise ModelError(f"model {self.category!r}: {field} has {len(getattr(self, field))} "
                                 f"entries, expected {m} (one per vertex)")
        for field in ("angle_var", "length_var"):
            if min(getattr(self, field)) <= 0:
                raise ModelError(f"model {self.category!r}: {field} must be > 0")
        if len(set(self.names)) != m:
            raise ModelError(f"model {self.category!r}: vertex names repeat")
        if self.simplify_vertices < m:
            raise ModelError(f"model {self.category!r}: simplify_vertices {self.simplify_vertices} "
                             f"< number of vertices {m}")

    @property
    def size(self) -> int:
        return len(self.names)

    def to_dict(self) -> dict[str, Any]:
        return {
            "category": self.category,
            "simplify_vertices": self.simplify_vertices,
            "vertices": [
                {"name": n, "angle_mean": round(float(self.angle_mean[i]), 6),
                 "angle_var": float(f"{self.angle_var[i]:.6g}"), "angle_group": self.angle_groups[i],
                 "edge_length_mean": round(float(self.length_mean[i]), 6),
                 "edge_length_var": float(f"{self.length_var[i]:.6g}"),
                 "edge_group": self.length_groups[i]}
                for i, n in enumerate(self.names)
            ],
        }


def model_from_fields(fields: Any) -> PolygonalModel:
    """Build a model from a `drivers.common.configfile.Fields` mapping; `recipe` is ignored."""
    from drivers.common.configfile import ConfigError

    fields.reject_unknown({"category", "simplify_vertices", "vertices", "recipe", "comment"})
    category = fields.str("category")
    n_simplify = fields.int("simplify_vertices", min=3, max=60)
    verts = fields.items("vertices")
    names, am, av, lm, lv, ag, lg = [], [], [], [], [], [], []
    for v in verts:
        v.reject_unknown({"name", "angle_mean", "angle_var", "angle_group", "edge_length_mean",
                          "edge_length_var", "edge_group"})
        names.append(v.str("name"))
        am.append(v.float("angle_mean", min=0.0, max=2 * np.pi))
        av.append(v.float("angle_var", positive=True))
        ag.append(v.int("angle_group", min=0))
        lm.append(v.float("edge_length_mean", min=0.0, max=1.0))
        lv.append(v.float("edge_length_var", positive=True))
        lg.append(v.int("edge_group", min=0))
    try:
        return PolygonalModel(category, tuple(names), tuple(am), tuple(av), tuple(lm), tuple(lv),
                              tuple(ag), tuple(lg), n_simplify)
    except ModelError as exc:
        raise ConfigError(fields.file, "vertices", str(exc)) from exc


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
    n_rev = sum(1 for p in polys if make_clockwise(p)[1])
    if n_rev * 2 > len(polys):
        names = names[::-1]
        polys = [p[::-1] for p in polys]
    angles = np.array([polygon_angles(p) for p in polys])  # (K, M)
    lengths = np.array([relative_edge_lengths(p) for p in polys])
    ag, lg = symmetry_groups(names)
    floor = dict(min_var or {})
    a_floor, l_floor = floor.get("angle", 1e-4), floor.get("length", 1e-6)

    def pooled(values: NDArray, groups: tuple[int, ...], var_floor: float) -> tuple[list, list]:
        means, vars_ = [0.0] * len(groups), [0.0] * len(groups)
        for g in set(groups):
            cols = [i for i, gi in enumerate(groups) if gi == g]
            sample = values[:, cols].ravel()
            mu = float(sample.mean())
            var = float(sample.var()) if sample.size > 1 else var_floor
            for c in cols:
                means[c], vars_[c] = mu, max(var, var_floor)
        return means, vars_

    am, av = pooled(angles, ag, a_floor)
    lm, lv = pooled(lengths, lg, l_floor)
    return PolygonalModel(category, tuple(names), tuple(am), tuple(av), tuple(lm), tuple(lv), ag, lg,
                          simplify_vertices)
