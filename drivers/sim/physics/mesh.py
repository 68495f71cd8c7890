"""A garment's cloth mesh cut from its outline: the outline's vertices (landmarks among them) and points
along its edges at most `spacing` apart, a triangular lattice inside, Delaunay triangles kept where
they lie inside the outline (so a concave outline, the pants' crotch or a shirt's armpit, keeps its
notch)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import Delaunay

from drivers.common.plane import FoldLine
from drivers.sim.geometry import point_segment_distance, points_in_polygon


def resample_outline(outline: np.ndarray, corners: list[int], spacing: float) -> np.ndarray:
    """The outline through its `corners` (sorted indices) with points about `spacing` apart along
    the stretch between two corners."""
    points: list[np.ndarray] = []
    for start, end in zip(corners, [*corners[1:], corners[0] + len(outline)], strict=True):
        stretch = outline[np.arange(start, end + 1) % len(outline)]
        lengths = np.linalg.norm(np.diff(stretch, axis=0), axis=1)
        along = np.concatenate([[0.0], np.cumsum(lengths)])
        pieces = max(1, round(float(along[-1]) / spacing))
        targets = np.linspace(0.0, float(along[-1]), pieces + 1)[:-1]
        points.extend(np.column_stack([np.interp(targets, along, stretch[:, 0]),
                                       np.interp(targets, along, stretch[:, 1])]))
    return np.array(points)


SLIVER_AREA = 0.01   # a triangle this x spacing^2 in (twice its) area is a sliver


@dataclass(frozen=True)
class ClothMesh:
    points: np.ndarray            # (V, 2) table x, y of the flat cloth's vertices
    triangles: np.ndarray         # (T, 3) vertex indices, counter-clockwise seen from above


def crease_points(outline: np.ndarray, line: FoldLine, spacing: float) -> np.ndarray:
    """Points about `spacing` apart along `line` where it crosses the inside of `outline`, each run
    starting and ending half a spacing in from the outline."""
    along = np.array([-line.normal[1], line.normal[0]])
    reach = float(np.max(np.linalg.norm(outline - line.point, axis=1)))
    samples = line.point + np.outer(np.arange(-reach, reach, spacing / 8.0), along)
    distance, _ = point_segment_distance(samples, outline)
    inside = points_in_polygon(samples, outline) & (distance > 0.5 * spacing)
    points: list[np.ndarray] = []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], inside.astype(np.int8), [0]])))
    for start, end in zip(edges[::2], edges[1::2], strict=True):
        first, last = samples[start], samples[end - 1]
        pieces = max(1, round(float(np.linalg.norm(last - first)) / spacing))
        points.extend(first + (last - first) * (k / pieces) for k in range(pieces + 1))
    return np.array(points).reshape(-1, 2)


def _crossing(first: FoldLine, second: FoldLine) -> np.ndarray | None:
    """Where two lines cross (None: parallel)."""
    matrix = np.array([first.normal, second.normal])
    if abs(float(np.linalg.det(matrix))) < 1e-9:
        return None
    return np.linalg.solve(matrix, [float(first.normal @ first.point), float(second.normal @ second.point)])


def cut_mesh(outline: np.ndarray, spacing: float, corners: list[int] | None = None,
             creases: tuple[FoldLine, ...] = ()) -> ClothMesh:
    """Triangulate the polygon `outline` ((N, 2), either winding) with edges about `spacing` long.
    `corners`: the outline vertices kept (default all); between two of them the outline is resampled
    at about `spacing` (a finely drawn outline would leave edges too short for a stable step).
    `creases`: lines along which vertices are set in a row, the lattice cleared half a spacing
    around them, so triangle edges run along them and a fold on such a line creases on it."""
    outline = np.asarray(outline, dtype=float)
    if corners is not None:
        outline = resample_outline(outline, sorted(set(corners)), spacing)
    boundary: list[np.ndarray] = []
    for start, end in zip(outline, np.roll(outline, -1, axis=0), strict=True):
        pieces = max(1, math.ceil(float(np.linalg.norm(end - start)) / spacing))
        boundary.extend(start + (end - start) * (k / pieces) for k in range(pieces))
    edge_points = np.array(boundary)
    # a triangular lattice: its triangles are equilateral, so the cloth bends alike in every direction;
    # its rows run along the garment's main axis, as the folds of a recipe do, so such a fold creases
    # along a straight row instead of a zigzag
    (centre_x, centre_y), _, degrees = cv2.minAreaRect(outline.astype(np.float32))
    angle = math.radians(degrees)
    rotation = np.array([[math.cos(angle), -math.sin(angle)], [math.sin(angle), math.cos(angle)]])
    centre = np.array([centre_x, centre_y])
    local = (outline - centre) @ rotation          # the outline in the lattice's frame
    low, high = local.min(axis=0), local.max(axis=0)
    row_step = spacing * math.sqrt(3.0) / 2.0
    lattice = [np.array([x + (spacing / 2.0 if row % 2 else 0.0), y])
               for row, y in enumerate(np.arange(low[1] + row_step / 2.0, high[1], row_step))
               for x in np.arange(low[0] + spacing / 2.0, high[0], spacing)]
    interior = np.array(lattice).reshape(-1, 2) @ rotation.T + centre
    if len(interior):
        distance, _ = point_segment_distance(interior, outline)
        interior = interior[points_in_polygon(interior, outline) & (distance > 0.5 * spacing)]
    for line in creases:
        if len(interior):
            interior = interior[np.abs(line.side(interior)) > 0.5 * spacing]
    rows = [crease_points(outline, line, spacing) for line in creases]
    crossings = []
    for i, first in enumerate(creases):
        for second in creases[i + 1:]:
            crossing = _crossing(first, second)
            if crossing is not None and points_in_polygon(crossing[None], outline)[0]:
                crossings.append(crossing)
        # the crossings stand for every row's points next to the other lines
        others = [line for line in creases if line is not first]
        rows[i] = rows[i][np.all([np.abs(o.side(rows[i])) > 0.5 * spacing for o in others], axis=0)] \
            if others and len(rows[i]) else rows[i]
    points = np.vstack([edge_points, interior, *rows, np.array(crossings).reshape(-1, 2)])
    triangles = Delaunay(points).simplices
    centroids = points[triangles].mean(axis=1)
    triangles = triangles[points_in_polygon(centroids, outline)]
    # counter-clockwise seen from above: the cloth's normals point up while it lies flat
    first, second, third = (points[triangles[:, k]] for k in range(3))
    cross = ((second - first)[:, 0] * (third - first)[:, 1] - (second - first)[:, 1] * (third - first)[:, 0])
    # Delaunay joins three points of one straight edge into a flat sliver: it has no area to bend
    sliver = np.abs(cross) < SLIVER_AREA * spacing ** 2
    triangles, cross = triangles[~sliver], cross[~sliver]
    triangles[cross < 0] = triangles[cross < 0][:, [0, 2, 1]]
    used = np.unique(triangles)
    if len(used) != len(points):
        # a lattice point whose triangles all fell outside: renumber without it
        renumber = np.full(len(points), -1)
        renumber[used] = np.arange(len(used))
        points, triangles = points[used], renumber[triangles]
    return ClothMesh(points, triangles.astype(np.int32))
