"""`perceive --overlay`: the image with what perception found, named as the CloPeMa dataset names it.

Landmarks are numbered in the dataset's node order (clockwise on screen for a garment lying face up)
and coloured by the garment's own side as worn: the wearer's left in green, the wearer's right in
magenta, so a face-up garment shows its green side on the image's right.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from drivers.common.labels import Box, text_origins
from drivers.sessions.report import cv_text_size

CONTOUR_BGR = (0, 0, 255)
POLYGON_BGR = (255, 0, 0)
WEARER_LEFT_BGR = (60, 220, 60)
WEARER_RIGHT_BGR = (240, 80, 240)
NEITHER_SIDE_BGR = (0, 220, 255)
TEXT_BGR = (0, 0, 0)
BANNER_TEXT_BGR = (255, 255, 255)
HALO_BGR = (255, 255, 255)
FONT = cv2.FONT_HERSHEY_SIMPLEX
MARKER_RADIUS_PX = 8
LABEL_SCALE = 0.55
LABEL_GAP_PX = 10           # between a landmark and its label
HALO_THICKNESS = 4


def side_colour(name: str) -> tuple[int, int, int]:
    if "left" in name:
        return WEARER_LEFT_BGR
    if "right" in name:
        return WEARER_RIGHT_BGR
    return NEITHER_SIDE_BGR


def _text(image: np.ndarray, text: str, origin: tuple[int, int], scale: float,
          colour: tuple[int, int, int] = TEXT_BGR) -> None:
    # a white halo keeps the text readable on dark garments and on the table
    cv2.putText(image, text, origin, FONT, scale, HALO_BGR, HALO_THICKNESS, cv2.LINE_AA)
    cv2.putText(image, text, origin, FONT, scale, colour, 1 if scale < 0.7 else 2, cv2.LINE_AA)


def _order_arrow(image: np.ndarray, points: np.ndarray) -> None:
    """An arrow from the first node towards the second: the direction the dataset's order runs."""
    if len(points) < 2:
        return
    start, end = points[0], points[1]
    tip = start + 0.35 * (end - start)
    cv2.arrowedLine(image, tuple(int(v) for v in np.round(start)), tuple(int(v) for v in np.round(tip)),
                    NEITHER_SIDE_BGR, 3, cv2.LINE_AA, tipLength=0.25)


def draw_overlay(image: np.ndarray, observation: Any, facing: str = "front",
                 confidence: float | None = None) -> np.ndarray:
    """The image with the segmented contour, the matched polygon and the named, numbered landmarks."""
    out = image.copy()
    recognised = observation.category if confidence is None else \
        f"{observation.category} ({confidence:.0%})"
    lying = "face up" if facing == "front" else "face down"
    title = f"{recognised}, lying {lying} (facing: {facing}), match cost {observation.cost:.1f}"
    banner_height = _banner(out, [
        (title, BANNER_TEXT_BGR),
        ("numbered in the dataset's node order; left/right are the garment's own sides as worn",
         BANNER_TEXT_BGR),
        ("wearer's left", WEARER_LEFT_BGR), ("wearer's right", WEARER_RIGHT_BGR)])
    if observation.contour is not None:
        cv2.polylines(out, [observation.contour.reshape(-1, 1, 2).astype(np.int32)], True, CONTOUR_BGR, 2)
    cv2.polylines(out, [np.round(observation.polygon).astype(np.int32).reshape(-1, 1, 2)], True,
                  POLYGON_BGR, 2)
    names = list(observation.landmarks)
    points = np.array([observation.landmarks[name] for name in names], dtype=float).reshape(-1, 2)
    _order_arrow(out, points)
    centres = [(round(x), round(y)) for x, y in points]
    for name, centre in zip(names, centres, strict=True):
        cv2.circle(out, centre, MARKER_RADIUS_PX, side_colour(name), -1, cv2.LINE_AA)
        cv2.circle(out, centre, MARKER_RADIUS_PX, TEXT_BGR, 1, cv2.LINE_AA)
    labels = [f"{number} {name}" for number, name in enumerate(names, start=1)]
    # labels keep off the banner, the markers and each other, and inside the image
    keep_off = [Box(0, 0, out.shape[1], banner_height),
                *(Box(x - MARKER_RADIUS_PX, y - MARKER_RADIUS_PX, 2 * MARKER_RADIUS_PX, 2 * MARKER_RADIUS_PX)
                  for x, y in centres)]
    origins = text_origins(labels, centres, lambda text: cv_text_size(text, LABEL_SCALE, HALO_THICKNESS),
                           (out.shape[1], out.shape[0]), gap=LABEL_GAP_PX, obstacles=keep_off)
    for text, origin in zip(labels, origins, strict=True):
        _text(out, text, origin, LABEL_SCALE)
    return out


def _banner(image: np.ndarray, lines: list[tuple[str, tuple[int, int, int]]]) -> int:
    """Header lines on a darkened strip at the top of the image (drawn first: landmarks stay on top);
    the strip's height."""
    line_height = 30
    height = 12 + line_height * len(lines)
    image[:height] = (image[:height] * 0.5).astype(image.dtype)
    for row, (text, colour) in enumerate(lines):
        cv2.putText(image, text, (16, 32 + row * line_height), FONT, 0.75, colour, 2, cv2.LINE_AA)
    return height
