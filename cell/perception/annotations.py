"""CloPeMa annotation records (parsed from the YAML mapping; the file reading is the caller's)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .models import DESIGN_LANDMARKS, TYPE_TO_CATEGORY


class AnnotationError(ValueError):
    pass


def canonical_name(name: str) -> str:
    """The dataset's misspellings read as the design's names."""
    return name.strip().replace("rigth", "right").replace("sleave", "sleeve")


@dataclass(frozen=True)
class Annotation:
    image: str
    category: str
    shape: str
    landmarks: dict[str, tuple[float, float]]
    polygon: NDArray                 # all annotated points, file order
    moves: tuple[tuple[float, float, float, float], ...]
    flat_landmarks: dict[str, tuple[float, float]] | None

    def model_points(self) -> NDArray:
        """The category's design landmarks in design order (raises if one is missing)."""
        names = DESIGN_LANDMARKS[self.category]
        missing = [n for n in names if n not in self.landmarks]
        if missing:
            raise AnnotationError(f"{self.image}: landmarks missing: {', '.join(missing)}")
        return np.asarray([self.landmarks[n] for n in names], float)


def _named(names: Any, poly: Any, field: str) -> dict[str, tuple[float, float]]:
    if not isinstance(names, list) or not isinstance(poly, list) or len(names) != len(poly):
        raise AnnotationError(f"{field}: node names and polygon must be lists of equal length")
    out = {}
    for n, p in zip(names, poly):
        name = n[0] if isinstance(n, list) and n else n
        if not isinstance(name, str) or not isinstance(p, list) or len(p) != 2:
            raise AnnotationError(f"{field}: bad entry {n!r}: {p!r}")
        out[canonical_name(name)] = (float(p[0]), float(p[1]))
    return out


def parse_annotation(data: Mapping[str, Any]) -> Annotation:
    try:
        image = str(data["path_c"])
        typ = str(data["type"])
        shape = str(data.get("shape", "flat"))
        lms = _named(data["node_names"], data["poly_c"], "poly_c")
    except KeyError as exc:
        raise AnnotationError(f"missing field {exc.args[0]!r}") from exc
    if typ not in TYPE_TO_CATEGORY:
        raise AnnotationError(f"unknown garment type {typ!r}")
    moves = tuple(tuple(float(v) for v in m) for m in (data.get("moves") or []))
    flat = None
    if "poly_c_flat" in data and "node_names_flat" in data:
        flat = _named(data["node_names_flat"], data["poly_c_flat"], "poly_c_flat")
    poly = np.asarray([lms[k] for k in lms], float)
    return Annotation(image, TYPE_TO_CATEGORY[typ], shape, lms, poly, moves, flat)  # type: ignore[arg-type]
