"""CloPeMa annotation records: parsed from one YAML mapping, or read from a dataset folder.

The dataset's conventions (`shared/facts/clopema-dataset.md`): `left`/`right` are the garment's own
sides as worn; `facing: back` means the garment lies face down, so the picture is the mirror image of
a face-up one; misspellings (`rigth`, `sleave`) are read as the design spells them. A folded
garment's node list holds each fold line as two nodes named `fold_<k>` and every landmark where it
now lies: it is not an outline and is kept as the list it is (`nodes`).

Perception names landmarks as for a garment lying face up (it cannot tell the sides apart from the
outline), so `landmarks_as_seen` gives an annotation's landmarks in those terms: mirrored when the
garment lies face down.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from drivers.common.configfile import yaml_problem
from drivers.common.garments import LANDMARKS, TYPE_TO_CATEGORY, canonical_name, mirror_name

log = logging.getLogger(__name__)

FACINGS = ("front", "back")
SHAPES = ("flat", "wrinkled", "folded")
FOLD_NODE = re.compile(r"^fold_(\d+)$")

Point = tuple[float, float]


class AnnotationError(ValueError):
    """An annotation or a dataset folder that cannot be read; the message names it and why."""


@dataclass(frozen=True)
class Annotation:
    image: str                       # path_c, relative to the annotation file
    category: str
    type: str                        # the dataset's garment type (tshirt, polo, sweater...)
    shape: str                       # flat | wrinkled | folded
    facing: str | None               # front | back | None when the file does not say
    nodes: tuple[tuple[str, Point], ...]  # every node, file order, names as the design spells them
    moves: tuple[tuple[float, float, float, float], ...]
    flat_landmarks: dict[str, Point] | None  # foldcell's extension: the garment before its folds

    @property
    def landmarks(self) -> dict[str, Point]:
        """Named landmarks (fold-line ends left out), as annotated."""
        return {name: point for name, point in self.nodes if not FOLD_NODE.match(name)}

    @property
    def fold_lines(self) -> dict[int, tuple[Point, Point]]:
        """Fold k -> its two ends (a folded garment's `fold_<k>` node pairs)."""
        ends: dict[int, list[Point]] = {}
        for name, point in self.nodes:
            match = FOLD_NODE.match(name)
            if match:
                ends.setdefault(int(match.group(1)), []).append(point)
        return {k: (pts[0], pts[1]) for k, pts in sorted(ends.items()) if len(pts) == 2}

    @property
    def polygon(self) -> NDArray:
        """Every annotated point in file order (not an outline when the garment is folded)."""
        return np.asarray([point for _, point in self.nodes], float)

    @property
    def mirrored(self) -> bool:
        """The garment lies face down: its names are mirrored with respect to perception's."""
        return self.facing == "back"

    def landmarks_as_seen(self) -> dict[str, Point]:
        """The landmarks named as perception names them (as if face up): mirrored for `facing: back`."""
        if not self.mirrored:
            return self.landmarks
        return {mirror_name(name): point for name, point in self.landmarks.items()}

    def model_points(self, names: Sequence[str] | None = None) -> NDArray:
        """The category's model landmarks (or the nodes `names`) in that order, named as perception
        names them (other nodes, such as a shirt's collar, are left out). Raises if one is missing."""
        names = LANDMARKS[self.category] if names is None else names
        seen = self.landmarks_as_seen()
        missing = [n for n in names if n not in seen]
        if missing:
            raise AnnotationError(f"{self.image}: landmarks missing: {', '.join(missing)}")
        return np.asarray([seen[n] for n in names], float)


def _point(value: Any, where: str) -> Point:
    if (not isinstance(value, (list, tuple)) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                       for v in value)):
        raise AnnotationError(f"{where}: must be [x, y] with finite numbers, got {value!r}")
    return float(value[0]), float(value[1])


def _nodes(names: Any, points: Any, names_field: str, field: str) -> tuple[tuple[str, Point], ...]:
    if not isinstance(names, list) or not isinstance(points, list):
        raise AnnotationError(f"{names_field}, {field}: must be lists")
    if len(names) != len(points):
        raise AnnotationError(f"{field}: {len(points)} points for {len(names)} {names_field}")
    out = []
    for i, (entry, point) in enumerate(zip(names, points, strict=True)):
        name = entry[0] if isinstance(entry, list) and len(entry) == 1 else entry
        if not isinstance(name, str) or not name.strip():
            raise AnnotationError(f"{names_field}[{i}]: must be a one-element list holding a name, "
                                  f"got {entry!r}")
        out.append((canonical_name(name), _point(point, f"{field}[{i}]")))
    return tuple(out)


def _choice(data: Mapping[str, Any], key: str, choices: tuple[str, ...], default: str | None) -> str | None:
    value = data.get(key, default)
    if value is None:
        return None
    if not isinstance(value, str) or value.strip() not in choices:
        raise AnnotationError(f"{key}: must be one of {', '.join(choices)}, got {value!r}")
    return value.strip()


def parse_annotation(data: Mapping[str, Any]) -> Annotation:
    """One annotation mapping; errors name the field and the reason."""
    for key in ("path_c", "type", "node_names", "poly_c"):
        if key not in data:
            raise AnnotationError(f"missing field {key!r}")
    image, garment_type = data["path_c"], data["type"]
    if not isinstance(image, str) or not image:
        raise AnnotationError(f"path_c: must be an image file name, got {image!r}")
    if garment_type not in TYPE_TO_CATEGORY:
        raise AnnotationError(f"type: unknown garment type {garment_type!r} "
                              f"(known: {', '.join(sorted(TYPE_TO_CATEGORY))})")
    shape = _choice(data, "shape", SHAPES, "flat")
    facing = _choice(data, "facing", FACINGS, None)
    nodes = _nodes(data["node_names"], data["poly_c"], "node_names", "poly_c")
    raw_moves = data.get("moves") or []
    if not isinstance(raw_moves, list):
        raise AnnotationError(f"moves: must be a list of [x1, y1, x2, y2] rows, got {raw_moves!r}")
    moves = []
    for i, row in enumerate(raw_moves):
        if (not isinstance(row, list) or len(row) != 4
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)):
            raise AnnotationError(f"moves[{i}]: must be [x1, y1, x2, y2], got {row!r}")
        moves.append((float(row[0]), float(row[1]), float(row[2]), float(row[3])))
    flat = None
    if "poly_c_flat" in data and "node_names_flat" in data:
        flat = dict(_nodes(data["node_names_flat"], data["poly_c_flat"], "node_names_flat", "poly_c_flat"))
    return Annotation(image, TYPE_TO_CATEGORY[garment_type], garment_type, str(shape), facing, nodes,
                      tuple(moves), flat)


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
        except yaml.YAMLError as exc:
            log.warning("skipping %s: not valid YAML: %s", path, yaml_problem(exc))
        except (AnnotationError, OSError) as exc:
            log.warning("skipping %s: %s", path, exc)
    return out
