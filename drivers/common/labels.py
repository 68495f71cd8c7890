"""Text labels on an image: where (near their point, inside the image, off each other and, room
allowing, off the garment) and how (each once, on a backing box readable on any colour).

Each label goes at the first free spot among: with a centre given, spots on rays from its point
away from that centre (the garment's centroid), nearest first; then a few spots around its point
(right-above, right-below, left-above, left-below) that lie inside the image, then those pushed
inside. With a mask to keep off, the free spot covering the fewest of its pixels wins (the first such
in that order). When no spot is free, the free spot nearest the preferred one: the search for it is
complete, as a free box can slide left and up until it meets the image's edge or another box, so
trying the positions 0 and the right and bottom edges of the boxes placed finds one whenever one
exists. Only when none does (no room) does a label overlap the least.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

# the outward spots: distances from the point in label heights beyond the gap, and turns off the
# outward ray (degrees), tried nearest first and straightest first
OUTWARD_STEPS = 6
OUTWARD_TURNS_DEG = (0, 20, -20, 40, -40, 60, -60, 90, -90)
LEADER_MIN_PX = 4           # a label farther than the gap plus this from its point gets a leader line


@dataclass(frozen=True)
class Box:
    x: int
    y: int
    w: int
    h: int

    def overlap(self, other: Box) -> int:
        """The area two boxes share (0 when they only touch)."""
        dx = min(self.x + self.w, other.x + other.w) - max(self.x, other.x)
        dy = min(self.y + self.h, other.y + other.h) - max(self.y, other.y)
        return max(0, dx) * max(0, dy)

    def inside(self, width: int, height: int) -> bool:
        return self.x >= 0 and self.y >= 0 and self.x + self.w <= width and self.y + self.h <= height


def place_labels(anchors: Sequence[tuple[float, float]], sizes: Sequence[tuple[int, int]],
                 image_size: tuple[int, int], *, gap: int = 0, obstacles: Sequence[Box] = (),
                 away_from: tuple[float, float] | None = None, keep_off: NDArray | None = None) -> list[Box]:
    """A box (top-left x, y, width, height) per label of `sizes` (w, h) for its anchor point (x, y),
    in an image of `image_size` (width, height); `gap` px between a label and its point. Boxes stay
    inside the image (a label larger than the image starts at its top-left corner) and, room allowing,
    off each other and off `obstacles`; with `away_from` (x, y) they go outward from it, and with
    `keep_off` (a boolean mask of the image) off its pixels where a free spot allows."""
    width, height = image_size
    covered = _coverage(keep_off) if keep_off is not None else None
    placed: list[Box] = list(obstacles)
    out: list[Box] = []
    for (ax, ay), (w, h) in zip(anchors, sizes, strict=True):
        w, h = int(w), int(h)
        max_x, max_y = max(0, width - w), max(0, height - h)
        preferred = [(ax + gap, ay - gap - h), (ax + gap, ay + gap), (ax - gap - w, ay - gap - h),
                     (ax - gap - w, ay + gap)]
        if away_from is not None:
            preferred = _outward(ax - away_from[0], ay - away_from[1], ax, ay, w, h, gap) + preferred
        # the spots that fit as they are first, then each pushed inside
        fitting = [Box(round(x), round(y), w, h) for x, y in preferred if 0 <= x <= max_x and 0 <= y <= max_y]
        spots = fitting + [Box(_clamp(x, max_x), _clamp(y, max_y), w, h) for x, y in preferred[-4:]]
        free = [b for b in spots if not any(b.overlap(p) for p in placed)]
        if not free:
            box = _nearest_free(spots[0], placed, max_x, max_y)
        elif covered is None:
            box = free[0]
        else:
            box = min(free, key=lambda b: _pixels_in(covered, b))
        placed.append(box)
        out.append(box)
    return out


def _outward(dx: float, dy: float, ax: float, ay: float, w: int, h: int,
             gap: int) -> list[tuple[float, float]]:
    """Top-left corners of a w x h box beyond the point (ax, ay) on rays turned a little off the
    direction (dx, dy), the box's near side `gap` + steps of h from the point."""
    base = math.atan2(dy, dx) if (dx, dy) != (0, 0) else -math.pi / 2
    corners = []
    for step in range(OUTWARD_STEPS):
        for turn in OUTWARD_TURNS_DEG:
            ux, uy = math.cos(base + math.radians(turn)), math.sin(base + math.radians(turn))
            reach = gap + step * h + abs(ux) * w / 2 + abs(uy) * h / 2   # centre to the box's near side
            corners.append((ax + ux * reach - w / 2, ay + uy * reach - h / 2))
    return corners


def _coverage(mask: NDArray) -> NDArray:
    """Summed-area table of a boolean mask: the pixels of any box in four look-ups."""
    table = np.zeros((mask.shape[0] + 1, mask.shape[1] + 1), np.int64)
    table[1:, 1:] = np.cumsum(np.cumsum(mask, axis=0, dtype=np.int64), axis=1)
    return table


def _pixels_in(table: NDArray, box: Box) -> int:
    x0, y0 = min(box.x, table.shape[1] - 1), min(box.y, table.shape[0] - 1)
    x1, y1 = min(box.x + box.w, table.shape[1] - 1), min(box.y + box.h, table.shape[0] - 1)
    return int(table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0])


def _clamp(value: float, top: int) -> int:
    return int(min(max(round(value), 0), top))


def _nearest_free(want: Box, placed: list[Box], max_x: int, max_y: int) -> Box:
    """The free box of want's size nearest `want`, among the positions that touch an edge or a placed
    box (complete, see the module's note); the least overlapping one when none is free."""
    w, h = want.w, want.h
    xs = {0, max_x, want.x, *(p.x + p.w for p in placed), *(p.x - w for p in placed)}
    ys = {0, max_y, want.y, *(p.y + p.h for p in placed), *(p.y - h for p in placed)}
    cx = np.array(sorted(x for x in xs if 0 <= x <= max_x))
    cy = np.array(sorted(y for y in ys if 0 <= y <= max_y))
    gx, gy = (g.ravel() for g in np.meshgrid(cx, cy))
    covered = np.zeros(gx.shape, dtype=np.int64)
    for p in placed:
        dx = np.minimum(gx + w, p.x + p.w) - np.maximum(gx, p.x)
        dy = np.minimum(gy + h, p.y + p.h) - np.maximum(gy, p.y)
        covered += np.maximum(dx, 0) * np.maximum(dy, 0)
    distance = (gx - want.x) ** 2 + (gy - want.y) ** 2
    best = int(np.lexsort((distance, covered))[0])
    return Box(int(gx[best]), int(gy[best]), w, h)


@dataclass(frozen=True)
class LabelStyle:
    """How labels look: OpenCV's font at `scale` and `thickness` (one of each: OpenCV 5 draws a
    thicker stroke with a bolder, wider face), `text_bgr` on a `backing_bgr` box grown by `padding`
    px and outlined in the label's accent colour."""
    scale: float
    thickness: int = 1
    padding: int = 3
    text_bgr: tuple[int, int, int] = (0, 0, 0)
    backing_bgr: tuple[int, int, int] = (255, 255, 255)
    font: int = cv2.FONT_HERSHEY_SIMPLEX


def text_size(text: str, style: LabelStyle) -> tuple[int, int, int]:
    """(width, height above the baseline, depth below it) of `text` as cv2.putText draws it."""
    (w, h), baseline = cv2.getTextSize(text, style.font, style.scale, style.thickness)
    return w, h, baseline + style.thickness  # the stroke reaches a little past the baseline's depth


def draw_labels(image: NDArray, texts: Sequence[str], anchors: Sequence[tuple[float, float]],
                style: LabelStyle, accents: Sequence[tuple[int, int, int]] | None = None, *, gap: int = 0,
                obstacles: Sequence[Box] = (), away_from: tuple[float, float] | None = None,
                keep_off: NDArray | None = None) -> list[Box]:
    """Draw each text once, on its backing box placed by `place_labels` (same arguments), with a thin
    leader line in its accent colour (default: the text's) from its point when the box sits away from
    it. The boxes drawn, in the image's pixels."""
    sizes = [text_size(text, style) for text in texts]
    pad = style.padding
    boxes = place_labels(anchors, [(w + 2 * pad, h + depth + 2 * pad) for w, h, depth in sizes],
                         (image.shape[1], image.shape[0]), gap=gap, obstacles=obstacles, away_from=away_from,
                         keep_off=keep_off)
    colours = accents if accents is not None else [style.text_bgr] * len(texts)
    for (ax, ay), box, colour in zip(anchors, boxes, colours, strict=True):
        near = (min(max(round(ax), box.x), box.x + box.w - 1), min(max(round(ay), box.y), box.y + box.h - 1))
        if max(abs(near[0] - ax), abs(near[1] - ay)) > gap + LEADER_MIN_PX:   # not beside its point
            cv2.line(image, (round(ax), round(ay)), near, colour, style.thickness, cv2.LINE_AA)
    for text, box, (_w, h, _depth), colour in zip(texts, boxes, sizes, colours, strict=True):
        cv2.rectangle(image, (box.x, box.y), (box.x + box.w - 1, box.y + box.h - 1), style.backing_bgr, -1)
        cv2.rectangle(image, (box.x, box.y), (box.x + box.w - 1, box.y + box.h - 1), colour, 1)
        cv2.putText(image, text, (box.x + pad, box.y + pad + h), style.font, style.scale, style.text_bgr,
                    style.thickness, cv2.LINE_AA)
    return boxes
