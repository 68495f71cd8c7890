"""Labels: inside the image always; off each other, and outward off the garment, whenever there is
room; each text drawn once."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from drivers.common.labels import Box, LabelStyle, draw_labels, place_labels

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


def _ink_blobs(patch: np.ndarray) -> tuple[int, int, int]:
    """Dark ink of a light patch: (connected blobs, leftmost column, rightmost column)."""
    ink = (patch.max(axis=2) < 128).astype(np.uint8)
    cols = np.flatnonzero(ink.any(axis=0))
    return cv2.connectedComponents(ink, connectivity=8)[0] - 1, int(cols[0]), int(cols[-1])


@pytest.mark.parametrize("thickness", [1, 2])
def test_a_label_is_its_text_drawn_once_on_a_backing_box(thickness: int) -> None:
    """The label's box holds exactly one cv2.putText of its text on the backing colour, inside its
    border: no second stroke in another face (OpenCV 5 draws thicker strokes with a wider font)."""
    style = LabelStyle(scale=0.55, thickness=thickness)
    text = "5 right-sleeve-outer"
    image = np.full((200, 400, 3), 90, np.uint8)
    (box,) = draw_labels(image, [text], [(100.0, 100.0)], style, [(240, 80, 240)], gap=10)
    inner = image[box.y + 1:box.y + box.h - 1, box.x + 1:box.x + box.w - 1]
    (w, h), _baseline = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 0.55, thickness)
    once = np.full((box.h, box.w, 3), 255, np.uint8)
    cv2.putText(once, text, (style.padding, style.padding + h), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0),
                thickness, cv2.LINE_AA)
    assert np.array_equal(inner, once[1:-1, 1:-1])
    # and that one stroke is as wide as the text's measure, in as many glyph blobs as the text has
    blobs, left, right = _ink_blobs(inner)
    assert right - left + 1 <= w and blobs == _ink_blobs(once)[0]
    # the border is the accent colour, the image outside the box untouched
    assert np.all(image[box.y, box.x:box.x + box.w] == (240, 80, 240))
    outside = np.ones(image.shape[:2], bool)
    outside[box.y:box.y + box.h, box.x:box.x + box.w] = False
    assert np.all(image[outside] == 90)


def test_labels_go_outward_from_the_garment_when_there_is_room() -> None:
    """Points all round a disc, labels placed away from its centre: every label lies beyond its point
    as seen from the centre, off the disc (counted here pixel by pixel), off the others, inside."""
    centre, radius = np.array([320.0, 240.0]), 120.0
    yy, xx = np.mgrid[:HEIGHT, :WIDTH]
    disc = (xx - centre[0]) ** 2 + (yy - centre[1]) ** 2 <= radius ** 2
    angles = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    anchors = [tuple(centre + radius * np.array([np.cos(a), np.sin(a)])) for a in angles]
    boxes = place_labels(anchors, [(70, 14)] * len(anchors), (WIDTH, HEIGHT), gap=6, away_from=tuple(centre))
    assert overlaps(boxes) == []
    for (ax, ay), b in zip(anchors, boxes, strict=True):
        assert b.inside(WIDTH, HEIGHT)
        assert not disc[b.y:b.y + b.h, b.x:b.x + b.w].any()
        outward = np.array([b.x + b.w / 2 - ax, b.y + b.h / 2 - ay]) @ (np.array([ax, ay]) - centre)
        assert outward > 0


def test_a_label_turns_off_the_outward_ray_to_keep_off_the_garment() -> None:
    """A sleeve lies straight outward of a point: its label goes beside the ray, off the garment's
    pixels, still outward and near its point."""
    garment = np.zeros((HEIGHT, WIDTH), bool)
    garment[200:280, 100:300] = True            # the body; the point is its right side's middle
    garment[150:245, 320:480] = True            # a sleeve beyond it, reaching down past its level
    (box,) = place_labels([(300.0, 240.0)], [(80, 16)], (WIDTH, HEIGHT), gap=6, away_from=(200.0, 240.0),
                          keep_off=garment)
    assert not garment[box.y:box.y + box.h, box.x:box.x + box.w].any()
    assert box.x + box.w / 2 > 300 and box.x < 300 + 6 + 2 * 16 + 80
