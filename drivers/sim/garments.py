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

from drivers.common.garments import CATEGORIES, LANDMARKS
from drivers.sim.config import SHAPES, SimConfig
from drivers.sim.errors import SimInputError
from drivers.sim.geometry import segments_intersect

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


def _draw(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _towel_local(rng: np.random.Generator, cfg: SimConfig) -> np.ndarray:
    ranges = cfg.ranges("towel")
    width, height = _draw(rng, ranges["width"]), _draw(rng, ranges["height"])
    corners = np.array([[-width / 2, -height / 2], [width / 2, -height / 2], [width / 2, height / 2],
                        [-width / 2, height / 2]])
    return corners + rng.uniform(-cfg.corner_jitter, cfg.corner_jitter, size=corners.shape)


def _pants_local(rng: np.random.Generator, cfg: SimConfig) -> np.ndarray:
    ranges = cfg.ranges("pants")
    waist, length, rise = (_draw(rng, ranges["waist_width"]), _draw(rng, ranges["length"]),
                           _draw(rng, ranges["rise"]))
    hem, leg_gap, flare = (_draw(rng, ranges["hem_width"]), _draw(rng, ranges["leg_gap"]),
                           _draw(rng, ranges["flare"]))
    outer_x = waist / 2 + flare
    inner_x = max(outer_x - hem, leg_gap)
    top, bottom = length / 2, -length / 2
    skew = rng.uniform(-0.01, 0.01, size=4)   # legs of slightly different lengths
    return np.array([
        [-outer_x, bottom + skew[0]], [-inner_x, bottom + skew[1]], [0.0, top - rise],
        [inner_x, bottom + skew[2]], [outer_x, bottom + skew[3]], [waist / 2, top], [-waist / 2, top],
    ])


def _shirt_local(category: str, rng: np.random.Generator, cfg: SimConfig) -> np.ndarray:
    ranges = cfg.ranges(category)
    body_width, body_length = _draw(rng, ranges["body_width"]), _draw(rng, ranges["body_length"])
    shoulder_width, drop, armhole = (_draw(rng, ranges["shoulder_width"]),
                                     _draw(rng, ranges["shoulder_drop"]), _draw(rng, ranges["armhole_depth"]))
    top, bottom = body_length / 2, -body_length / 2
    sides = []
    for side in (-1.0, 1.0):   # left, then right
        sleeve_length = _draw(rng, ranges["sleeve_length"])
        sleeve_width = _draw(rng, ranges["sleeve_width"])
        angle = _draw(rng, ranges["sleeve_angle"])
        shoulder = np.array([side * shoulder_width / 2, top - drop])
        armpit = np.array([side * body_width / 2, top - drop - armhole])
        along = np.array([side * np.cos(angle), -np.sin(angle)])
        outer = shoulder + sleeve_length * along
        inner = outer + sleeve_width * np.array([-side * np.sin(angle), -np.cos(angle)])
        sides.append((armpit, inner, outer, shoulder))
    (left_armpit, left_inner, left_outer, left_shoulder), (right_armpit, right_inner, right_outer,
                                                           right_shoulder) = sides
    return np.array([[-body_width / 2, bottom], left_armpit, left_inner, left_outer, left_shoulder,
                     right_shoulder, right_outer, right_inner, right_armpit, [body_width / 2, bottom]],
                    dtype=float)


def _shape_local(category: str, rng: np.random.Generator, cfg: SimConfig) -> np.ndarray:
    """The garment's landmarks in its own frame (m), in the design's order."""
    if category == "towel":
        return _towel_local(rng, cfg)
    if category == "pants":
        return _pants_local(rng, cfg)
    return _shirt_local(category, rng, cfg)


def _ripple_outline(local: np.ndarray, category: str, shape: str, rng: np.random.Generator,
                    cfg: SimConfig) -> tuple[np.ndarray, tuple[int, ...]]:
    """The border through the landmarks `local`, every `edges.spacing`, rippled (the ripple fades to
    zero at the landmarks), sleeves and legs bowed, a shirt's neckline dipped; and the index of each
    landmark in it."""
    edges = cfg.edges
    names = LANDMARKS[category]
    neck_edge = names.index("left-shoulder") if "left-shoulder" in names else -1
    amplitude = edges.wrinkled_amplitude if shape == "wrinkled" else edges.flat_amplitude
    out: list[np.ndarray] = []
    index: list[int] = []
    count = len(local)
    for i in range(count):
        start, end = local[i], local[(i + 1) % count]
        edge = end - start
        length = float(np.linalg.norm(edge))
        steps = max(int(np.ceil(length / edges.spacing)), 2)
        t = np.arange(steps) / steps                 # excludes the end, which starts the next edge
        along = t * length
        normal = np.array([-edge[1], edge[0]]) / max(length, 1e-12)
        ripple = np.zeros(steps)
        for _ in range(2):
            wavelength = _draw(rng, edges.wavelength)
            ripple += np.sin(2 * np.pi * along / wavelength + rng.uniform(0, 2 * np.pi))
        ripple *= amplitude / 2.0
        ramp = np.clip(np.minimum(along, length - along) / edges.corner_ramp, 0.0, 1.0)
        ramp = ramp * ramp * (3 - 2 * ramp)          # smoothstep: zero offset and slope at corners
        offset = ripple * ramp
        if i in _BOWED_EDGES[category]:
            offset = offset + rng.uniform(-edges.sleeve_bow, edges.sleeve_bow) * length * np.sin(np.pi * t)
        if i == neck_edge:
            # a smooth dip between the shoulders (shirts have a neckline the 10-vertex model lacks)
            ranges = cfg.ranges(category)
            half = min(_draw(rng, ranges["neck_width"]) / 2.0, 0.4 * length)
            depth = _draw(rng, ranges["neck_depth"])
            x = (along - length / 2.0) / half
            offset = offset - depth * np.where(np.abs(x) < 1.0, np.cos(np.clip(x, -1, 1) * np.pi / 2) ** 2,
                                               0.0)
        index.append(len(out))
        out.extend(start + t[:, None] * edge + offset[:, None] * normal)
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
        weights = np.array([weight for _, weight in cfg.shape_weights], dtype=float)
        shape = SHAPES[int(rng.choice(len(SHAPES), p=weights / weights.sum()))]
    if shape not in SHAPES:
        raise SimInputError(f"shape: must be one of {', '.join(SHAPES)}, got {shape!r}")
    lo_view, hi_view = view_bounds(np.asarray(view_polygon, dtype=float), cfg.pose.view_margin)
    for _ in range(cfg.pose.attempts):
        local = _shape_local(category, rng, cfg)
        if segments_intersect(local):
            continue
        outline_local, index = _ripple_outline(local, category, shape, rng, cfg)
        theta = float(rng.uniform(-cfg.pose.rotation, cfg.pose.rotation))
        cos, sin = np.cos(theta), np.sin(theta)
        rotation = np.array([[cos, -sin], [sin, cos]]) @ _GARMENT_TO_TABLE
        placed = outline_local @ rotation.T
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
