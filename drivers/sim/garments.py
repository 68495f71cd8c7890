"""Parametric garment shapes per category with ground-truth landmarks.

A shape is built in a garment frame (x to the viewer's right, y towards the garment's top, seen from
above), rippled along its border with the ripple fading to zero at every landmark (so corners stay
exact), then posed on the table: garment "up" points along table +x (away from the robot, the image
top), the viewer's right along table -y (the image right), turned by a random angle (any, by
default), anywhere in the camera's view.

Names follow the dataset (`drivers.common.garments`): `left`/`right` are the wearer's sides. A garment
lying face up (`facing="front"`) has its wearer's left on the viewer's right; one lying face down
(`facing="back"`) is the mirror image, its wearer's left on the viewer's left. The lists come out in
the dataset's order, which runs clockwise on screen face up and counter-clockwise face down. A shirt
also carries the dataset's neckline and collar nodes on its neckline: a shirt without a collar dips
between the neckline's ends; a collared one (a polo, a shirt) has its collar standing out above them, as
the dataset's polos lie, the collar's corners (its `collar-*` nodes) sharp corners of the outline.

The planner's samples (`place_garment`: tests, the bench, `foldcell plan check`) are plainer: one
typical garment of each category (`TEMPLATES`, the same landmarks in the same order), its landmarks
alone, placed anywhere on the table (no camera) within the robot's reach, in the same frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drivers.common.garments import ANNOTATED_NODES, CATEGORIES, FACINGS, LANDMARKS, SHIRT_NECK_NODES
from drivers.robot.table import TableConfig
from drivers.sim.config import SHAPES, SimConfig
from drivers.sim.errors import SimInputError
from drivers.sim.geometry import point_segment_distance, points_in_polygon, segments_intersect

_SHIRT_TRACE = ("bottom-right", "right-armpit", "right-sleeve-inner", "right-sleeve-outer", "right-shoulder",
                "left-shoulder", "left-sleeve-outer", "left-sleeve-inner", "left-armpit", "bottom-left")
# the order each border is drawn in, face up, from the image's lower left; fixed, so that a seed always
# draws the same garment (the ripple's random draws go edge by edge)
_TRACE: dict[str, tuple[str, ...]] = {
    "towel": ("bottom-right", "bottom-left", "top-left", "top-right"),
    "pants": ("right-leg-outer", "right-leg-inner", "crotch", "left-leg-inner", "left-leg-outer", "top-left",
              "top-right"),
    "short-sleeve": _SHIRT_TRACE,
    "long-sleeve": _SHIRT_TRACE,
}

# edges (the landmarks they join) that bow a little: sleeves and legs are not quite straight
_SHIRT_BOWED = (frozenset({"right-armpit", "right-sleeve-inner"}),
                frozenset({"right-sleeve-outer", "right-shoulder"}),
                frozenset({"left-shoulder", "left-sleeve-outer"}),
                frozenset({"left-sleeve-inner", "left-armpit"}))
_BOWED_EDGES: dict[str, tuple[frozenset[str], ...]] = {
    "towel": (),
    "pants": (frozenset({"right-leg-outer", "right-leg-inner"}),
              frozenset({"left-leg-inner", "left-leg-outer"}),
              frozenset({"left-leg-outer", "top-left"}), frozenset({"top-right", "right-leg-outer"})),
    "short-sleeve": _SHIRT_BOWED,
    "long-sleeve": _SHIRT_BOWED,
}
# the shirt's neckline dips into the body on this edge (drawn from its first name to its second)
_NECK_EDGE = ("right-shoulder", "left-shoulder")

# garment frame (right, up) -> table frame: right -> -y, up -> +x
_GARMENT_TO_TABLE = np.array([[0.0, 1.0], [-1.0, 0.0]])


@dataclass(frozen=True)
class Garment:
    """A flat garment on the table (table frame, m)."""

    category: str
    shape: str                        # "flat" or "wrinkled"
    facing: str                       # "front" (lying face up) or "back" (face down)
    names: tuple[str, ...]            # the model's landmarks, `LANDMARKS` order
    landmarks: np.ndarray             # (N, 2), in `names` order
    outline: np.ndarray               # (M, 2) rippled border through every node, in `names` order
    landmark_index: tuple[int, ...]   # index of each landmark in `outline`
    node_names: tuple[str, ...]       # every node the dataset annotates (`ANNOTATED_NODES` order)
    node_index: tuple[int, ...]       # index of each node in `outline`
    rotation: float                   # rad, garment up vs table +x
    scale: float                      # the drawn sizes scaled by this to fit the view (1: as drawn)
    centre: np.ndarray

    def nodes(self) -> np.ndarray:
        """(K, 2) points of `node_names` (for a shirt the landmarks and its neckline nodes)."""
        return self.outline[list(self.node_index)].copy()


def _draw(rng: np.random.Generator, bounds: tuple[float, float]) -> float:
    return float(rng.uniform(bounds[0], bounds[1]))


def _towel_local(rng: np.random.Generator, cfg: SimConfig) -> np.ndarray:
    ranges = cfg.ranges("towel")
    width = _draw(rng, ranges["long_side"])
    height = width / _draw(rng, ranges["aspect"])
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
    for side in (-1.0, 1.0):   # the viewer's left (the wearer's right, face up), then the viewer's right
        sleeve_length = _draw(rng, ranges["sleeve_length"])
        sleeve_width = _draw(rng, ranges["sleeve_width"])
        angle = _draw(rng, ranges["sleeve_angle"])
        shoulder = np.array([side * shoulder_width / 2, top - drop])
        armpit = np.array([side * body_width / 2, top - drop - armhole])
        along = np.array([side * np.cos(angle), -np.sin(angle)])
        outer = shoulder + sleeve_length * along
        inner = outer + sleeve_width * np.array([-side * np.sin(angle), -np.cos(angle)])
        sides.append((armpit, inner, outer, shoulder))
    (right_armpit, right_inner, right_outer, right_shoulder), (left_armpit, left_inner, left_outer,
                                                               left_shoulder) = sides
    return np.array([[-body_width / 2, bottom], right_armpit, right_inner, right_outer, right_shoulder,
                     left_shoulder, left_outer, left_inner, left_armpit, [body_width / 2, bottom]],
                    dtype=float)


def _shape_local(category: str, rng: np.random.Generator, cfg: SimConfig) -> np.ndarray:
    """The garment's landmarks lying face up in its own frame (m), in `_TRACE` order."""
    if category == "towel":
        return _towel_local(rng, cfg)
    if category == "pants":
        return _pants_local(rng, cfg)
    return _shirt_local(category, rng, cfg)


@dataclass(frozen=True)
class _Border:
    """A traced border: its points, the index of each traced landmark and of each extra node in it."""

    points: np.ndarray
    landmark_index: tuple[int, ...]              # `_TRACE` order
    node_index: dict[str, int]                   # extra nodes (a shirt's neckline) by name


def _ripple_outline(local: np.ndarray, category: str, shape: str, rng: np.random.Generator,
                    cfg: SimConfig, collared: bool = False) -> _Border:
    """The border through the landmarks `local` (`_TRACE` order), every `edges.spacing`, rippled (the
    ripple fades to zero at the landmarks), sleeves and legs bowed, a shirt's neckline dipped (or its
    collar standing above it, `collared`) with the dataset's neckline and collar nodes on it."""
    edges = cfg.edges
    names = _TRACE[category]
    amplitude = edges.wrinkled_amplitude if shape == "wrinkled" else edges.flat_amplitude
    out: list[np.ndarray] = []
    index: list[int] = []
    extra: dict[str, int] = {}
    count = len(local)
    for i in range(count):
        start, end = local[i], local[(i + 1) % count]
        edge = end - start
        length = float(np.linalg.norm(edge))
        steps = max(int(np.ceil(length / edges.spacing)), 2)
        along = np.arange(steps) / steps * length    # excludes the end, which starts the next edge
        normal = np.array([-edge[1], edge[0]]) / max(length, 1e-12)
        waves = [(_draw(rng, edges.wavelength), rng.uniform(0, 2 * np.pi)) for _ in range(2)]
        bow = 0.0
        if frozenset({names[i], names[(i + 1) % count]}) in _BOWED_EDGES[category]:
            bow = rng.uniform(-edges.sleeve_bow, edges.sleeve_bow) * length
        half = depth = 0.0
        if (names[i], names[(i + 1) % count]) == _NECK_EDGE:
            ranges = cfg.ranges(category)
            half = min(_draw(rng, ranges["neck_width"]) / 2.0, 0.4 * length)
            depth = _draw(rng, ranges["neck_depth"])
            # the neckline meets the shoulder line at the dip's (the collar's) ends; the collar's corners
            spread = _draw(rng, edges.collar_corners) if collared else edges.collar_spread
            collar = spread * half
            node_along = length / 2.0 + np.array([-half, -collar, collar, half])
            along = np.sort(np.concatenate([along, node_along]))
            for name, position in zip(SHIRT_NECK_NODES, node_along, strict=True):
                extra[name] = len(out) + int(np.searchsorted(along, position))
        ripple = np.zeros_like(along)
        for wavelength, phase in waves:
            ripple += np.sin(2 * np.pi * along / wavelength + phase)
        ripple *= amplitude / 2.0
        ramp = np.clip(np.minimum(along, length - along) / edges.corner_ramp, 0.0, 1.0)
        ramp = ramp * ramp * (3 - 2 * ramp)          # smoothstep: zero offset and slope at corners
        offset = ripple * ramp + bow * np.sin(np.pi * along / length)
        if depth:
            x = (along - length / 2.0) / half
            if collared:
                # the collar stands `depth` above the neckline, straight across between its corners
                offset = offset + depth * np.clip((1.0 - np.abs(x)) / (1.0 - spread), 0.0, 1.0)
            else:
                # a smooth dip between the shoulders
                offset = offset - depth * np.where(np.abs(x) < 1.0,
                                                   np.cos(np.clip(x, -1, 1) * np.pi / 2) ** 2, 0.0)
        index.append(len(out))
        out.extend(start + (along / length)[:, None] * edge + offset[:, None] * normal)
    return _Border(np.array(out), tuple(index), extra)


def _in_dataset_order(category: str, border: _Border) -> tuple[np.ndarray, tuple[int, ...], tuple[int, ...]]:
    """The border turned to run in the dataset's order from its first landmark (index 0), and the
    indices of the landmarks (`LANDMARKS` order) and of every annotated node (`ANNOTATED_NODES`)."""
    trace = _TRACE[category]
    where = dict(zip(trace, border.landmark_index, strict=True)) | border.node_index
    names = LANDMARKS[category]
    count = len(border.points)
    forward = (trace.index(names[1]) - trace.index(names[0])) % len(trace) == 1
    indices = {name: (i if forward else count - 1 - i) for name, i in where.items()}
    points = border.points if forward else border.points[::-1]
    first = indices[names[0]]
    points = np.roll(points, -first, axis=0)
    indices = {name: (i - first) % count for name, i in indices.items()}
    return (points, tuple(indices[n] for n in names), tuple(indices[n] for n in ANNOTATED_NODES[category]))


def view_bounds(view_polygon: np.ndarray, margin: float) -> tuple[np.ndarray, np.ndarray]:
    lo = view_polygon.min(0) + margin
    hi = view_polygon.max(0) - margin
    return lo, hi


def inside_view(points: np.ndarray, view_polygon: np.ndarray, margin: float) -> bool:
    """Every point inside the camera's view, at least `margin` from its edge (table frame)."""
    view = np.asarray(view_polygon, dtype=float)
    return bool(points_in_polygon(points, view).all()
                and point_segment_distance(points, view)[0].min() >= margin)


def make_garment(category: str, rng: np.random.Generator, cfg: SimConfig, view_polygon: np.ndarray,
                 shape: str | None = None, facing: str = "front",
                 area: tuple[np.ndarray, np.ndarray] | None = None, collared: bool = False) -> Garment:
    """A random garment of `category` lying inside `view_polygon` (table frame, the camera's view),
    face up (`facing="front"`) or face down (`"back"`: the mirror image, names on the wearer's sides);
    a `collared` shirt's collar stands above its neckline.

    Its rotation is drawn uniformly within +-`pose.rotation` (the whole circle at pi). A garment too
    large for the view at its rotation is scaled down to fit, its proportions kept, by no less than
    `pose.min_scale` (else another is drawn). `area` (table frame, low and high corners) confines it
    further, e.g. to where the robot reaches.
    """
    if category not in CATEGORIES:
        raise SimInputError(f"category: must be one of {', '.join(CATEGORIES)}, got {category!r}")
    if facing not in FACINGS:
        raise SimInputError(f"facing: must be one of {', '.join(FACINGS)}, got {facing!r}")
    if shape is None:
        weights = np.array([weight for _, weight in cfg.shape_weights], dtype=float)
        shape = SHAPES[int(rng.choice(len(SHAPES), p=weights / weights.sum()))]
    if shape not in SHAPES:
        raise SimInputError(f"shape: must be one of {', '.join(SHAPES)}, got {shape!r}")
    lo_view, hi_view = view_bounds(np.asarray(view_polygon, dtype=float), cfg.pose.view_margin)
    if area is not None:
        lo_view, hi_view = np.maximum(lo_view, area[0]), np.minimum(hi_view, area[1])
        if np.any(hi_view <= lo_view):
            raise SimInputError("area: does not overlap the camera view (check config/sim.yaml pose)")
    room = hi_view - lo_view
    # face down, the viewer sees the face-up shape mirrored across the garment's vertical axis
    mirror = np.array([-1.0, 1.0]) if facing == "back" else np.ones(2)
    for attempt in range(cfg.pose.attempts):
        # a turn is kept while garments are drawn for it (redrawing it whenever one does not fit
        # would favour the turns that fit the view best); one no garment fits is given up
        if attempt % cfg.pose.place_attempts == 0:
            theta = float(rng.uniform(-cfg.pose.rotation, cfg.pose.rotation))
            cos, sin = np.cos(theta), np.sin(theta)
            rotation = np.array([[cos, -sin], [sin, cos]]) @ _GARMENT_TO_TABLE
        local = _shape_local(category, rng, cfg)
        if segments_intersect(local):
            continue
        outline_local, landmark_index, node_index = _in_dataset_order(
            category, _ripple_outline(local, category, shape, rng, cfg, collared))
        placed = (outline_local * mirror) @ rotation.T
        scale = min(1.0, float(np.min(room / (placed.max(0) - placed.min(0)))))
        if scale < cfg.pose.min_scale:
            continue
        placed = placed * scale
        lo = lo_view - placed.min(0)
        hi = hi_view - placed.max(0)
        # the view is no rectangle on the table: a place in its bounding box may reach past it
        for _ in range(cfg.pose.place_attempts):
            centre = rng.uniform(lo, np.maximum(hi, lo))
            outline = placed + centre
            if inside_view(outline, view_polygon, cfg.pose.view_margin):
                break
        else:
            continue
        landmarks = outline[list(landmark_index)].copy()
        return Garment(category=category, shape=shape, facing=facing, names=LANDMARKS[category],
                       landmarks=landmarks, outline=outline, landmark_index=landmark_index,
                       node_names=ANNOTATED_NODES[category], node_index=node_index, rotation=theta,
                       scale=scale, centre=centre)
    raise SimInputError(f"category: no {category} of the configured sizes fits the camera view "
                        f"after {cfg.pose.attempts} attempts (check config/sim.yaml garments and pose)")


# --- the planner's samples -------------------------------------------------------------------------
# A typical adult garment of each category lying face up in its own frame (m), scaled to the 0.8 m x
# 1.2 m table
_TYPICAL: dict[str, dict[str, tuple[float, float]]] = {
    "towel": {"bottom-left": (0.25, -0.18), "bottom-right": (-0.25, -0.18), "top-right": (-0.25, 0.18),
              "top-left": (0.25, 0.18)},
    "pants": {"left-leg-outer": (0.24, -0.40), "left-leg-inner": (0.05, -0.40), "crotch": (0.0, 0.12),
              "right-leg-inner": (-0.05, -0.40), "right-leg-outer": (-0.24, -0.40),
              "top-right": (-0.19, 0.40), "top-left": (0.19, 0.40)},
    "short-sleeve": {"bottom-left": (0.22, -0.30), "bottom-right": (-0.22, -0.30),
                     "right-armpit": (-0.22, 0.12), "right-sleeve-inner": (-0.34, 0.02),
                     "right-sleeve-outer": (-0.42, 0.14), "right-shoulder": (-0.19, 0.30),
                     "left-shoulder": (0.19, 0.30), "left-sleeve-outer": (0.42, 0.14),
                     "left-sleeve-inner": (0.34, 0.02), "left-armpit": (0.22, 0.12)},
    "long-sleeve": {"bottom-left": (0.22, -0.30), "bottom-right": (-0.22, -0.30),
                    "right-armpit": (-0.22, 0.12), "right-sleeve-inner": (-0.30, -0.28),
                    "right-sleeve-outer": (-0.40, -0.24), "right-shoulder": (-0.19, 0.30),
                    "left-shoulder": (0.19, 0.30), "left-sleeve-outer": (0.40, -0.24),
                    "left-sleeve-inner": (0.30, -0.28), "left-armpit": (0.22, 0.12)},
}
# the samples list the landmarks in model order (`LANDMARKS`) from this one, as they always have
_SAMPLE_FIRST = {"towel": "top-right", "pants": "top-right", "short-sleeve": "bottom-right",
                 "long-sleeve": "bottom-right"}


def _template(category: str) -> list[tuple[str, float, float]]:
    names = LANDMARKS[category]
    first = names.index(_SAMPLE_FIRST[category])
    return [(name, *_TYPICAL[category][name]) for name in names[first:] + names[:first]]


# category -> (name, x, y) of the typical garment lying face up (garment frame, m), in model order
TEMPLATES: dict[str, list[tuple[str, float, float]]] = {category: _template(category)
                                                         for category in CATEGORIES}

# Long garments lie along the table's width: pants' top points along +y.
_SAMPLE_BASE_ANGLE = {"pants": np.pi / 2}
# Scale ranges so that each garment fits the reachable part of the table.
_SAMPLE_SCALE = {"towel": (0.9, 1.05), "pants": (0.85, 0.95), "short-sleeve": (0.7, 0.8),
                 "long-sleeve": (0.7, 0.8)}
# Pants are long for the table: less freedom to turn.
_SAMPLE_MAX_ROTATION = {"pants": np.pi / 12}


def place_garment(category: str, table: TableConfig, rng: np.random.Generator, margin: float = 0.04,
                  max_rotation: float | None = None, scale_range: tuple[float, float] | None = None,
                  reach_radius: float | None = None, attempts: int = 5000) -> dict[str, tuple[float, float]]:
    """The typical garment's landmarks (`TEMPLATES`, table frame, m) placed at random: its top pointing
    away from the robot, or along the table for pants, turned by up to +-max_rotation (default per
    category); random scale and position, lying on the table with `margin` and, if `reach_radius` is
    given, within that distance of the turn-table axis."""
    scale_range = scale_range or _SAMPLE_SCALE.get(category, (0.9, 1.0))
    if max_rotation is None:
        max_rotation = _SAMPLE_MAX_ROTATION.get(category, np.pi / 6)
    tpl = TEMPLATES[category]
    names = [t[0] for t in tpl]
    base = np.array([[t[1], t[2]] for t in tpl])
    for _ in range(attempts):
        ang = rng.uniform(-max_rotation, max_rotation) + _SAMPLE_BASE_ANGLE.get(category, 0.0)
        s = rng.uniform(*scale_range)
        c, si = np.cos(ang), np.sin(ang)
        local = base @ _GARMENT_TO_TABLE.T * s
        rot = local @ np.array([[c, si], [-si, c]])
        centre = np.array([rng.uniform(0, table.size_x), rng.uniform(0, table.size_y)])
        pts = rot + centre
        inside = bool(np.all(table.contains(pts, margin)))
        if inside and reach_radius is not None:
            inside = bool(np.all(np.linalg.norm(table.table_to_world(pts)[:, :2], axis=1) <= reach_radius))
        if inside:
            return {n: (float(p[0]), float(p[1])) for n, p in zip(names, pts, strict=True)}
    raise ValueError(f"could not place a {category} on the table")
