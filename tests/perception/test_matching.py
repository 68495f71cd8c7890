"""Matching DP (Alg. 1, Eq. 3-7): exact global optimum, back-tracking, invariance."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cell.perception.geometry import (
    inner_angle,
    inner_angles_of_triples,
    make_clockwise,
    polygon_angles,
)
from cell.perception.matching import (
    CostTables,
    MatchWeights,
    cost_tables,
    mapping_cost,
    match,
    match_tables,
)
from cell.perception.models import PolygonalModel, learn_model
from drivers.common.garments import CATEGORIES, LANDMARKS
from drivers.common.plane import signed_area
from tests.perception.brute_force import brute_force
from tests.perception.scenes import landmark_polygons, landmarks_and_neckline, random_garment


def _random_model(rng: np.random.Generator, m: int) -> PolygonalModel:
    return PolygonalModel("x", tuple(f"v{i}" for i in range(m)), tuple(rng.uniform(0.5, 5.5, m)),
                          tuple(rng.uniform(0.05, 1.0, m)), tuple(rng.uniform(0.05, 0.5, m)),
                          tuple(rng.uniform(0.001, 0.05, m)), tuple(range(m)), tuple(range(m)), 20)


def test_inner_angles_of_clockwise_rectangle_and_notch() -> None:
    rect = np.array([[0, 0], [4, 0], [4, 2], [0, 2]], float)   # clockwise on screen (y down)
    assert signed_area(rect) > 0
    assert np.allclose(polygon_angles(rect), np.pi / 2)
    notch = np.array([[0, 0], [4, 0], [4, 4], [2, 2], [0, 4]], float)
    ang = polygon_angles(notch)
    assert ang[3] > np.pi and math.isclose(ang.sum(), 3 * np.pi)  # pentagon: (5-2) pi
    ccw, rev = make_clockwise(rect[::-1])
    assert rev and np.allclose(ccw, rect)
    assert math.isclose(float(inner_angle(rect[3], rect[0], rect[1])), np.pi / 2)


def test_angles_of_all_triples_equal_inner_angle_of_each() -> None:
    p = np.random.default_rng(2).uniform(0, 50, (9, 2))
    table = inner_angles_of_triples(p)
    for i, j, k in np.ndindex(9, 9, 9):
        assert table[i, j, k] == pytest.approx(float(inner_angle(p[i], p[j], p[k])), abs=1e-12)


@pytest.mark.parametrize("seed", range(6))
def test_dp_equals_enumeration_of_every_mapping(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(25):
        m = int(rng.integers(3, 6))
        n = int(rng.integers(m, 10))
        pts = rng.uniform(0, 100, (n, 2))
        tables = cost_tables(pts, _random_model(rng, m), MatchWeights())
        cost, mapping = match_tables(tables)
        best, _ = brute_force(tables)
        assert cost == pytest.approx(best, rel=1e-9, abs=1e-9)
        assert mapping_cost(tables, mapping) == pytest.approx(cost, rel=1e-9, abs=1e-9)
        # the mapping is valid: distinct points in cyclic order
        assert len(set(mapping)) == m
        steps = [(mapping[(k + 1) % m] - mapping[k]) % n for k in range(m)]
        assert sum(steps) == n and all(s > 0 for s in steps)


@pytest.mark.parametrize(("m", "n"), [(3, 3), (3, 8), (6, 6), (7, 11), (8, 12)])
def test_dp_equals_enumeration_for_long_models_and_tied_costs(m: int, n: int) -> None:
    """Many DP steps (up to M = 8), no slack (N = M), and integer costs full of exact ties: the
    optimum equals enumeration's and the back-tracked mapping costs exactly that."""
    rng = np.random.default_rng(100 * m + n)
    for _ in range(3):
        for tables in (cost_tables(rng.uniform(0, 100, (n, 2)), _random_model(rng, m), MatchWeights()),
                       CostTables(rng.integers(0, 3, (m, n, n, n)).astype(float),
                                  rng.integers(0, 3, (m, n, n)).astype(float))):
            cost, mapping = match_tables(tables)
            assert cost == pytest.approx(brute_force(tables)[0], rel=1e-9, abs=1e-9)
            assert mapping_cost(tables, mapping) == pytest.approx(cost, rel=1e-9, abs=1e-9)
            steps = [(mapping[(k + 1) % m] - mapping[k]) % n for k in range(m)]
            assert sum(steps) == n and all(s > 0 for s in steps)


def test_number_of_enumerated_mappings_is_eq3() -> None:
    # brute_force enumerates N * C(N-1, M-1) mappings; count them the same way
    n, m = 7, 4
    count = sum(math.comb(n - 1, m - 1) for _ in range(n))
    assert count == n * math.comb(n - 1, m - 1) == 140


def test_too_few_points_is_an_error() -> None:
    from cell.perception.errors import ModelError
    rng = np.random.default_rng(0)
    with pytest.raises(ModelError, match="fewer than"):
        match(rng.uniform(0, 10, (3, 2)), _random_model(rng, 4))


@pytest.fixture(scope="module")
def models() -> dict[str, PolygonalModel]:
    rng = np.random.default_rng(11)
    floors = {"angle": 0.0076, "length": 2e-5}
    return {c: learn_model(c, landmark_polygons(c, 60, rng), LANDMARKS[c], 12, floors) for c in CATEGORIES}


@pytest.mark.parametrize("category", CATEGORIES)
def test_matching_recovers_landmarks_and_is_similarity_invariant(models, category: str) -> None:
    """A polygon of the sim's garment border (its landmarks and, for shirts, the neckline) is matched
    with every landmark exactly on its true point (a towel's up to its turns)."""
    rng = np.random.default_rng(3)
    ok = 0
    trials = 12
    for _ in range(trials):
        g = random_garment(category, rng)
        outline = landmarks_and_neckline(g)
        res = match(outline, models[category])
        found = np.array([res.landmarks[n] for n in g.names])
        # a towel at any rotation has no up: any quarter turn of its corner names is as right
        turns = range(len(g.names)) if category == "towel" else (0,)
        err = min(np.abs(found - np.roll(g.landmarks, k, axis=0)).max() for k in turns)
        ok += err < 1e-6
        # rotate (small: the upright convention must still hold), scale, translate
        th = rng.uniform(-0.2, 0.2)
        rot = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
        s, t = rng.uniform(0.5, 2.0), rng.uniform(-300, 300, 2)
        moved = outline @ rot.T * s + t
        res2 = match(np.roll(moved, int(rng.integers(len(moved))), axis=0), models[category])
        expect = np.array([res.landmarks[n] for n in g.names]) @ rot.T * s + t
        moved_found = np.array([res2.landmarks[n] for n in g.names])
        # a towel's corner names may turn with it (its turns match alike)
        assert min(np.abs(moved_found - np.roll(expect, k, axis=0)).max() for k in turns) < 1e-6
        assert res2.cost == pytest.approx(res.cost, rel=1e-9, abs=1e-9)
    assert ok >= trials - 1


def test_category_is_found_by_lowest_cost(models) -> None:
    rng = np.random.default_rng(5)
    right = 0
    total = 0
    for c in models:
        for _ in range(5):
            outline = landmarks_and_neckline(random_garment(c, rng))
            costs = {k: match(outline, m).cost for k, m in models.items() if len(outline) >= m.size}
            right += min(costs, key=costs.get) == c
            total += 1
    assert right >= total - 1


@pytest.mark.parametrize("seed", range(3))
def test_dp_with_expected_positions_equals_enumeration(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    for _ in range(20):
        m = int(rng.integers(3, 6))
        n = int(rng.integers(m, 10))
        pts = rng.uniform(0, 100, (n, 2))
        expected = rng.uniform(0, 100, (m, 2))
        tables = cost_tables(pts, _random_model(rng, m), MatchWeights(), expected)
        cost, mapping = match_tables(tables)
        assert cost == pytest.approx(brute_force(tables)[0], rel=1e-9, abs=1e-9)
        assert mapping_cost(tables, mapping) == pytest.approx(cost, rel=1e-9, abs=1e-9)


def test_expected_positions_name_a_symmetric_outline() -> None:
    # a square: its shape alone cannot tell which corner is which; where they should be can
    square = np.array([[0, 0], [100, 0], [100, 100], [0, 100]], float)
    model = PolygonalModel("x", ("a", "b", "c", "d"), (np.pi / 2,) * 4, (0.05,) * 4, (0.25,) * 4,
                           (0.001,) * 4, (0, 0, 0, 0), (0, 0, 0, 0), 4)
    for shift in range(4):
        expected = np.roll(square, -shift, axis=0) + np.array([6.0, -4.0])
        res = match(square, model, MatchWeights(), expected)
        assert [res.landmarks[n] for n in "abcd"] == [tuple(p) for p in np.roll(square, -shift, axis=0)]


def test_expected_positions_of_the_wrong_shape_are_an_error() -> None:
    from cell.perception.errors import ModelError
    rng = np.random.default_rng(5)
    with pytest.raises(ModelError, match="expected positions"):
        match(rng.uniform(0, 10, (6, 2)), _random_model(rng, 4), MatchWeights(), np.zeros((3, 2)))
