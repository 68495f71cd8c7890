"""Where to draw text labels on an image: near their point, inside the image, not on each other. Pure.

Each label goes at the first of a few spots around its point (right-above, right-below, left-above,
left-below) that lies inside the image and is free, else at the first of them pushed inside that is
free; when none is, at the free spot nearest the
preferred one. The search for a free spot is complete: a free box can slide left and up until it meets
the image's edge or another box, so trying the positions 0 and the right and bottom edges of the boxes
placed finds one whenever one exists. Only when none does (no room) does a label overlap the least.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np


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
                 image_size: tuple[int, int], *, gap: int = 0,
                 obstacles: Sequence[Box] = ()) -> list[Box]:
    """A box (top-left x, y, width, height) per label of `sizes` (w, h) for its anchor point (x, y),
    in an image of `image_size` (width, height); `gap` px between a label and its point. Boxes stay
    inside the image (a label larger than the image starts at its top-left corner) and, room allowing,
    off each other and off `obstacles`."""
    width, height = image_size
    placed: list[Box] = list(obstacles)
    out: list[Box] = []
    for (ax, ay), (w, h) in zip(anchors, sizes, strict=True):
        w, h = int(w), int(h)
        max_x, max_y = max(0, width - w), max(0, height - h)
        preferred = [(ax + gap, ay - gap - h), (ax + gap, ay + gap), (ax - gap - w, ay - gap - h),
                     (ax - gap - w, ay + gap)]
        # the spots that fit as they are first, then each pushed inside
        fitting = [Box(round(x), round(y), w, h) for x, y in preferred if 0 <= x <= max_x and 0 <= y <= max_y]
        spots = fitting + [Box(_clamp(x, max_x), _clamp(y, max_y), w, h) for x, y in preferred]
        box = next((b for b in spots if not any(b.overlap(p) for p in placed)), None)
        if box is None:
            box = _nearest_free(spots[0], placed, max_x, max_y)
        placed.append(box)
        out.append(box)
    return out


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


def text_origins(texts: Sequence[str], anchors: Sequence[tuple[float, float]],
                 measure: Callable[[str], tuple[int, int, int]], image_size: tuple[int, int], *,
                 gap: int = 0, obstacles: Sequence[Box] = ()) -> list[tuple[int, int]]:
    """`place_labels` for texts drawn from their baseline's left end (as OpenCV's putText does):
    `measure(text) -> (width, height above the baseline, depth below it)`; the origin of each text."""
    sizes = [measure(text) for text in texts]
    boxes = place_labels(anchors, [(w, h + depth) for w, h, depth in sizes], image_size, gap=gap,
                         obstacles=obstacles)
    return [(box.x, box.y + h) for box, (_w, h, _depth) in zip(boxes, sizes, strict=True)]
