"""Exhaustive references for the dynamic programs of perception (small instances only)."""

from __future__ import annotations

import itertools

import numpy as np
from numpy.typing import NDArray

from cell.perception.matching import CostTables, mapping_cost


def brute_force_closed(costs: NDArray, k: int) -> float:
    L = costs.shape[0]
    best = np.inf
    for combo in itertools.combinations(range(L), k):
        c = sum(costs[combo[t], combo[(t + 1) % k]] for t in range(k))
        best = min(best, c)
    return float(best)


def brute_force_open(costs: NDArray, k: int) -> float:
    L = costs.shape[0]
    best = np.inf
    for mid in itertools.combinations(range(1, L - 1), k - 2):
        combo = (0, *mid, L - 1)
        best = min(best, sum(costs[combo[t], combo[t + 1]] for t in range(k - 1)))
    return float(best)


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
