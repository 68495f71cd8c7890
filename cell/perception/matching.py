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
mapping; back-tracking the stored argmins recovers it. tests/perception/test_matching.py checks
this against enumeration of Eq. 3 on random small instances.
"""

from __future__ import annotations

import functools
import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from .errors import ModelError
from .geometry import inner_angle, make_clockwise, polygon_edge_lengths
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
    landmarks: dict[str, tuple[float, float]]


def _neg_log_normal(x: NDArray, mean: NDArray | float, var: NDArray | float) -> NDArray:
    return 0.5 * (_LOG_2PI + np.log(var)) + (x - mean) ** 2 / (2.0 * var)


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
    sigma = max(w.position_sigma * float(polygon_edge_lengths(e).sum()), 1e-9)
    d2 = ((np.asarray(points, float)[None, :, :] - e[:, None, :]) ** 2).sum(axis=2)
    return w.position * d2 / (2.0 * sigma ** 2)


def cost_tables(points: NDArray, model: PolygonalModel, w: MatchWeights,
                expected: NDArray | None = None) -> CostTables:
    """Local costs; with `expected` (M, 2), each vertex also pays `position_cost` (the fold tells
    where a folded garment's landmarks are: its nearly symmetric outline alone often cannot)."""
    p = np.asarray(points, float)
    n = len(p)
    # angle tensor ang[i, j, k] = inner angle of p_i p_j p_k
    ang = inner_angle(p[:, None, None, :], p[None, :, None, :], p[None, None, :, :])
    means = np.asarray(model.angle_mean)[:, None, None, None]
    vars_ = np.asarray(model.angle_var)[:, None, None, None]
    V = w.vertex * _neg_log_normal(ang[None], means, vars_)
    if expected is not None:
        if np.shape(expected) != (model.size, 2):
            raise ModelError(f"expected positions must be ({model.size}, 2) for model {model.category!r}, "
                             f"got {np.shape(expected)}")
        V = V + position_cost(p, expected, w)[:, None, :, None]
    seg = np.linalg.norm(p[None, :, :] - p[:, None, :], axis=2)
    perimeter = float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())
    rel = seg / perimeter
    E = w.edge * _neg_log_normal(rel[None], np.asarray(model.length_mean)[:, None, None],
                                 np.asarray(model.length_var)[:, None, None])
    # S[j, k]: straightness penalty of the points strictly between j and k (Eq. 6, 7)
    own = w.segment * _neg_log_normal(inner_angle(np.roll(p, 1, 0), p, np.roll(p, -1, 0)),
                                      w.straight_mean, w.straight_var)
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


def brute_force(tables: CostTables) -> tuple[float, tuple[int, ...]]:
    """Enumerate every valid mapping of Eq. 3 (small instances only)."""
    m_count, n = tables.V.shape[0], tables.V.shape[1]
    best, best_map = np.inf, ()
    for a in range(n):
        rest = [(a + t) % n for t in range(1, n)]
        for combo in itertools.combinations(rest, m_count - 1):
            mp = (a, *combo)
            c = mapping_cost(tables, mp)
            if c < best:
                best, best_map = c, mp
    return best, best_map


@functools.lru_cache(maxsize=64)
def _slack_states(D: int) -> tuple[NDArray, NDArray, NDArray]:
    """Packed DP states (b, x, y), 0 <= b <= x <= y < D, and for each its predecessors.

    pred[s, t] is the index of state (b, di, x) for di = b + t (the extra index S, holding
    infinity, pads the rows of states with fewer predecessors); pred_di holds di.
    """
    states = np.array([(b, x, y) for b in range(D) for x in range(b, D) for y in range(x, D)], int)
    index = {tuple(st): i for i, st in enumerate(states)}
    S = len(states)
    pred = np.full((S, D), S, int)
    pred_di = np.zeros((S, D), int)
    for i, (b, x, _) in enumerate(states):
        for t, di in enumerate(range(b, x + 1)):
            pred[i, t] = index[(b, di, x)]
            pred_di[i, t] = di
    return states, pred, pred_di


@functools.lru_cache(maxsize=32)
def _dp_indices(N: int, M: int) -> tuple:
    """Flat gather indices of every DP level for a contour of N points and a model of M vertices.

    They depend on the sizes only, so they are computed once per (N, M) and reused.
    """
    D = N - M + 1
    states, pred, pred_di = _slack_states(D)
    b, x, y = states[:, 0], states[:, 1], states[:, 2]
    a = np.arange(N)[:, None]
    i0, i1, i2 = a % N, (a + 1 + b) % N, (a + 2 + y) % N
    init = (i0 * N + i1, (i0 * N + i1) * N + i2, i1 * N + i2, x == b)
    a3 = a[:, :, None]
    steps = []
    for m in range(2, M - 1):
        ii = (a3 + m - 1 + pred_di) % N
        jj = (a + m + x) % N
        kk = (a + m + 1 + y) % N
        steps.append(((ii * N + jj[..., None]) * N + kk[..., None], jj * N + kk))
    ip, il, i1 = (a + M - 2 + x) % N, (a + M - 1 + y) % N, (a + 1 + b) % N
    close = ((ip * N + il) * N + a, il * N + a, (il * N + a) * N + i1)
    return states, pred, init, steps, close


def match_tables(tables: CostTables) -> tuple[float, tuple[int, ...]]:
    """Global optimum of C(f) over all valid mappings (see module docstring).

    The state tensor is packed: only slack triples (b, d_{m-1}, d_m) with b <= d_{m-1} <= d_m
    are stored, for all shifts a at once, so each level is one gather, one add and one
    min-reduction over the predecessor slack.
    """
    V, ES = tables.V, tables.ES
    M, N = V.shape[0], V.shape[1]
    if N < M:
        raise ModelError(f"contour has {N} points, fewer than the model's {M} vertices")
    states, pred, init, steps, close = _dp_indices(N, M)
    S = len(states)
    Vf = V.reshape(M, -1)
    ESf = ES.reshape(M, -1)
    inf = np.inf
    # level 2 (vertices 0, 1, 2 placed): idx0 = a, idx1 = a + 1 + b, idx2 = a + 2 + y; needs x == b
    e01, v012, e12, valid = init
    T = np.where(valid, ESf[0].take(e01) + Vf[1].take(v012) + ESf[1].take(e12), inf)
    pad = np.full((N, 1), inf)
    back: list[NDArray] = []
    rows = np.arange(S)[None, :]
    for m, (vidx, eidx) in zip(range(2, M - 1), steps, strict=True):
        Tp = np.concatenate([T, pad], axis=1)
        cand = Tp[:, pred] + Vf[m].take(vidx)
        arg = np.argmin(cand, axis=2)
        T = np.take_along_axis(cand, arg[..., None], axis=2)[..., 0] + ESf[m].take(eidx)
        back.append(pred[rows, arg])
    vl, el, v0 = close
    final = T + Vf[M - 1].take(vl) + ESf[M - 1].take(el) + Vf[0].take(v0)
    flat = int(np.argmin(final))
    best = float(final.flat[flat])
    if not np.isfinite(best):
        raise ModelError("no valid mapping of the contour to the model")
    a0, s0 = divmod(flat, S)
    slacks = [0] * M
    st = s0
    slacks[M - 1], slacks[M - 2] = int(states[st, 2]), int(states[st, 1])
    for lvl in range(len(back) - 1, -1, -1):
        st = int(back[lvl][a0, st])
        slacks[lvl + 1] = int(states[st, 1])
    slacks[1] = int(states[st, 0])
    mapping = tuple(int((a0 + m + slacks[m]) % N) for m in range(M))
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
    landmarks = {name: (float(pts[i, 0]), float(pts[i, 1]))
                 for name, i in zip(model.names, mapping, strict=True)}
    return MatchResult(cost, mapping, pts, landmarks)
