"""Planar polygon helpers for the simulated world (table frame, metres, z up).

"Clockwise" is as seen from above (negative shoelace area in the right-handed table frame), which is
clockwise on screen for a camera looking down.
"""

from __future__ import annotations

import numpy as np

from drivers.common.plane import FoldLine, signed_area


def is_clockwise(poly: np.ndarray) -> bool:
    return signed_area(poly) < 0.0


def clip_halfplane(poly: np.ndarray, line: FoldLine, keep_positive: bool) -> np.ndarray:
    """Sutherland-Hodgman clip of a polygon to one side of a line.

    A non-convex polygon cut into several pieces comes back as one ring joined by zero-area bridges
    along the line, which fills and measures correctly.
    """
    p = np.asarray(poly, dtype=float)
    s = line.side(p)
    if not keep_positive:
        s = -s
    out: list[np.ndarray] = []
    n = len(p)
    for i in range(n):
        a, b = p[i], p[(i + 1) % n]
        sa, sb = s[i], s[(i + 1) % n]
        if sa >= 0:
            out.append(a)
        if (sa >= 0) != (sb >= 0):
            t = sa / (sa - sb)
            out.append(a + t * (b - a))
    return np.array(out).reshape(-1, 2)


def point_segment_distance(pts: np.ndarray, poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of each point to a closed polyline and the nearest point on it."""
    pts = np.atleast_2d(np.asarray(pts, dtype=float))
    a = np.asarray(poly, dtype=float)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    den = np.maximum((ab * ab).sum(1), 1e-18)
    t = np.clip(((pts[:, None, :] - a[None]) * ab[None]).sum(2) / den[None], 0.0, 1.0)
    near = a[None] + t[..., None] * ab[None]
    d = np.linalg.norm(pts[:, None, :] - near, axis=2)
    k = d.argmin(1)
    idx = np.arange(len(pts))
    return d[idx, k], near[idx, k]


def nearest_edge(poly: np.ndarray, point: np.ndarray) -> tuple[int, float]:
    """The edge i -> i+1 (cyclic) of a closed polyline nearest to `point`, and how far along it
    (0..1) the nearest point lies."""
    a = np.asarray(poly, dtype=float)
    b = np.roll(a, -1, axis=0)
    ab = b - a
    along = ((np.asarray(point, dtype=float) - a) * ab).sum(1)
    t = np.clip(along / np.maximum((ab * ab).sum(1), 1e-18), 0, 1)
    distance = np.linalg.norm(a + t[:, None] * ab - point, axis=1)
    i = int(distance.argmin())
    return i, float(t[i])


def fold_line_ends(poly: np.ndarray, line: FoldLine) -> np.ndarray:
    """Where the fold line enters and leaves a closed polygon: its outermost crossings, (2, 2), or
    (0, 2) when the line misses it."""
    a = np.asarray(poly, dtype=float)
    b = np.roll(a, -1, axis=0)
    sa, sb = line.side(a), line.side(b)
    crossing = (sa > 0) != (sb > 0)
    if not crossing.any():
        return np.zeros((0, 2))
    t = sa[crossing] / (sa[crossing] - sb[crossing])
    points = a[crossing] + t[:, None] * (b[crossing] - a[crossing])
    along = points @ np.array([-line.normal[1], line.normal[0]])
    return points[[int(along.argmin()), int(along.argmax())]]


def points_in_polygon(pts: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule point-in-polygon for (N, 2) points."""
    pts = np.atleast_2d(np.asarray(pts, dtype=float))
    a = np.asarray(poly, dtype=float)
    b = np.roll(a, -1, axis=0)
    x, y = pts[:, 0:1], pts[:, 1:2]
    cond = (a[None, :, 1] > y) != (b[None, :, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = a[None, :, 0] + (y - a[None, :, 1]) * (b[None, :, 0] - a[None, :, 0]) / (b[None, :,
                                                                                          1] - a[None, :, 1])
    return (np.sum(cond & (x < xint), axis=1) % 2) == 1


def segments_intersect(poly: np.ndarray) -> bool:
    """True when a closed polygon's non-adjacent edges cross (it is not simple)."""
    p = np.asarray(poly, dtype=float)
    n = len(p)
    a, b = p, np.roll(p, -1, axis=0)

    def orient(p0: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
        return np.sign((p1[..., 0] - p0[..., 0]) * (p2[..., 1] - p0[..., 1])
                       - (p1[..., 1] - p0[..., 1]) * (p2[..., 0] - p0[..., 0]))

    i, j = np.triu_indices(n, k=2)
    keep = ~((i == 0) & (j == n - 1))
    i, j = i[keep], j[keep]
    o1 = orient(a[i], b[i], a[j])
    o2 = orient(a[i], b[i], b[j])
    o3 = orient(a[j], b[j], a[i])
    o4 = orient(a[j], b[j], b[i])
    return bool(np.any((o1 * o2 < 0) & (o3 * o4 < 0)))


def rigid_fit(before: np.ndarray, after: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rotation R (2x2) and shift t that best carry points `before` onto `after` (both (n, 2)),
    after ~ before @ R.T + t, by least squares (Kabsch)."""
    a, b = np.asarray(before, dtype=float), np.asarray(after, dtype=float)
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    u, _, vt = np.linalg.svd((a - ca).T @ (b - cb))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, d]) @ u.T
    return rotation, cb - ca @ rotation.T
