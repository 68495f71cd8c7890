"""Garment outlines with the proportions of real garments, built here from measurements and not from
the simulated world, so recognition is checked against an independent reference: pants about 1 m long
with a 0.4 m waist and legs spread apart, wide polos with short sleeves and a neckline, shirts with long
sleeves, towels of aspect 1:1 to 1:2, pants folded once (one leg onto the other). Shapes are in metres
in the garment's frame (x to its right, y up); `posed` turns, mirrors, scales and moves one, and
`traced` rasterises it and traces its border as a segmentation would.

`CLOPEMA_PANTS` is the node polygon of a real annotated photograph (CloPeMa cloA00023, flat pants,
pixels as published); `CLOPEMA_POLO` that of a wrinkled polo (cloA01158), whose collar stands out
above its neckline and whose wearer's-left shoulder sags, so the collar's corner is a sharper corner
than the shoulder beside it.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

CLOPEMA_PANTS = np.array([[788.9, 65.9], [875.2, 124.3], [497.2, 627.9], [1132.7, 465.6], [1172.0, 570.9],
                          [344.9, 936.2], [171.1, 668.5]])

CLOPEMA_POLO_NAMES = ("bottom-left", "bottom-right", "right-armpit", "right-sleeve-inner",
                      "right-sleeve-outer", "right-shoulder", "neckline-right", "collar-right",
                      "collar-left", "neckline-left", "left-shoulder", "left-sleeve-outer",
                      "left-sleeve-inner", "left-armpit")
CLOPEMA_POLO = np.array([[800.3, 875.3], [526.3, 636.8], [679.8, 345.0], [678.6, 337.4], [616.4, 183.9],
                         [830.8, 133.2], [948.8, 190.3], [998.2, 173.8], [1116.2, 294.3], [1099.7, 336.2],
                         [1159.4, 459.2], [1210.1, 629.2], [1056.6, 644.4], [1013.5, 595.0]])
CLOPEMA_CM_PER_PX = 0.09   # the dataset's photographs (facts/clopema-dataset.md)


def _between(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


def pants(rng: np.random.Generator) -> NDArray:
    waist, length, rise = _between(rng, 0.36, 0.46), _between(rng, 0.95, 1.1), _between(rng, 0.25, 0.34)
    hem = _between(rng, 0.17, 0.24)
    spread = _between(rng, 0.0, 0.35)           # how far each hem lies out beyond the waist's side
    outer = waist / 2 + spread
    inner = max(outer - hem, 0.01)
    return np.array([[-waist / 2, 0.0], [waist / 2, 0.0], [outer, -length], [inner, -length], [0.0, -rise],
                     [-inner, -length], [-outer, -length]])


def folded_pants(rng: np.random.Generator) -> NDArray:
    """One leg folded onto the other: the half of the pants on one side of its middle."""
    half = pants(rng)
    waist, outer, inner, crotch = half[1], half[2], half[3], half[4]
    return np.array([[0.0, 0.0], waist, outer, inner, crotch])


def _shirt(rng: np.random.Generator, sleeve_length: tuple[float, float], sleeve_width: tuple[float, float],
           sleeve_angle: tuple[float, float]) -> NDArray:
    body_width, body_length = _between(rng, 0.48, 0.62), _between(rng, 0.65, 0.78)
    shoulders = body_width * _between(rng, 0.85, 0.95)
    armhole, drop = _between(rng, 0.2, 0.26), _between(rng, 0.02, 0.05)
    neck_width, neck_depth = _between(rng, 0.15, 0.2), _between(rng, 0.03, 0.09)
    top = body_length
    sides = []
    for side in (-1.0, 1.0):
        length, width = _between(rng, *sleeve_length), _between(rng, *sleeve_width)
        angle = _between(rng, *sleeve_angle)
        shoulder = np.array([side * shoulders / 2, top - drop])
        armpit = np.array([side * body_width / 2, top - drop - armhole])
        outer_end = shoulder + length * np.array([side * np.cos(angle), -np.sin(angle)])
        inner_end = outer_end + width * np.array([-side * np.sin(angle), -np.cos(angle)])
        sides.append((armpit, inner_end, outer_end, shoulder))
    (left_armpit, left_inner, left_outer, left_shoulder), (right_armpit, right_inner, right_outer,
                                                           right_shoulder) = sides
    return np.array([[-body_width / 2, 0.0], left_armpit, left_inner, left_outer, left_shoulder,
                     [-neck_width / 2, top], [0.0, top - neck_depth], [neck_width / 2, top],
                     right_shoulder, right_outer, right_inner, right_armpit, [body_width / 2, 0.0]])


def polo(rng: np.random.Generator) -> NDArray:
    return _shirt(rng, (0.18, 0.26), (0.15, 0.2), (0.3, 0.8))


def long_sleeve(rng: np.random.Generator) -> NDArray:
    """Sleeves longer than the body is wide, spread out or hanging beside the body."""
    return _shirt(rng, (0.58, 0.72), (0.1, 0.14), (0.4, 1.1))


def towel(rng: np.random.Generator) -> NDArray:
    width = _between(rng, 0.4, 0.8)
    height = width * _between(rng, 1.0, 2.0)
    return np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])


SHAPES = {"towel": towel, "pants": pants, "short-sleeve": polo, "long-sleeve": long_sleeve}


def posed(shape: NDArray, angle: float, mirrored: bool, scale: float, offset: tuple[float, float]) -> NDArray:
    """The shape turned by `angle` (rad), mirrored left-right first if asked, scaled and moved."""
    points = np.asarray(shape, float) * (np.array([-1.0, 1.0]) if mirrored else 1.0)
    turn = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return points @ turn.T * scale + np.asarray(offset)


def traced(polygon: NDArray) -> NDArray:
    """The border of the filled polygon (pixels), traced like a segmentation's."""
    points = np.asarray(polygon, float)
    origin = np.floor(points.min(axis=0)) - 4
    size = np.ceil(points.max(axis=0) - origin).astype(int) + 4
    mask = np.zeros((size[1], size[0]), np.uint8)
    cv2.fillPoly(mask, [np.round((points - origin) * 16).astype(np.int32)], 1, shift=4)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return max(contours, key=cv2.contourArea).reshape(-1, 2).astype(float) + origin


def random_outline(category: str, rng: np.random.Generator, folded: bool = False) -> NDArray:
    """A traced outline of a real-proportioned garment at any rotation, either side up, any size."""
    shape = folded_pants(rng) if folded else SHAPES[category](rng)
    pixels_per_m = _between(rng, 500.0, 1100.0)
    return traced(posed(shape, _between(rng, 0.0, 2 * np.pi), bool(rng.random() < 0.5), pixels_per_m,
                        (800.0, 800.0)))
