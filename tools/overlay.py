"""`perceive --overlay`: the image with what perception found, named as the CloPeMa dataset names it.

Landmarks are numbered in the dataset's node order (clockwise on screen for a garment lying face up)
and coloured by the garment's own side as worn: the wearer's left in green, the wearer's right in
magenta, so a face-up garment shows its green side on the image's right.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from drivers.common.labels import Box, LabelStyle, draw_labels, text_size

CONTOUR_BGR = (0, 0, 255)
POLYGON_BGR = (255, 0, 0)
WEARER_LEFT_BGR = (60, 220, 60)
WEARER_RIGHT_BGR = (240, 80, 240)
NEITHER_SIDE_BGR = (0, 220, 255)
TEXT_BGR = (0, 0, 0)
BAND_BGR = (48, 48, 48)
BAND_TEXT_BGR = (255, 255, 255)
MARKER_RADIUS_PX = 8
LABEL_STYLE = LabelStyle(scale=0.55)
LABEL_GAP_PX = 10           # between a landmark and its label
TITLE_STYLE = LabelStyle(scale=0.75, thickness=2)
TITLE_MARGIN_PX = 12        # around the title band's text
TITLE_LINE_GAP_PX = 10
LEGEND_GAP_PX = 30          # between the legend's entries on its line


def side_colour(name: str) -> tuple[int, int, int]:
    if "left" in name:
        return WEARER_LEFT_BGR
    if "right" in name:
        return WEARER_RIGHT_BGR
    return NEITHER_SIDE_BGR


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
    """The image with the segmented contour, the matched polygon and the named, numbered landmarks,
    under a title band added above it (the image keeps its every row)."""
    out = image.copy()
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
    outline = observation.contour if observation.contour is not None else observation.polygon
    garment = np.zeros(out.shape[:2], np.uint8)
    cv2.fillPoly(garment, [np.round(outline).astype(np.int32).reshape(-1, 1, 2)], 1)
    rows, cols = np.nonzero(garment)
    # labels go outward from the garment, off it, the markers and each other where there is room
    markers = [Box(x - MARKER_RADIUS_PX, y - MARKER_RADIUS_PX, 2 * MARKER_RADIUS_PX, 2 * MARKER_RADIUS_PX)
               for x, y in centres]
    draw_labels(out, [f"{number} {name}" for number, name in enumerate(names, start=1)], centres, LABEL_STYLE,
                [side_colour(name) for name in names], gap=LABEL_GAP_PX, obstacles=markers,
                away_from=(float(cols.mean()), float(rows.mean())) if len(rows) else None,
                keep_off=garment.astype(bool))
    recognised = observation.category if confidence is None else \
        f"{observation.category} ({confidence:.0%})"
    lying = "face up" if facing == "front" else "face down"
    title = f"{recognised}, lying {lying} (facing: {facing}), match cost {observation.cost:.1f}"
    band = _title_band(out.shape[1], [
        [(title, BAND_TEXT_BGR)],
        [("numbered in the dataset's node order; left/right are the garment's own sides as worn",
          BAND_TEXT_BGR)],
        [("wearer's left", WEARER_LEFT_BGR), ("wearer's right", WEARER_RIGHT_BGR)]])
    return np.vstack([band, out])


def _title_band(width: int, lines: list[list[tuple[str, tuple[int, int, int]]]]) -> np.ndarray:
    """A band of text lines (each a row of coloured entries) to go above an image `width` px wide,
    the text scaled down to fit it."""
    def line_width(line: list[tuple[str, tuple[int, int, int]]], style: LabelStyle) -> int:
        return sum(text_size(text, style)[0] for text, _ in line) + LEGEND_GAP_PX * (len(line) - 1)

    widest = max(line_width(line, TITLE_STYLE) for line in lines)
    fit = min(1.0, (width - 2 * TITLE_MARGIN_PX) / widest)
    style = LabelStyle(TITLE_STYLE.scale * fit, TITLE_STYLE.thickness)
    _w, above, below = text_size("Ag", style)
    line_height = above + below + TITLE_LINE_GAP_PX
    band = np.full((2 * TITLE_MARGIN_PX + line_height * len(lines) - TITLE_LINE_GAP_PX, width, 3), BAND_BGR,
                   np.uint8)
    for row, line in enumerate(lines):
        x, y = TITLE_MARGIN_PX, TITLE_MARGIN_PX + row * line_height + above
        for text, colour in line:
            cv2.putText(band, text, (x, y), style.font, style.scale, colour, style.thickness, cv2.LINE_AA)
            x += text_size(text, style)[0] + LEGEND_GAP_PX
    return band
