"""Optimal polygonal approximation of a closed contour (Perez and Vidal style DP).

Cost of a polygon: the integral square error (ISE) of Perez and Vidal, the sum over contour
points of the squared distance to the line through the polygon edge spanning them (the edge
from vertex a to vertex b spans the contour points from a to b along the contour). Vertices are
chosen among candidate contour points.

* Open curve (`simplify_open`): exact DP over the candidates, first and last fixed.
* Closed curve (`simplify_closed`): exact. The DP is run for *every* start candidate at once
  (a min-plus product per vertex over the slacks of consecutive vertices), so no start is skipped;
  this is the cyclic optimum over the candidate set. Tests compare both with brute-force enumeration.
* The pipeline passes as candidates the vertices of a Douglas-Peucker approximation of the
  full contour with a sub-pixel-to-pixel tolerance (`candidates`), so the DP works on tens of
  points while the ISE still counts every contour pixel; the result is exact for that candidate
  set (not for all contour pixels as vertices).
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from .errors import PerceptionError


def _arc_moments(q: NDArray, start: NDArray, end: NDArray) -> tuple[NDArray, ...]:
    """Sums of 1, x, y, xx, yy, xy over the points `q` from `start` to `end` inclusive, `end`
    unrolled (start <= end < start + n): prefix sums over the contour once, and an arc past its
    last point adds the whole contour's sums."""
    n = len(q)
    x, y = q[:, 0], q[:, 1]
    pref = np.zeros((6, n + 1))
    np.cumsum(np.stack([np.ones_like(x), x, y, x * x, y * y, x * y]), axis=1, out=pref[:, 1:])
    wraps = end >= n
    return tuple(pref[t, end % n + 1] - pref[t, start] + wraps * pref[t, n] for t in range(6))


def edge_costs(points: NDArray, cand: NDArray) -> NDArray:
    """C[i, j]: ISE of the contour arc from cand[i] forward to cand[j] against line cand[i]cand[j]."""
    p = np.asarray(points, float)
    n = len(p)
    q = p - p.mean(axis=0)      # moments about the centroid: no cancellation in the sums
    c = np.asarray(cand, int)
    s = c[:, None]
    e = np.where(c[None, :] > s, c[None, :], c[None, :] + n)       # unrolled end, e > s
    cnt, sx, sy, sxx, syy, sxy = _arc_moments(q, s, e)
    A = q[c][:, None, :]
    B = q[c][None, :, :]
    d = B - A
    length = np.linalg.norm(d, axis=2)
    length = np.where(length > 0, length, 1.0)
    nx, ny = -d[..., 1] / length, d[..., 0] / length
    off = nx * A[..., 0] + ny * A[..., 1]
    cost = (nx * nx * sxx + ny * ny * syy + 2 * nx * ny * sxy
            - 2 * off * (nx * sx + ny * sy) + off * off * cnt)
    return np.maximum(cost, 0.0)


def simplify_open(costs: NDArray, k: int) -> tuple[float, list[int]]:
    """Exact: best polyline of k vertices over candidates 0..L-1 with both ends fixed."""
    L = costs.shape[0]
    if k < 2 or k > L:
        raise PerceptionError(f"cannot approximate {L} points by {k} vertices")
    # D[v, j]: best cost of a polyline from 0 to j with v+1 vertices
    cost = np.where(np.triu(np.ones((L, L), bool), 1), costs, np.inf)
    D = cost[0].copy()
    back = []
    for _ in range(k - 2):
        cand = D[:, None] + cost
        arg = np.argmin(cand, axis=0)
        D = cand[arg, np.arange(L)]
        back.append(arg)
    path = [L - 1]
    for arg in reversed(back):
        path.append(int(arg[path[-1]]))
    path.append(0)
    return float(D[L - 1]), path[::-1]


def simplify_closed_costs(costs: NDArray, k: int) -> tuple[float, list[int]]:
    """Exact cyclic optimum of k vertices over L candidates (all starts at once).

    Vertex v of the polygon starting at candidate s is candidate s + v + d_v (mod L), with slacks
    0 = d_0 <= d_1 <= ... <= d_{k-1} <= L - k. The best cost of the first v + 1 vertices with
    slack d is kept at [d, c] in the column c = s + v: in that frame every step adds the same
    edges, G[d, d', c] = costs[c - 1 + d, c + d'] (inf for d > d'), to the previous column, a
    min-plus product over d. Back-tracking recomputes the minima along the chosen path.
    """
    L = costs.shape[0]
    if k < 3 or k > L:
        raise PerceptionError(f"cannot approximate a closed contour of {L} candidate points by {k} vertices")
    E = L - k + 1
    column = np.arange(L)
    previous = (column - 1) % L
    slack = np.arange(E)[:, None]
    step = costs[(column - 1 + slack[:, :, None]) % L, (column + slack[None]) % L]     # G[d, d', c]
    step[slack > slack.T] = np.inf
    best_so_far = np.full((E, L), np.inf)
    best_so_far[0] = 0.0                                                                # vertex 0 at s
    kept = [best_so_far]
    candidate = np.empty_like(step)
    for _ in range(k - 1):
        np.add(best_so_far[:, None, previous], step, out=candidate)
        best_so_far = candidate.min(axis=0)
        kept.append(best_so_far)
    total = best_so_far + costs[(column + slack) % L, (column - (k - 1)) % L]          # last vertex back to s
    d, c = divmod(int(np.argmin(total)), L)
    best = float(total[d, c])
    vertices = []
    for v in range(k - 1, 0, -1):
        vertices.append(int((c + d) % L))
        d = int(np.argmin(kept[v - 1][:, previous[c]] + step[:, d, c]))
        c = previous[c]
    vertices.append(int(c))
    return best, sorted(vertices)


def candidates(contour: NDArray, tolerance: float, max_count: int, growth: float = 1.5) -> NDArray:
    """Indices of Douglas-Peucker vertices of the closed contour, at most `max_count` of them."""
    pts = np.asarray(contour, np.float32).reshape(-1, 1, 2)
    eps = tolerance
    while True:
        approx = cv2.approxPolyDP(pts, eps, True).reshape(-1, 2)
        if len(approx) <= max_count:
            break
        eps *= growth
    # map approximation vertices back to contour indices (approxPolyDP returns contour points)
    flat = np.asarray(contour, np.float64).reshape(-1, 2)
    # a point may occur twice on a contour; as before, the last occurrence is taken
    order = np.lexsort((np.arange(len(flat)), flat[:, 1], flat[:, 0]))
    sx, sy = flat[order, 0], flat[order, 1]
    ax, ay = approx[:, 0].astype(np.float64), approx[:, 1].astype(np.float64)
    # last position whose (x, y) <= the query, lexicographically
    lo = np.searchsorted(sx, ax, side="left")
    hi = np.searchsorted(sx, ax, side="right")
    idx = []
    for q in range(len(approx)):
        seg = sy[lo[q]:hi[q]]
        k = lo[q] + int(np.searchsorted(seg, ay[q], side="right")) - 1
        idx.append(int(order[k]))
    return np.asarray(sorted(set(idx)), int)


def simplify_closed(contour: NDArray, k: int, cand: NDArray | None = None) -> tuple[NDArray, float]:
    """Polygon (k, 2) approximating the closed contour, and its ISE."""
    pts = np.asarray(contour, float)
    if cand is None:
        cand = np.arange(len(pts))
    if len(cand) < k:
        raise PerceptionError(f"the contour has only {len(cand)} corner candidates, fewer than the "
                              f"{k} vertices asked for")
    costs = edge_costs(pts, cand)
    cost, verts = simplify_closed_costs(costs, k)
    return pts[np.asarray(cand)[verts]], cost


def with_points_near(polygon: NDArray, contour: NDArray, targets: NDArray, min_gap: float) -> NDArray:
    """`polygon` (vertices on `contour`) with, for each target, the contour point nearest to it
    added as a vertex, unless a vertex is already within `min_gap` of that point.

    A landmark that is expected somewhere (after a fold) may sit on a nearly straight stretch of the
    outline, where an optimal simplification puts no vertex; the matching can only place it on one.
    The order along the contour is kept.
    """
    c = np.asarray(contour, float)
    poly = np.asarray(polygon, float)

    def nearest(points: NDArray) -> NDArray:
        return np.array([int(np.argmin(((c - p) ** 2).sum(axis=1))) for p in points], int)

    index = list(nearest(poly))
    for t in nearest(np.asarray(targets, float)):
        if np.min(np.linalg.norm(poly - c[t], axis=1)) > min_gap:
            index.append(int(t))
    return c[np.unique(index)]
