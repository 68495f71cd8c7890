"""Layered folding physics and the folded-landmark convention."""

import numpy as np
import pytest

from drivers.common.plane import FoldLine, signed_area
from drivers.sim.folding import (
    Layer,
    area_of_union,
    crumpled_fold_layers,
    fold_landmarks,
    fold_layers,
    iou,
    lines_agree,
)
from drivers.sim.geometry import clip_halfplane

RES = 0.001


def rect(w=0.6, h=0.4, cx=0.4, cy=0.6):
    return np.array([[cx - w / 2, cy - h / 2], [cx + w / 2, cy - h / 2], [cx + w / 2, cy + h / 2],
                     [cx - w / 2, cy + h / 2]])


def test_fold_line_from_move_is_perpendicular_bisector():
    line = FoldLine.from_move(np.array([0.0, 0.0]), np.array([0.2, 0.0]))
    assert np.allclose(line.point, [0.1, 0.0])
    assert line.side(np.array([[0.0, 0.0]]))[0] > 0    # the grasp's side moves
    assert np.allclose(line.reflect(np.array([[0.0, 0.0]])), [[0.2, 0.0]])


@pytest.mark.parametrize("seed", range(20))
def test_fold_then_unfold_restores_the_silhouette(seed):
    rng = np.random.default_rng(seed)
    # a random star-shaped (non-convex) polygon
    ang = np.sort(rng.uniform(0, 2 * np.pi, 12))
    r = rng.uniform(0.1, 0.25, 12)
    poly = np.column_stack([0.4 + r * np.cos(ang), 0.6 + r * np.sin(ang)])
    g = poly[rng.integers(12)]
    p = np.array([0.4, 0.6]) + rng.uniform(-0.05, 0.05, 2)
    line = FoldLine.from_move(g, p)
    folded = fold_layers([Layer(poly)], line)
    assert len(folded) >= 2 and folded[-1].flipped
    assert iou([la.polygon for la in folded], [poly], RES) < 0.999   # it did change
    n_moved = sum(la.flipped for la in folded)
    back_line = FoldLine(line.point, -line.normal)
    unfolded = fold_layers(folded, back_line, select=range(len(folded) - n_moved, len(folded)))
    assert iou([la.polygon for la in unfolded], [poly], RES) > 0.995
    assert abs(sum(abs(signed_area(la.polygon)) for la in unfolded) - abs(signed_area(poly))) < 1e-9


def test_folding_a_towel_in_half_halves_its_area():
    poly = rect()
    g, p = poly[0], poly[3]     # bottom-left onto top-left
    folded = fold_layers([Layer(poly)], FoldLine.from_move(g, p))
    assert len(folded) == 2
    assert area_of_union([la.polygon for la in folded], RES) == pytest.approx(0.12, rel=0.01)
    # layer areas are conserved (cloth neither grows nor shrinks)
    assert sum(abs(signed_area(la.polygon)) for la in folded) == pytest.approx(0.24)


def test_moved_stack_is_turned_over():
    poly = rect()
    line = FoldLine.from_move(poly[0], poly[3])
    two = fold_layers([Layer(poly)], line)
    line2 = FoldLine(np.array([0.4, 0.6]), np.array([-1.0, 0.0]))    # then the x < 0.4 half over
    four = fold_layers(two, line2)
    assert len(four) == 4
    # the top layer before this fold comes to lie lowest of the moved ones
    assert [la.flipped for la in four] == [False, True, False, True]


def test_clip_halfplane_of_a_concave_polygon_keeps_area():
    u = np.array([[0, 0], [3, 0], [3, 3], [2, 3], [2, 1], [1, 1], [1, 3], [0, 3]], float)
    line = FoldLine(np.array([0.0, 2.0]), np.array([0.0, 1.0]))
    a = abs(signed_area(clip_halfplane(u, line, True)))
    b = abs(signed_area(clip_halfplane(u, line, False)))
    assert a == pytest.approx(2.0) and b == pytest.approx(5.0)


def test_lines_agree_within_tolerance():
    a = FoldLine.from_move(np.array([0.0, 0.0]), np.array([0.2, 0.0]))
    b = FoldLine.from_move(np.array([0.0, 0.3]), np.array([0.2, 0.31]))
    c = FoldLine.from_move(np.array([0.0, 0.3]), np.array([0.3, 0.3]))
    assert lines_agree([a, b], 0.15, 0.03)
    assert not lines_agree([a, c], 0.15, 0.03)


def test_disagreeing_grippers_crumple():
    poly = rect()
    moves = [(poly[0], poly[3]), (poly[1], poly[2] + [0.0, 0.15])]
    ideal = fold_layers([Layer(poly)], FoldLine.from_move(poly[0], poly[3]))
    bad = crumpled_fold_layers([Layer(poly)], moves, 0.25, 0.01, np.random.default_rng(0))
    assert iou([la.polygon for la in bad], [la.polygon for la in ideal], RES) < 0.95


def test_fold_landmarks_of_a_towel_in_half():
    names = ["bottom-left", "bottom-right", "top-right", "top-left"]
    poly = rect()    # counter-clockwise seen from above, as towels are listed
    line = FoldLine.from_move(poly[0], poly[3])
    n, p = fold_landmarks(names, poly, line, 1, merge_distance=0.01)
    assert sorted(n) == ["fold1-from", "fold1-to", "top-left", "top-right"]
    d = dict(zip(n, p, strict=True))
    # the fold line y = 0.6 cuts the left and right edges
    assert np.allclose(sorted([d["fold1-from"][0], d["fold1-to"][0]]), [0.1, 0.7])
    assert np.allclose([d["fold1-from"][1], d["fold1-to"][1]], 0.6)
    assert np.allclose(sorted(tuple(d[k]) for k in ("top-left", "top-right")), [[0.1, 0.8], [0.7, 0.8]])
    assert signed_area(p) > 0        # the towel's orientation is kept
    # clockwise walk: F (entering the moving part) comes right after the stationary run, then T
    cw = n[::-1]
    i = cw.index("fold1-from")
    assert cw[(i + 1) % 4] == "fold1-to"


def test_fold_landmarks_merge_close_vertices():
    names = ["a", "e", "b", "c", "d"]
    # clockwise seen from above; e sits 5 mm beside where the fold line crosses the top edge
    poly = np.array([[0.1, 0.8], [0.405, 0.8], [0.7, 0.8], [0.7, 0.4], [0.1, 0.4]])
    line = FoldLine(np.array([0.4, 0.6]), np.array([-1.0, 0.0]))     # the x < 0.4 part moves
    n, p = fold_landmarks(names, poly, line, 2, merge_distance=0.01)
    assert n == ["b", "c", "fold2-from", "fold2-to"]
    assert np.allclose(p, [[0.7, 0.8], [0.7, 0.4], [0.4, 0.4], [0.4, 0.8]])
    n, _ = fold_landmarks(names, poly, line, 2, merge_distance=0.001)
    assert n == ["e", "b", "c", "fold2-from", "fold2-to"]
