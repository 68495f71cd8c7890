"""Synthetic flat garments on the table (landmarks in the `table` frame), for tests, the bench and
`foldcell plan check`. Shapes are typical adult sizes scaled to the 0.8 m x 1.2 m table; the vertex
order is the polygonal models' order (clockwise on screen)."""

from __future__ import annotations

import numpy as np

from drivers.robot.table import TableConfig

# Upright garment lying face up, x to the viewer's right, y towards the garment's top (m), model order
# (names on the wearer's sides: the wearer's left on the viewer's right).
TEMPLATES: dict[str, list[tuple[str, float, float]]] = {
    "towel": [("top-right", -0.25, 0.18), ("top-left", 0.25, 0.18), ("bottom-left", 0.25, -0.18),
              ("bottom-right", -0.25, -0.18)],
    "pants": [("top-right", -0.19, 0.40), ("top-left", 0.19, 0.40), ("left-leg-outer", 0.24, -0.40),
              ("left-leg-inner", 0.05, -0.40), ("crotch", 0.0, 0.12), ("right-leg-inner", -0.05, -0.40),
              ("right-leg-outer", -0.24, -0.40)],
    "short-sleeve": [("bottom-right", -0.22, -0.30), ("right-armpit", -0.22, 0.12),
                     ("right-sleeve-inner", -0.34, 0.02), ("right-sleeve-outer", -0.42, 0.14),
                     ("right-shoulder", -0.19, 0.30), ("left-shoulder", 0.19, 0.30),
                     ("left-sleeve-outer", 0.42, 0.14), ("left-sleeve-inner", 0.34, 0.02),
                     ("left-armpit", 0.22, 0.12), ("bottom-left", 0.22, -0.30)],
    "long-sleeve": [("bottom-right", -0.22, -0.30), ("right-armpit", -0.22, 0.12),
                    ("right-sleeve-inner", -0.30, -0.28), ("right-sleeve-outer", -0.40, -0.24),
                    ("right-shoulder", -0.19, 0.30), ("left-shoulder", 0.19, 0.30),
                    ("left-sleeve-outer", 0.40, -0.24), ("left-sleeve-inner", 0.30, -0.28),
                    ("left-armpit", 0.22, 0.12), ("bottom-left", 0.22, -0.30)],
}

# Long garments lie along the table's width: pants' top points along +y.
BASE_ANGLE = {"pants": np.pi / 2}
# Scale ranges so that each garment fits the reachable part of the table.
SCALE = {"towel": (0.9, 1.05), "pants": (0.85, 0.95), "short-sleeve": (0.7, 0.8), "long-sleeve": (0.7, 0.8)}
# Pants are long for the table: less freedom to turn.
MAX_ROTATION = {"pants": np.pi / 12}


def place_garment(category: str, table: TableConfig, rng: np.random.Generator, margin: float = 0.04,
                  max_rotation: float | None = None, scale_range: tuple[float, float] | None = None,
                  reach_radius: float | None = None, attempts: int = 5000) -> dict[str, tuple[float, float]]:
    """A random placement (the garment's top pointing away from the robot, or along the table for
    pants, turned by up to +-max_rotation (default per category); random scale and position) lying on
    the table with `margin` and, if `reach_radius` is given, within that distance of the turn-table axis."""
    scale_range = scale_range or SCALE.get(category, (0.9, 1.0))
    if max_rotation is None:
        max_rotation = MAX_ROTATION.get(category, np.pi / 6)
    tpl = TEMPLATES[category]
    names = [t[0] for t in tpl]
    base = np.array([[t[1], t[2]] for t in tpl])
    for _ in range(attempts):
        # upright garment's top points along table +x (away from the robot), its right along -y
        ang = rng.uniform(-max_rotation, max_rotation) + BASE_ANGLE.get(category, 0.0)
        s = rng.uniform(*scale_range)
        c, si = np.cos(ang), np.sin(ang)
        local = np.column_stack([base[:, 1], -base[:, 0]]) * s     # (top, right) -> (x, -y)
        rot = local @ np.array([[c, si], [-si, c]])
        centre = np.array([rng.uniform(0, table.size_x), rng.uniform(0, table.size_y)])
        pts = rot + centre
        inside = bool(np.all(table.contains(pts, margin)))
        if inside and reach_radius is not None:
            inside = bool(np.all(np.linalg.norm(table.table_to_world(pts)[:, :2], axis=1) <= reach_radius))
        if inside:
            return {n: (float(p[0]), float(p[1])) for n, p in zip(names, pts, strict=True)}
    raise ValueError(f"could not place a {category} on the table")


__all__ = ["TEMPLATES", "place_garment"]
