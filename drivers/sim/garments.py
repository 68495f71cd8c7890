"""Parametric garment shapes per category with ground-truth landmarks.

A shape is built in a garment frame (x to the viewer's right, y towards the garment's top, seen from
above), rippled along its border with the ripple fading to zero at every landmark (so corners stay
exact), then posed on the table: garment "up" points along table +x (away from the robot, the image
top), garment "right" along table -y (the image right), turned by a small random angle.
Landmark lists follow the design page's order (counter-clockwise for towel and pants, clockwise for
the shirts, as the shared convention states).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.sim.config import CATEGORIES, SHAPES, SimConfig
from drivers.sim.errors import SimInputError
from drivers.sim.geometry import segments_intersect

LANDMARKS: dict[str, tuple[str, ...]] = {
    "towel": ("bottom-left", "bottom-right", "top-right", "top-left"),
    "pants": ("left-leg-outer", "left-leg-inner", "crotch", "right-leg-inner", "right-leg-outer",
              "top-right", "top-left"),
    "short-sleeve": ("bottom-left", "left-armpit", "left-sleeve-inner", "left-sleeve-outer", "left-shoulder",
                     "right-shoulder", "right-sleeve-outer", "right-sleeve-inner", "right-armpit",
                     "bottom-right"),
}
LANDMARKS["long-sleeve"] = LANDMARKS["short-sleeve"]

# edges (index of their first landmark) that bow a little: sleeves and legs are not quite straight
_BOWED_EDGES: dict[str, tuple[int, ...]] = {
    "towel": (),
    "pants": (0, 3, 4, 6),
    "short-sleeve": (1, 3, 5, 7),
}
_BOWED_EDGES["long-sleeve"] = _BOWED_EDGES["short-sleeve"]

# garment frame (right, up) -> table frame: right -> -y, up -> +x
_GARMENT_TO_TABLE = np.array([[0.0, 1.0], [-1.0, 0.0]])


@dataclass(frozen=True)
class Garment:
    """A flat garment on the table (table frame, m)."""

    category: str
    shape: str                        # "flat" or "wrinkled"
    names: tuple[str, ...]
    landmarks: np.ndarray             # (N, 2), in `names` order
    outline: np.ndarray               # (M, 2) rippled border through every landmark, same orientation
    landmark_index: tuple[int, ...]   # index of each landmark in `outline`
    rotation: float                   # rad, garment up vs table +x
    centre: np.ndarray


def _u(rng: np.random.Generator, r: tuple[float, float]) -> float:
    return float(rng.uniform(r[0], r[1]))


def _shape_local(category: str, rng: np.random.Generator, cfg: SimConfig) -> np.ndarray:
    r = cfg.ranges(category)
    if category == "towel":
        w, h = _u(rng, r["width"]), _u(rng, r["height"])
        pts = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
        return pts + rng.uniform(-cfg.corner_jitter, cfg.corner_jitter, size=pts.shape)
    if category == "pants":
        ww, ln, rise = _u(rng, r["waist_width"]), _u(rng, r["length"]), _u(rng, r["rise"])
        hem, gap, flare = _u(rng, r["hem_width"]), _u(rng, r["leg_gap"]), _u(rng, r["flare"])
        outer = ww / 2 + flare
        inner = max(outer - hem, gap)
        top, bottom = ln / 2, -ln / 2
        skew = rng.uniform(-0.01, 0.01, size=4)   # legs of slightly different lengths
        return np.array([
            [-outer, bottom + skew[0]], [-inner, bottom + skew[1]], [0.0, top - rise],
            [inner, bottom + skew[2]], [outer, bottom + skew[3]], [ww / 2, top], [-ww / 2, top],
        ])
    bw, bl = _u(rng, r["body_width"]), _u(rng, r["body_length"])
    sw, drop, arm = _u(rng, r["shoulder_width"]), _u(rng, r["shoulder_drop"]), _u(rng, r["armhole_depth"])
    top, bottom = bl / 2, -bl / 2
    pts = [[-bw / 2, bottom]]
    sides = []
    for sgn in (-1.0, 1.0):
        ls, swid, ang = _u(rng, r["sleeve_length"]), _u(rng, r["sleeve_width"]), _u(rng, r["sleeve_angle"])
        shoulder = np.array([sgn * sw / 2, top - drop])
        armpit = np.array([sgn * bw / 2, top - drop - arm])
        d = np.array([sgn * np.cos(ang), -np.sin(ang)])
        outer = shoulder + ls * d
        inner = outer + swid * np.array([-sgn * np.sin(ang), -np.cos(ang)])
        sides.append((armpit, inner, outer, shoulder))
    (la, li, lo, lsh), (ra, ri, ro, rsh) = sides
    pts += [la, li, lo, lsh, rsh, ro, ri, ra, [bw / 2, bottom]]
    return np.array(pts, dtype=float)


def _ripple_outline(local: np.ndarray, category: str, shape: str, rng: np.random.Generator,
                    cfg: SimConfig) -> tuple[np.ndarray, tuple[int, ...]]:
    e = cfg.edges
    neck_edge = LANDMARKS[category].index("left-shoulder") if "left-shoulder" in LANDMARKS[category] else -1
    amp = e.wrinkled_amplitude if shape == "wrinkled" else e.flat_amplitude
    out: list[np.ndarray] = []
    index: list[int] = []
    n = len(local)
    for i in range(n):
        a, b = local[i], local[(i + 1) % n]
        seg = b - a
        length = float(np.linalg.norm(seg))
        k = max(int(np.ceil(length / e.spacing)), 2)
        t = np.arange(k) / k                         # excludes b, which starts the next edge
        s = t * length
        normal = np.array([-seg[1], seg[0]]) / max(length, 1e-12)
        ripple = np.zeros(k)
        for _ in range(2):
            wl = _u(rng, e.wavelength)
            ripple += np.sin(2 * np.pi * s / wl + rng.uniform(0, 2 * np.pi))
        ripple *= amp / 2.0
        ramp = np.clip(np.minimum(s, length - s) / e.corner_ramp, 0.0, 1.0)
        ramp = ramp * ramp * (3 - 2 * ramp)          # smoothstep: zero offset and slope at corners
        offset = ripple * ramp
        if i in _BOWED_EDGES[category]:
            offset = offset + rng.uniform(-e.sleeve_bow, e.sleeve_bow) * length * np.sin(np.pi * t)
        if i == neck_edge:
            # a smooth dip between the shoulders (shirts have a neckline the 10-vertex model lacks)
            r = cfg.ranges(category)
            half = min(_u(rng, r["neck_width"]) / 2.0, 0.4 * length)
            depth = _u(rng, r["neck_depth"])
            x = (s - length / 2.0) / half
            offset = offset - depth * np.where(np.abs(x) < 1.0, np.cos(np.clip(x, -1, 1) * np.pi / 2) ** 2,
                                               0.0)
        index.append(len(out))
        out.extend(a + t[:, None] * seg + offset[:, None] * normal)
    return np.array(out), tuple(index)


def view_bounds(view_polygon: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    lo = view_polygon.min(0) + margin
    hi = view_polygon.max(0) - margin
    return lo, hi


def make_garment(category: str, rng: np.random.Generator, cfg: SimConfig, view_polygon: np.ndarray,
                 shape: str | None = None) -> Garment:
    """A random garment of `category` lying inside `view_polygon` (table frame, the camera's view)."""
    if category not in CATEGORIES:
        raise SimInputError(f"category: must be one of {', '.join(CATEGORIES)}, got {category!r}")
    if shape is None:
        w = np.array([v for _, v in cfg.shape_weights], dtype=float)
        shape = SHAPES[int(rng.choice(len(SHAPES), p=w / w.sum()))]
    if shape not in SHAPES:
        raise SimInputError(f"shape: must be one of {', '.join(SHAPES)}, got {shape!r}")
    lo_view, hi_view = view_bounds(np.asarray(view_polygon, dtype=float), cfg.pose.view_margin)
    for _ in range(cfg.pose.attempts):
        local = _shape_local(category, rng, cfg)
        if segments_intersect(local):
            continue
        outline_local, index = _ripple_outline(local, category, shape, rng, cfg)
        theta = float(rng.uniform(-cfg.pose.rotation, cfg.pose.rotation))
        c, s = np.cos(theta), np.sin(theta)
        rot = np.array([[c, -s], [s, c]]) @ _GARMENT_TO_TABLE
        placed = outline_local @ rot.T
        lo = lo_view - placed.min(0)
        hi = hi_view - placed.max(0)
        if np.any(hi < lo):
            continue
        centre = rng.uniform(lo, hi)
        outline = placed + centre
        landmarks = outline[list(index)].copy()
        return Garment(category=category, shape=shape, names=LANDMARKS[category], landmarks=landmarks,
                       outline=outline, landmark_index=index, rotation=theta, centre=centre)
    raise SimInputError(f"category: no {category} of the configured sizes fits the camera view "
                        f"after {cfg.pose.attempts} attempts (check config/sim.yaml garments and pose)")
