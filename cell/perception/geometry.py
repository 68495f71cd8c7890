"""Plane geometry on pixel polygons (image axes: x right, y down).

A polygon is *clockwise* when it turns clockwise on screen; with y down that is a positive
shoelace sum (`drivers.common.plane.signed_area`). Inner angles are in [0, 2*pi): pi/2 at each
corner of a rectangle, more than pi at a concave vertex.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from drivers.common.plane import edge_lengths, signed_area

Points = NDArray[np.float64]  # (n, 2) pixel coordinates


def make_clockwise(poly: Points) -> tuple[Points, bool]:
    """The polygon in clockwise order and whether it was reversed."""
    p = np.asarray(poly, dtype=float)
    if signed_area(p) < 0:
        return p[::-1].copy(), True
    return p, False


def inner_angle(prev: NDArray, vertex: NDArray, nxt: NDArray) -> NDArray:
    """Inner angle at `vertex` of a clockwise polygon, broadcasting over leading axes."""
    a = np.asarray(prev, float) - vertex
    b = np.asarray(nxt, float) - vertex
    ang = np.arctan2(a[..., 1], a[..., 0]) - np.arctan2(b[..., 1], b[..., 0])
    return np.mod(ang, 2 * np.pi)


def inner_angles_of_triples(points: Points) -> NDArray:
    """ang[i, j, k] = `inner_angle`(p_i, p_j, p_k) for every triple of points, from the N^2
    directions between them (N^3 arctan2 calls would cost more than the rest of a matching)."""
    p = np.asarray(points, float)
    d = p[None, :, :] - p[:, None, :]                 # d[j, i] = p_i - p_j
    heading = np.arctan2(d[..., 1], d[..., 0])
    ang = heading.T[:, :, None] - heading[None, :, :]
    ang += (ang < 0) * (2 * np.pi)     # as np.mod over (-2 pi, 2 pi), at a fraction of its cost
    return ang


def polygon_angles(poly: Points) -> NDArray:
    """Inner angle at every vertex of a clockwise polygon."""
    p = np.asarray(poly, float)
    return inner_angle(np.roll(p, 1, axis=0), p, np.roll(p, -1, axis=0))


def relative_edge_lengths(poly: Points) -> NDArray:
    lengths = edge_lengths(poly)
    return lengths / lengths.sum()
