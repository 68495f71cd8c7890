"""Synthetic garments and images for tests, model learning and benchmarks (pure, seeded).

Shapes are templates in cm (image axes, garment upright, landmarks in the design's order) with
random proportions, converted to pixels at `cm_per_px`, rotated and placed on a rendered wooden
table lit unevenly (bright centre, dark corners). Shirts get a neckline dip between the
shoulders that is drawn but is not a landmark, as in real data.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .models import DESIGN_LANDMARKS

IMAGE_SIZE = (1280, 1024)
CM_PER_PX = 0.09
TABLE_BGR = (118.0, 168.0, 205.0)
GARMENT_BGR = [(160, 60, 30), (40, 40, 170), (60, 130, 40), (70, 70, 70), (235, 235, 235),
               (30, 30, 30), (140, 50, 120), (30, 140, 200), (200, 200, 90)]


def _template(category: str, rng: np.random.Generator) -> tuple[NDArray, list[tuple[int, NDArray]]]:
    """Landmark polygon in cm and extra drawn-only points (inserted after index)."""
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    extras: list[tuple[int, NDArray]] = []
    if category == "towel":
        w, h = u(45, 80), u(30, 60)
        pts = [(0, h), (w, h), (w, 0), (0, 0)]
    elif category == "pants":
        W, L, crotch, leg = u(38, 46), u(62, 80), u(22, 30), u(12, 15)
        flare = u(-3, 1)
        pts = [(-flare, L), (leg - flare, L + u(-1, 1)), (W / 2, crotch), (W - leg + flare, L + u(-1, 1)),
               (W + flare, L), (W, 0), (0, 0)]
    else:
        W, H = u(44, 52), u(58, 70)
        arm = u(19, 24)
        sh = u(9, 13)
        if category == "short-sleeve":
            sl, sw, ang = u(12, 18), u(13, 16), np.deg2rad(u(25, 40))
        else:
            sl, sw, ang = u(40, 50), u(10, 13), np.deg2rad(u(55, 70))
        # sleeve: from the armpit along direction (-sin ang... ) pointing outwards and down
        d = np.array([-np.sin(ang), np.cos(ang)])   # left sleeve axis (outwards, down)
        nrm = np.array([-d[1], d[0]])               # towards the shoulder side
        armpit = np.array([0.0, arm])
        inner = armpit + d * sl
        outer = inner + np.array([d[1], -d[0]]) * -sw
        if outer[1] > inner[1]:
            outer = inner - nrm * sw
        shoulder = np.array([sh, u(0, 2)])
        left = [(0, H), tuple(armpit), tuple(inner), tuple(outer), tuple(shoulder)]
        right = [(W - x, y) for x, y in reversed(left)]
        pts = left + right
        neck_w, neck_d = u(0.35, 0.5) * (W - 2 * sh), u(2, 6)
        extras = [(4, np.array([[W / 2 - neck_w / 2, shoulder[1] + 1], [W / 2, shoulder[1] + neck_d],
                                [W / 2 + neck_w / 2, shoulder[1] + 1]]))]
    jitter = rng.normal(0.0, 0.6, (len(pts), 2))   # shape variation of real garments, cm
    return np.asarray(pts, float) + jitter, extras


@dataclass(frozen=True)
class SyntheticGarment:
    category: str
    names: tuple[str, ...]
    landmarks: NDArray   # (M, 2) px, design order
    outline: NDArray     # (P, 2) px, drawn polygon including non-landmark points


def random_garment(category: str, rng: np.random.Generator, max_rotation_deg: float = 15.0,
                   image_size: tuple[int, int] = IMAGE_SIZE, cm_per_px: float = CM_PER_PX,
                   margin_px: float = 60.0) -> SyntheticGarment:
    pts, extras = _template(category, rng)
    outline = []
    for i, p in enumerate(pts):
        outline.append(p[None])
        for after, e in extras:
            if after == i:
                outline.append(e)
    out = np.concatenate(outline)
    theta = np.deg2rad(rng.uniform(-max_rotation_deg, max_rotation_deg))
    rot = np.array([[np.cos(theta), -np.sin(theta)], [np.sin(theta), np.cos(theta)]])
    lm = pts / cm_per_px @ rot.T
    out = out / cm_per_px @ rot.T
    lo, hi = out.min(axis=0), out.max(axis=0)
    size = hi - lo
    avail = np.asarray(image_size, float) - 2 * margin_px
    scale = min(1.0, float(np.min(avail / size)))
    lm, out = (lm - lo) * scale, (out - lo) * scale
    room = avail - size * scale
    shift = margin_px + rng.uniform(0, 1, 2) * np.maximum(room, 0)
    return SyntheticGarment(category, DESIGN_LANDMARKS[category], lm + shift, out + shift)


def illumination(image_size: tuple[int, int] = IMAGE_SIZE, strength: float = 0.35,
                 centre: tuple[float, float] = (0.5, 0.45)) -> NDArray:
    """Gain field: 1 + strength/2 at a bright spot, falling to about 1 - strength/2 in the corners."""
    w, h = image_size
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((xx / w - centre[0]) ** 2 + (yy / h - centre[1]) ** 2) / 0.25
    return (1.0 - strength / 2 + strength * np.exp(-r2)).astype(np.float32)


def table_image(rng: np.random.Generator, image_size: tuple[int, int] = IMAGE_SIZE,
                light: NDArray | None = None, table_seed: int = 7) -> NDArray:
    """An empty wooden table (the same grain for the same table_seed), lit by `light`."""
    w, h = image_size
    trng = np.random.default_rng(table_seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    phase = trng.uniform(0, 6.28, 3)
    grain = (np.sin(xx / 23.0 + 3 * np.sin(yy / 180.0 + phase[0])) * 0.5
             + np.sin(xx / 7.0 + 2 * np.sin(yy / 60.0 + phase[1])) * 0.25)
    base = np.asarray(TABLE_BGR, np.float32)
    img = base[None, None, :] * (1.0 + 0.06 * grain[..., None])
    img = img + rng.normal(0, 3.0, img.shape).astype(np.float32)
    if light is None:
        light = illumination(image_size)
    img = img * light[..., None]
    return np.clip(img, 0, 255).astype(np.uint8)


def render(garment: SyntheticGarment | None, rng: np.random.Generator,
           image_size: tuple[int, int] = IMAGE_SIZE, light: NDArray | None = None,
           colour: tuple[float, float, float] | None = None) -> NDArray:
    """The garment drawn on the table; None draws the empty table."""
    if light is None:
        light = illumination(image_size)
    img = table_image(rng, image_size, light).astype(np.float32)
    if garment is not None:
        if colour is None:
            colour = GARMENT_BGR[int(rng.integers(len(GARMENT_BGR)))]
        mask = np.zeros(img.shape[:2], np.uint8)
        shift = 4
        pts = np.round(garment.outline * (1 << shift)).astype(np.int32)
        cv2.fillPoly(mask, [pts], 255, lineType=cv2.LINE_AA, shift=shift)
        alpha = (mask.astype(np.float32) / 255.0)[..., None]
        cloth = np.asarray(colour, np.float32)[None, None, :] * light[..., None]
        cloth = cloth + rng.normal(0, 4.0, img.shape).astype(np.float32)
        img = img * (1 - alpha) + cloth * alpha
    return np.clip(img, 0, 255).astype(np.uint8)
