"""Label placement: inside the image always; off each other whenever there is room."""

from __future__ import annotations

import itertools

from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.common.labels import Box, place_labels

WIDTH, HEIGHT = 640, 480


@st.composite
def labels(draw, max_w: int, max_h: int, most: int):
    """Labels of at most max_w x max_h px at anchors anywhere in the image, or somewhat outside it."""
    n = draw(st.integers(1, most))
    anchors = [(draw(st.floats(-50, WIDTH + 50)), draw(st.floats(-50, HEIGHT + 50))) for _ in range(n)]
    sizes = [(draw(st.integers(1, max_w)), draw(st.integers(1, max_h))) for _ in range(n)]
    return anchors, sizes


def overlaps(boxes: list[Box]) -> list[tuple[Box, Box]]:
    """Pairs that share area, computed independently of Box.overlap."""
    return [(a, b) for a, b in itertools.combinations(boxes, 2)
            if a.x < b.x + b.w and b.x < a.x + a.w and a.y < b.y + b.h and b.y < a.y + a.h]


# Room: every label at most W/8 x H/16 and at most 10 of them. The top-left corners a box may not take
# (next to the others) cover at most 9 * (W/4 * H/8) = 28 % of the image, those that keep it inside at
# least 7/8 * 15/16 = 82 %: a free spot always exists.
@settings(max_examples=300, deadline=None)
@given(labels(WIDTH // 8, HEIGHT // 16, 10), st.integers(0, 12))
def test_labels_with_room_are_inside_and_pairwise_disjoint(case, gap) -> None:
    anchors, sizes = case
    boxes = place_labels(anchors, sizes, (WIDTH, HEIGHT), gap=gap)
    assert [(b.w, b.h) for b in boxes] == sizes
    assert all(b.x >= 0 and b.y >= 0 and b.x + b.w <= WIDTH and b.y + b.h <= HEIGHT for b in boxes)
    assert overlaps(boxes) == []


@settings(max_examples=100, deadline=None)
@given(labels(WIDTH // 2, HEIGHT // 2, 30))
def test_crowded_labels_still_stay_inside(case) -> None:
    anchors, sizes = case
    boxes = place_labels(anchors, sizes, (WIDTH, HEIGHT))
    assert all(b.x >= 0 and b.y >= 0 and b.x + b.w <= WIDTH and b.y + b.h <= HEIGHT for b in boxes)


def test_a_label_goes_right_above_its_point_when_free_and_keeps_off_obstacles() -> None:
    assert place_labels([(100, 100)], [(40, 10)], (WIDTH, HEIGHT), gap=5) == [Box(105, 85, 40, 10)]
    # at the right edge it flips to the left of its point; in the top corner below it
    assert place_labels([(630, 100)], [(40, 10)], (WIDTH, HEIGHT), gap=5) == [Box(585, 85, 40, 10)]
    assert place_labels([(5, 2)], [(40, 10)], (WIDTH, HEIGHT), gap=5) == [Box(10, 7, 40, 10)]
    # two points side by side: the second label does not cover the first
    a, b = place_labels([(100, 100), (110, 100)], [(40, 10), (40, 10)], (WIDTH, HEIGHT), gap=5)
    assert a == Box(105, 85, 40, 10) and not overlaps([a, b])
    banner = Box(0, 0, WIDTH, 60)
    (c,) = place_labels([(100, 50)], [(40, 10)], (WIDTH, HEIGHT), gap=5, obstacles=[banner])
    assert not overlaps([banner, c]) and c.inside(WIDTH, HEIGHT)


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 60), st.integers(1, 30), st.data())
def test_the_one_free_spot_left_is_found(w, h, data) -> None:
    """Obstacles cover the image but for one hole of the label's size: the label goes into the hole."""
    hx, hy = data.draw(st.integers(0, WIDTH - w)), data.draw(st.integers(0, HEIGHT - h))
    around = [Box(0, 0, hx, HEIGHT), Box(hx + w, 0, WIDTH - hx - w, HEIGHT), Box(hx, 0, w, hy),
              Box(hx, hy + h, w, HEIGHT - hy - h)]
    anchor = (data.draw(st.floats(0, WIDTH)), data.draw(st.floats(0, HEIGHT)))
    assert place_labels([anchor], [(w, h)], (WIDTH, HEIGHT), obstacles=around) == [Box(hx, hy, w, h)]
