"""Optimal polygon simplification (Perez-Vidal ISE): exact open and cyclic DPs vs brute force."""

from __future__ import annotations

import numpy as np
import pytest

from cell.perception.errors import PerceptionError
from cell.perception.simplify import (
    candidates,
    edge_costs,
    simplify_closed,
    simplify_closed_costs,
    simplify_open,
)
from tests.perception.brute_force import brute_force_closed, brute_force_open


def _direct_ise(points: np.ndarray, a: int, b: int) -> float:
    n = len(points)
    A, B = points[a], points[b]
    d = B - A
    nrm = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    span = (b - a) % n
    return float(sum(((points[(a + t) % n] - A) @ nrm) ** 2 for t in range(span + 1)))


def test_edge_costs_equal_direct_sums_including_wraparound() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 50, (15, 2))
    cand = np.array([0, 3, 7, 12])
    C = edge_costs(pts, cand)
    for i in range(4):
        for j in range(4):
            if i != j:
                assert C[i, j] == pytest.approx(_direct_ise(pts, cand[i], cand[j]), rel=1e-7, abs=1e-7)


@pytest.mark.parametrize("seed", range(5))
def test_open_and_cyclic_dp_equal_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(20):
        L = int(rng.integers(4, 10))
        P = int(rng.integers(L, 25))
        pts = rng.uniform(0, 50, (P, 2))
        cand = np.sort(rng.choice(P, L, replace=False))
        C = edge_costs(pts, cand)
        k = int(rng.integers(3, L + 1))
        cost, verts = simplify_closed_costs(C, k)
        assert cost == pytest.approx(brute_force_closed(C, k), rel=1e-9, abs=1e-9)
        assert len(set(verts)) == k
        assert cost == pytest.approx(sum(C[verts[t], verts[(t + 1) % k]] for t in range(k)), abs=1e-9)
        ocost, overts = simplify_open(C, k)
        assert ocost == pytest.approx(brute_force_open(C, k), rel=1e-9, abs=1e-9)
        assert overts[0] == 0 and overts[-1] == L - 1 and len(overts) == k


@pytest.mark.parametrize("seed", range(3))
def test_cyclic_dp_with_tied_costs_returns_a_polygon_of_the_optimal_cost(seed: int) -> None:
    """Integer edge costs full of exact ties, up to k = L (no slack): the back-tracked polygon has
    k distinct vertices and costs exactly the brute-force optimum."""
    rng = np.random.default_rng(50 + seed)
    for _ in range(20):
        L = int(rng.integers(3, 11))
        k = int(rng.integers(3, L + 1))
        C = rng.integers(0, 4, (L, L)).astype(float)
        cost, verts = simplify_closed_costs(C, k)
        assert cost == brute_force_closed(C, k)
        assert len(set(verts)) == k and verts == sorted(verts)
        assert sum(C[verts[t], verts[(t + 1) % k]] for t in range(k)) == cost


def test_polygon_contour_is_recovered_exactly() -> None:
    # a densely sampled hexagon: 6 vertices give zero error and the corners themselves
    corners = np.array([[0, 0], [40, -10], [80, 0], [90, 40], [40, 70], [-10, 40]], float)
    dense = np.concatenate([np.linspace(corners[i], corners[(i + 1) % 6], 12, endpoint=False)
                            for i in range(6)])
    cand = candidates(dense, 0.5, 40)
    poly, cost = simplify_closed(dense, 6, cand)
    assert cost == pytest.approx(0.0, abs=1e-6)
    assert {tuple(p) for p in poly} == {tuple(c) for c in corners}


def test_too_few_candidates_is_an_error() -> None:
    with pytest.raises(PerceptionError, match="fewer than"):
        simplify_closed(np.random.default_rng(0).uniform(0, 9, (10, 2)), 5, np.array([0, 3, 6]))


def test_points_near_expected_landmarks_become_vertices() -> None:
    from cell.perception.simplify import with_points_near
    side = np.arange(100)
    contour = np.vstack([np.column_stack([side, 0 * side]), np.column_stack([0 * side + 100, side]),
                         np.column_stack([100 - side, 0 * side + 100]),
                         np.column_stack([0 * side, 100 - side])])
    corners = np.array([[0, 0], [100, 0], [100, 100], [0, 100]], float)
    # a landmark expected mid-edge gets the nearest contour point, in contour order
    out = with_points_near(corners, contour, np.array([[103.0, 52.0]]), 5.0)
    assert out.tolist() == [[0, 0], [100, 0], [100, 52], [100, 100], [0, 100]]
    # one expected near a corner adds nothing
    assert with_points_near(corners, contour, np.array([[98.0, 3.0]]), 5.0).tolist() == corners.tolist()
