"""Plane geometry shared by perception, planning, evaluation and the simulated world: polygon
measures and the fold line.

Frame-neutral: points are (x, y) rows of an (n, 2) array in any planar frame (the table's, y to the
left seen from above, or an image's, y down). Only the sense of "clockwise" depends on the frame, so
it is left to the caller: `signed_area` is positive for a polygon that turns from +x towards +y,
which is counter-clockwise seen from above in the table frame and clockwise on screen in an image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


def signed_area(poly: ArrayLike) -> float:
    """Shoelace area of a closed polygon (n, 2): > 0 when it turns from +x towards +y (counter-clockwise
    in a y-up frame, clockwise on screen in a y-down image), < 0 the other way."""
    p = np.asarray(poly, dtype=float)
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def edge_lengths(poly: ArrayLike) -> np.ndarray:
    """Length of edge i -> i+1 (cyclic) of a closed polygon (n, 2), for every i."""
    p = np.asarray(poly, dtype=float)
    return np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1)


def perimeter(poly: ArrayLike) -> float:
    """Length of a closed polygon's outline."""
    return float(edge_lengths(poly).sum())


@dataclass(frozen=True)
class FoldLine:
    """A fold's line and the side of it that moves.

    `point` is a point on the line; `normal` (unit) is perpendicular to it and points to the side
    that MOVES (the grasped side: from the line towards the grasp points, away from where they are
    placed). `side` is > 0 on the moving side; a fold reflects that side across the line onto the
    side that stays (`side` < 0).
    """

    point: np.ndarray
    normal: np.ndarray

    @staticmethod
    def from_move(grasp: ArrayLike, place: ArrayLike) -> FoldLine:
        """The fold line of moving `grasp` onto `place`: their perpendicular bisector, the grasp's
        side moving."""
        g, p = np.asarray(grasp, dtype=float), np.asarray(place, dtype=float)
        d = g - p
        n = float(np.linalg.norm(d))
        if n < 1e-9:
            raise ValueError("move: grasp and place points coincide, no fold line")
        return FoldLine(point=(g + p) / 2.0, normal=d / n)

    def side(self, pts: ArrayLike) -> np.ndarray:
        """Signed distance of points (n, 2) (or one point) to the line, (n,): > 0 on the moving side."""
        return (np.atleast_2d(np.asarray(pts, dtype=float)) - self.point) @ self.normal

    def reflect(self, pts: ArrayLike) -> np.ndarray:
        """Points (n, 2) (or one point, as (1, 2)) mirrored across the line."""
        p = np.atleast_2d(np.asarray(pts, dtype=float))
        return p - 2.0 * self.side(p)[:, None] * self.normal[None, :]


def mask_iou(first: np.ndarray, second: np.ndarray, empty: float = 0.0) -> float:
    """Intersection over union of two boolean masks of one raster; `empty` when both are empty."""
    union = np.count_nonzero(first | second)
    return float(np.count_nonzero(first & second)) / union if union else empty
