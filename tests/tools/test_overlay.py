"""`perceive --overlay`'s drawing: the title in a band above the image, every label once on its own
box, outward off the garment, the image's other pixels as they were."""

from __future__ import annotations

from types import SimpleNamespace

import cv2
import numpy as np

from tools.overlay import LABEL_STYLE, draw_overlay

WIDTH, HEIGHT = 800, 600
CORNERS = {"bottom-left": (470.0, 380.0), "bottom-right": (330.0, 380.0), "right-armpit": (330.0, 270.0),
           "right-sleeve": (280.0, 250.0), "right-shoulder": (340.0, 210.0), "left-shoulder": (460.0, 210.0),
           "left-sleeve": (520.0, 250.0), "left-armpit": (470.0, 270.0)}


def _observation() -> SimpleNamespace:
    polygon = np.array(list(CORNERS.values()))
    # the contour: the polygon's border pixel by pixel
    contour = np.vstack([np.linspace(polygon[i], polygon[(i + 1) % len(polygon)], 60, endpoint=False)
                         for i in range(len(polygon))]).round().astype(np.int32)
    return SimpleNamespace(category="short-sleeve", cost=-3.2, contour=contour, polygon=polygon,
                           landmarks=dict(CORNERS))


def _ink(patch: np.ndarray) -> tuple[int, int]:
    """(connected blobs, width) of the dark ink on a light patch."""
    ink = (patch.max(axis=2) < 128).astype(np.uint8)
    cols = np.flatnonzero(ink.any(axis=0))
    return cv2.connectedComponents(ink, connectivity=8)[0] - 1, int(cols[-1] - cols[0] + 1)


def _within(inner: tuple[int, ...], outer: tuple[int, ...]) -> bool:
    (x, y, w, h), (ox, oy, ow, oh) = inner, outer
    return ox <= x and oy <= y and x + w <= ox + ow and y + h <= oy + oh


def test_overlay_adds_a_title_band_and_labels_each_name_once_off_the_garment() -> None:
    image = np.random.default_rng(4).integers(20, 200, (HEIGHT, WIDTH, 3)).astype(np.uint8)  # no white
    observation = _observation()
    drawn = draw_overlay(image, observation)
    band = drawn.shape[0] - HEIGHT
    assert band > 0 and drawn.shape[1:] == (WIDTH, 3)
    below = drawn[band:]
    # the labels: boxes of the backing white (which the noise never is), one per landmark
    white = np.all(below == 255, axis=2).astype(np.uint8)
    count, _labels, stats, _centroids = cv2.connectedComponentsWithStats(white, connectivity=8)
    regions = [tuple(int(v) for v in stats[i, :4]) for i in range(1, count)]
    # (a white region inside another is a glyph's hole, not a box)
    boxes = [r for r in regions if not any(_within(r, other) for other in regions if other != r)]
    assert len(boxes) == len(CORNERS)
    garment = np.zeros((HEIGHT, WIDTH), np.uint8)
    cv2.fillPoly(garment, [observation.contour.reshape(-1, 1, 2)], 1)
    names = [f"{number} {name}" for number, name in enumerate(CORNERS, start=1)]
    expected = {}
    for name in names:
        single = np.full((40, 300, 3), 255, np.uint8)
        cv2.putText(single, name, (5, 25), cv2.FONT_HERSHEY_SIMPLEX, LABEL_STYLE.scale, (0, 0, 0),
                    LABEL_STYLE.thickness, cv2.LINE_AA)
        expected[_ink(single)] = name
    seen = []
    for x, y, w, h in boxes:
        assert not garment[y - 1:y + h + 1, x - 1:x + w + 1].any()      # room all round: off the garment
        seen.append(expected.get(_ink(below[y:y + h, x:x + w])))          # one stroke of one name
    assert sorted(map(str, seen)) == sorted(names)
    # every other pixel of the image is the input's but for the outline, polygon, markers and arrow
    allowed = np.zeros((HEIGHT, WIDTH), np.uint8)
    cv2.polylines(allowed, [observation.contour.reshape(-1, 1, 2)], True, 1, 6)
    for x, y in CORNERS.values():
        cv2.circle(allowed, (round(x), round(y)), 11, 1, -1)
    first, second = np.array(list(CORNERS.values())[:2])
    cv2.line(allowed, tuple(first.astype(int)), tuple((first + 0.35 * (second - first)).astype(int)), 1, 25)
    for (x, y, w, h), name in zip(boxes, seen, strict=True):
        allowed[y - 1:y + h + 1, x - 1:x + w + 1] = 1     # the box and its one-pixel border
        ax, ay = CORNERS[name.split(" ", 1)[1]]            # and a leader line from its point
        near = (min(max(round(ax), x), x + w), min(max(round(ay), y), y + h))
        cv2.line(allowed, (round(ax), round(ay)), near, 1, 3)
    changed = np.any(below != image, axis=2)
    assert not (changed & (allowed == 0)).any()
