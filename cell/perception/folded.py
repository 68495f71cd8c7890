"""Folded polygons and folded models (paper Sec. III-F), by the shared fold convention.

A fold moves the grasped point G to the place point P. The fold line is the perpendicular
bisector of G->P; the part of the garment on G's side moves. Walking the outline clockwise, F is
where it crosses the line entering the moving part and T where it leaves. The folded outline is
the stationary vertices in order, with the moving vertices removed and F then T put in their
place; stationary vertices closer than `merge_distance` to F or T are removed (merged into them).
F is named `fold<s>-from` and T `fold<s>-to`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from drivers.common.plane import perimeter

from .errors import ModelError
from .geometry import make_clockwise, polygon_angles, relative_edge_lengths
from .models import PolygonalModel


def fold_names(fold_index: int) -> tuple[str, str]:
    return f"fold{fold_index}-from", f"fold{fold_index}-to"


def folded_polygon(polygon: NDArray, names: Sequence[str], grasp: Sequence[float], place: Sequence[float],
                   fold_index: int, merge_distance: float) -> tuple[NDArray, tuple[str, ...]]:
    """The outline after folding G onto P, and its vertex names (clockwise)."""
    poly = np.asarray(polygon, float)
    if len(poly) != len(names):
        raise ModelError(f"polygon has {len(poly)} vertices but {len(names)} names")
    if fold_index < 1:
        raise ModelError(f"fold_index must be >= 1, got {fold_index}")
    poly, reversed_ = make_clockwise(poly)
    vertex_names = list(names)[::-1] if reversed_ else list(names)
    G, P = np.asarray(grasp, float), np.asarray(place, float)
    step = P - G
    dist = float(np.linalg.norm(step))
    if dist <= 0:
        raise ModelError("grasp and place points coincide: no fold line")
    direction = step / dist
    mid = 0.5 * (G + P)
    side = (poly - mid) @ direction      # < 0: on G's side, moves
    moving = side < 0
    n = len(poly)
    if moving.all():
        raise ModelError("the fold line leaves the whole garment on the grasp side: nothing stays")
    if not moving.any():
        raise ModelError("the fold line does not cross the garment: nothing moves")
    # start the walk at a stationary vertex so the moving part is one block of the walk
    start = int(np.flatnonzero(~moving)[0])
    order = [(start + t) % n for t in range(n)]
    moving_in_walk = moving[order]
    moving_at = np.flatnonzero(moving_in_walk)
    if moving_at[-1] - moving_at[0] + 1 != len(moving_at):
        raise ModelError("the fold line crosses the outline more than twice; only single-part folds "
                         "are supported")
    first_moving, last_moving = int(moving_at[0]), int(moving_at[-1])   # positions in `order`
    a, b = order[first_moving - 1], order[first_moving]    # stationary -> moving edge
    c, d = order[last_moving], order[(last_moving + 1) % n]  # moving -> stationary edge

    def cross(i: int, j: int) -> NDArray:
        t = side[i] / (side[i] - side[j])
        return poly[i] + t * (poly[j] - poly[i])

    F, T = cross(a, b), cross(c, d)
    stationary = [order[q] for q in range(n) if not moving_in_walk[q]]
    # stationary vertices in order, starting after T so F, T land at the end
    after_t = stationary.index(d)
    stationary = stationary[after_t:] + stationary[:after_t]
    keep = [i for i in stationary if np.linalg.norm(poly[i] - F) >= merge_distance
            and np.linalg.norm(poly[i] - T) >= merge_distance]
    out = [poly[i] for i in keep] + [F, T]
    from_name, to_name = fold_names(fold_index)
    out_names = [vertex_names[i] for i in keep] + [from_name, to_name]
    return np.asarray(out), tuple(out_names)


def derive_folded_model(model: PolygonalModel, matched_polygon_px: NDArray,
                        move_px: tuple[Sequence[float], Sequence[float]], fold_index: int,
                        merge_fraction: float = 0.02) -> PolygonalModel:
    """The model to match after the fold `move_px` = (G, P) of the garment matched as given.

    `matched_polygon_px` holds the matched landmark of each model vertex, in model order. Means
    are measured on the folded polygon; variances are the smallest learned ones of the model,
    twice that next to the new vertices F and T (paper Sec. III-F).
    """
    pts = np.asarray(matched_polygon_px, float)
    if pts.shape != (model.size, 2):
        raise ModelError(f"matched polygon must be ({model.size}, 2) for model {model.category!r}, "
                         f"got {pts.shape}")
    poly, names = folded_polygon(pts, model.names, move_px[0], move_px[1], fold_index,
                                 merge_fraction * perimeter(pts))
    if len(poly) < 3:
        raise ModelError("the folded outline has fewer than 3 vertices")
    new = np.array([name in fold_names(fold_index) for name in names])
    a_var, l_var = min(model.angle_var), min(model.length_var)
    m = len(poly)
    angle_var = tuple(2 * a_var if new[i] else a_var for i in range(m))
    # edge i joins vertex i and i+1: adjacent to a new vertex if either end is new
    length_var = tuple(2 * l_var if (new[i] or new[(i + 1) % m]) else l_var for i in range(m))
    return PolygonalModel(
        model.category, names, tuple(float(v) for v in polygon_angles(poly)), angle_var,
        tuple(float(v) for v in relative_edge_lengths(poly)), length_var,
        tuple(range(m)), tuple(range(m)), max(model.simplify_vertices, m))


def group_moves(moves: Sequence[Sequence[float]], angle_tolerance: float = 0.1,
                offset_tolerance_px: float = 40.0) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """One (G, P) per fold from CloPeMa `moves` ([x1, y1, x2, y2] each, in order).

    Consecutive moves whose fold lines (perpendicular bisectors) agree within the tolerances
    are one two-arm fold; its (G, P) is the mean of their grasp and place points.
    """
    groups: list[list[tuple[NDArray, NDArray]]] = []
    last: tuple[NDArray, float] | None = None    # the last fold line: its normal and offset
    for move in moves:
        if len(move) != 4:
            raise ModelError(f"move {list(move)}: must be [x1, y1, x2, y2]")
        grasp, place = np.asarray(move[:2], float), np.asarray(move[2:4], float)
        length = float(np.linalg.norm(place - grasp))
        if length <= 0:
            raise ModelError(f"move {list(move)}: grasp and place coincide")
        normal = (place - grasp) / length
        offset = float(normal @ (0.5 * (grasp + place)))
        if (last is not None and float(normal @ last[0]) >= np.cos(angle_tolerance)
                and abs(offset - last[1]) <= offset_tolerance_px):
            groups[-1].append((grasp, place))
            continue
        groups.append([(grasp, place)])
        last = (normal, offset)
    out = []
    for group in groups:
        grasp = np.mean([pair[0] for pair in group], axis=0)
        place = np.mean([pair[1] for pair in group], axis=0)
        out.append(((float(grasp[0]), float(grasp[1])), (float(place[0]), float(place[1]))))
    return out
