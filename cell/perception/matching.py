"""Contour-to-model matching (paper Sec. III-D/E, Alg. 1, costs of Eq. 4 to 7).

Exactness. A mapping assigns model vertex m to contour point idx[m], with idx strictly
increasing cyclically (Eq. 3 counts them: N * C(N-1, M-1)). Its cost is

    C = sum_m V^m(idx[m-1], idx[m], idx[m+1]) + E^m(idx[m], idx[m+1]) + S(idx[m], idx[m+1]).

Alg. 1 fixes idx[0] by a cyclic shift and idx[M-1] = r, and runs a DP whose state is the pair
(idx[m-1], idx[m]). We run the same DP for *all* shifts and all anchors at once: we fix
a = idx[0] and b = idx[1] (instead of r; both anchor the cyclic closure equally) and write
idx[m] = a + m + d_m with slacks 0 <= d_1 <= ... <= d_{M-1} <= N - M. The state tensor
T[a, b, d_{m-1}, d_m] holds the exact minimum over the earlier slacks, so the final minimum over
(a, b, d_{M-2}, d_{M-1}) after adding the closing terms is the global optimum over every valid
mapping; back-tracking from it recovers the mapping. tests/perception/test_matching.py checks
this against enumeration of Eq. 3 on random small instances.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.common.landmarks import IMAGE, Landmarks
from drivers.common.plane import perimeter

from .errors import ModelError
from .geometry import inner_angles_of_triples, make_clockwise, polygon_angles
from .models import PolygonalModel

_LOG_2PI = float(np.log(2 * np.pi))


@dataclass(frozen=True)
class MatchWeights:
    vertex: float = 1.0          # lambda_V
    edge: float = 1.0 / 3.0      # lambda_E
    segment: float = 1.0         # lambda_S
    straight_mean: float = float(np.pi)            # xi
    straight_var: float = float(np.pi ** 2 / 16)   # phi^2
    upright_margin: float = 3.0  # cost gap within which relabellings are decided by uprightness
    position: float = 1.0        # lambda_P: weight of the expected-position term (folded garments)
    position_sigma: float = 0.05  # its standard deviation, as a fraction of the expected outline's perimeter


@dataclass(frozen=True)
class MatchResult:
    cost: float
    mapping: tuple[int, ...]      # mapping[m] = index of the contour point matched to vertex m
    points: NDArray               # the clockwise contour polygon the indices refer to
    landmarks: Landmarks          # the model's vertices where they were matched (image)


def _neg_log_normal(x: NDArray, mean: NDArray | float, var: NDArray | float, weight: float = 1.0) -> NDArray:
    """weight * -log N(x; mean, var), broadcast, computed in its one output array (temporaries of a
    vertex table's size cost more in page faults than the arithmetic)."""
    var = np.asarray(var, float)
    out = np.subtract(x, mean)
    np.square(out, out=out)
    out *= weight / (2.0 * var)
    out += weight * 0.5 * (_LOG_2PI + np.log(var))
    return out


@dataclass(frozen=True)
class CostTables:
    """All local costs for one contour and one model."""
    V: NDArray   # (M, N, N, N)  V[m, i, j, k]
    ES: NDArray  # (M, N, N)     E[m, j, k] + S[j, k]


def position_cost(points: NDArray, expected: NDArray, w: MatchWeights) -> NDArray:
    """P[m, j]: the cost of putting model vertex m on contour point j when m is expected at
    `expected[m]` (an isotropic normal whose deviation is `position_sigma` of the perimeter of
    the expected outline), weighted by lambda_P."""
    e = np.asarray(expected, float)
    sigma = max(w.position_sigma * perimeter(e), 1e-9)
    d2 = ((np.asarray(points, float)[None, :, :] - e[:, None, :]) ** 2).sum(axis=2)
    return w.position * d2 / (2.0 * sigma ** 2)


def cost_tables(points: NDArray, model: PolygonalModel, w: MatchWeights,
                expected: NDArray | None = None) -> CostTables:
    """Local costs; with `expected` (M, 2), each vertex also pays `position_cost` (the fold tells
    where a folded garment's landmarks are: its nearly symmetric outline alone often cannot)."""
    p = np.asarray(points, float)
    n = len(p)
    # angle tensor ang[i, j, k] = inner angle of p_i p_j p_k, flattened: the vertex costs run over
    # rows of N^3 (broadcasting against an inner axis of only N is several times slower)
    ang = inner_angles_of_triples(p).reshape(1, -1)
    V = _neg_log_normal(ang, np.asarray(model.angle_mean)[:, None], np.asarray(model.angle_var)[:, None],
                        w.vertex).reshape(model.size, n, n, n)
    if expected is not None:
        if np.shape(expected) != (model.size, 2):
            raise ModelError(f"expected positions must be ({model.size}, 2) for model {model.category!r}, "
                             f"got {np.shape(expected)}")
        V += position_cost(p, expected, w)[:, None, :, None]
    seg = np.linalg.norm(p[None, :, :] - p[:, None, :], axis=2)
    rel = seg / perimeter(p)
    E = _neg_log_normal(rel[None], np.asarray(model.length_mean)[:, None, None],
                        np.asarray(model.length_var)[:, None, None], w.edge)
    # S[j, k]: straightness penalty of the points strictly between j and k (Eq. 6, 7)
    own = _neg_log_normal(polygon_angles(p), w.straight_mean, w.straight_var, w.segment)
    csum = np.concatenate([[0.0], np.cumsum(np.concatenate([own, own]))])
    j = np.arange(n)[:, None]
    k = np.arange(n)[None, :]
    kk = np.where(k > j, k, k + n)  # unrolled end index
    S = csum[kk] - csum[j + 1]
    return CostTables(V, E + S[None])


def mapping_cost(tables: CostTables, mapping: tuple[int, ...]) -> float:
    """C(f) of one mapping (for tests and back-tracking checks)."""
    m_count = len(mapping)
    total = 0.0
    for m in range(m_count):
        i, j, k = mapping[m - 1], mapping[m], mapping[(m + 1) % m_count]
        total += tables.V[m, i, j, k] + tables.ES[m, j, k]
    return float(total)


@dataclass(frozen=True)
class _DPIndex:
    """Gather indices of the DP for a contour of N points and a model of M vertices.

    States are slack triples (b, x, y) = (d_1, d_m, d_{m+1}), 0 <= b <= x <= y < D = N - M + 1,
    kept as T[state, c] in the column c = (a + m) % N of shift a: in that frame every step gathers
    with the same indices, whole rows of N columns at a time. A state's predecessors are
    (b, b + t, x) for t = 0 .. x - b; states are sorted by x - b, largest first, so those having a
    t-th predecessor are a prefix (`prefix[t]` of them) and the minimum over predecessors is a few
    contiguous element-wise minima.
    """
    states: NDArray         # (S, 3) b, x, y
    prefix: tuple[int, ...]   # (D,) how many states have a t-th predecessor
    offsets: tuple[int, ...]  # (D + 1,) where the t-th predecessors start in `pred` and `triple`
    pred: NDArray           # (Q,) the predecessor's row of T (in the previous column)
    triple: NDArray         # (Q,) the row of `triple_at` of its vertex term
    triple_at: NDArray      # (R, N) into (N, N, N): (idx[m-1], idx[m], idx[m+1]) of slacks (d_{m-1}, x, y)
    edge_at: NDArray        # (S, N) into (N, N): (idx[m], idx[m+1])
    first_edge: NDArray     # (S, N) into (N, N): (idx[0], idx[1]), in the column of m = 1
    first_vertex: NDArray   # (S, N) into (N, N, N): (idx[0], idx[1], idx[2])
    first_valid: NDArray    # (S,): x == b, as d_1 is both once vertex 2 is placed
    close_vertex: NDArray   # (S, N) into (N, N, N): (idx[M-2], idx[M-1], idx[0]), in the column of m = M-2
    close_edge: NDArray     # (S, N) into (N, N): (idx[M-1], idx[0])
    close_first: NDArray    # (S, N) into (N, N, N): (idx[M-1], idx[0], idx[1])


@functools.lru_cache(maxsize=16)
def _dp_index(N: int, M: int) -> _DPIndex:
    """Computed once per (N, M): they depend on the sizes only."""
    D = N - M + 1
    triples = [(b, x, y) for b in range(D) for x in range(b, D) for y in range(x, D)]
    states = np.array(sorted(triples, key=lambda s: s[0] - s[1]), np.intp)   # stable: x - b descending
    row = {s: i for i, s in enumerate(map(tuple, states.tolist()))}
    prefix = tuple(int(np.sum(states[:, 1] - states[:, 0] >= t)) for t in range(D))
    # the vertex term of predecessor (b, di, x) -> (b, x, y) depends on (di, x, y) only: a state triple
    quads = [(bb, bb + t, xx, yy) for t, count in enumerate(prefix) for bb, xx, yy in states[:count].tolist()]
    pred = np.array([row[(bb, di, xx)] for bb, di, xx, _ in quads], np.intp)
    triple = np.array([row[(di, xx, yy)] for _, di, xx, yy in quads], np.intp)
    b, x, y = (states[:, i, None] for i in range(3))
    c = np.arange(N)
    first = c - (M - 2)   # idx[0] seen from the column of the last step
    return _DPIndex(
        states, prefix, tuple(int(o) for o in np.cumsum((0, *prefix))), pred, triple,
        _flat(N, c - 1 + b, c + x, c + 1 + y), _flat(N, c + x, c + 1 + y),
        _flat(N, c - 1, c + b), _flat(N, c - 1, c + b, c + 1 + y), states[:, 1] == states[:, 0],
        _flat(N, c + x, c + 1 + y, first), _flat(N, c + 1 + y, first),
        _flat(N, c + 1 + y, first, first + 1 + b))


def _flat(N: int, *index: NDArray) -> NDArray:
    """Flat index into an (N,) * len(index) table of cyclic contour indices."""
    flat = np.zeros(np.broadcast_shapes(*(np.shape(i) for i in index)), np.intp)
    for i in index:
        flat = flat * N + np.mod(i, N)
    return flat


def match_tables(tables: CostTables) -> tuple[float, tuple[int, ...]]:
    """Global optimum of C(f) over all valid mappings (see module docstring).

    Step m places vertex m + 1: it adds V^m at (idx[m-1], idx[m], idx[m+1]), minimises over
    idx[m-1], then adds E^m + S at (idx[m], idx[m+1]). The minima of every step are kept, and the
    back-tracking recomputes the few candidates of the one chosen state instead of storing argmins.
    """
    V, ES = tables.V, tables.ES
    M, N = V.shape[0], V.shape[1]
    if N < M:
        raise ModelError(f"contour has {N} points, fewer than the model's {M} vertices")
    ix = _dp_index(N, M)
    Vf, ESf = V.reshape(M, -1), ES.reshape(M, -1)
    T = ESf[0].take(ix.first_edge) + Vf[1].take(ix.first_vertex) + ESf[1].take(ix.edge_at)
    T[~ix.first_valid] = np.inf
    kept = [T]
    for m in range(2, M - 1):
        # the first step's states all have d_1 = d_2 (x == b): their only finite predecessor is t = 0
        slabs = 1 if m == 2 else len(ix.prefix)
        used = ix.offsets[slabs]
        previous = np.concatenate((T[:, -1:], T[:, :-1]), axis=1)      # column c holds column c - 1
        cand = previous.take(ix.pred[:used], axis=0)
        cand += Vf[m].take(ix.triple_at).take(ix.triple[:used], axis=0)
        T = cand[:ix.prefix[0]].copy()
        for t in range(1, slabs):
            np.minimum(T[:ix.prefix[t]], cand[ix.offsets[t]:ix.offsets[t + 1]], out=T[:ix.prefix[t]])
        T += ESf[m].take(ix.edge_at)
        kept.append(T)
    final = T + Vf[M - 1].take(ix.close_vertex) + ESf[M - 1].take(ix.close_edge) + Vf[0].take(ix.close_first)
    flat = int(np.argmin(final))
    best = float(final.flat[flat])
    if not np.isfinite(best):
        raise ModelError("no valid mapping of the contour to the model")
    state, column = divmod(flat, N)
    b, x, y = (int(v) for v in ix.states[state])
    slacks = [0] * M
    slacks[1], slacks[M - 2], slacks[M - 1] = b, x, y
    for m in range(M - 2, 1, -1):       # step m chose d_{m-1} = b + t
        rows = np.add(ix.offsets[:x - b + 1], state)
        preds = ix.pred[rows]
        before = kept[m - 2][preds, (column - 1) % N] + Vf[m].take(ix.triple_at[ix.triple[rows], column])
        state = int(preds[int(np.argmin(before))])
        column = (column - 1) % N
        x = int(ix.states[state, 1])
        slacks[m - 1] = x
    mapping = tuple(int((column - 1 + m + slacks[m]) % N) for m in range(M))
    return best, mapping


def _upright(tables: CostTables, mapping: tuple[int, ...], cost: float, pts: NDArray,
             model: PolygonalModel, margin: float) -> tuple[int, ...]:
    """Among (nearly) equal-cost cyclic relabellings, the one lying upright.

    Shared distributions make a symmetric model's mapping ambiguous (a towel turned by 180 deg
    has the same cost; a nearly square one turned by 90 deg almost the same); the landmark
    convention (the garment's top towards the image top) decides among relabellings whose cost
    is within `margin` of the optimum. The vertex assignment itself stays the optimal one.
    """
    m_count = len(mapping)
    tol = 1e-9 * max(1.0, abs(cost)) + margin
    ties = []
    for r in range(m_count):
        rot = tuple(mapping[(m + r) % m_count] for m in range(m_count))
        if mapping_cost(tables, rot) - cost <= tol:
            ties.append(rot)
    if len(ties) <= 1:
        return mapping
    top = [i for i, n in enumerate(model.names) if "top" in n or "shoulder" in n]
    if not top:
        return mapping
    return min(ties, key=lambda mp: float(np.mean([pts[mp[i], 1] for i in top])))


def match(points: NDArray, model: PolygonalModel, weights: MatchWeights | None = None,
          expected: NDArray | None = None) -> MatchResult:
    """Match a simplified contour (any orientation) to a model; the contour is made clockwise.

    `expected` (M, 2), in the model's vertex order and the contour's units, adds the position
    term of `cost_tables` (the global optimum stays exact); the reported cost then includes it.
    """
    w = weights or MatchWeights()
    pts, _ = make_clockwise(np.asarray(points, float))
    tables = cost_tables(pts, model, w, expected)
    cost, mapping = match_tables(tables)
    if expected is None:  # the expected positions already tell the labels apart
        mapping = _upright(tables, mapping, cost, pts, model, w.upright_margin)
    return MatchResult(cost, mapping, pts, Landmarks(IMAGE, model.names, pts[list(mapping)]))
