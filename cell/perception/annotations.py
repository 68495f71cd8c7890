"""CloPeMa annotation records: parsed from one YAML mapping, or read from a dataset folder."""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from drivers.common.garments import LANDMARKS, TYPE_TO_CATEGORY, canonical_name

log = logging.getLogger(__name__)


class AnnotationError(ValueError):
    """An annotation or a dataset folder that cannot be read; the message names it and why."""


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
        names = LANDMARKS[self.category]
        missing = [n for n in names if n not in self.landmarks]
        if missing:
            raise AnnotationError(f"{self.image}: landmarks missing: {', '.join(missing)}")
        return np.asarray([self.landmarks[n] for n in names], float)


def _named(names: Any, poly: Any, field: str) -> dict[str, tuple[float, float]]:
    if not isinstance(names, list) or not isinstance(poly, list) or len(names) != len(poly):
        raise AnnotationError(f"{field}: node names and polygon must be lists of equal length")
    out = {}
    for n, p in zip(names, poly, strict=True):
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


def load_annotations(directory: str | Path) -> list[tuple[Path, Annotation]]:
    """(annotation file, Annotation) for every parsable annotation YAML in the folder, in name order.

    YAML files that are not image annotations (no `path_c`) are passed over; broken ones are
    logged and skipped, so one bad file does not end a run over the folder.
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise AnnotationError(f"{folder}: not a directory")
    out = []
    for path in sorted(folder.glob("*.yaml")) + sorted(folder.glob("*.yml")):
        try:
            data = yaml.safe_load(path.read_text())
            if not isinstance(data, dict) or "path_c" not in data:
                continue
            out.append((path, parse_annotation(data)))
        except (yaml.YAMLError, AnnotationError, OSError) as exc:
            log.warning("skipping %s: %s", path, exc)
    return out
