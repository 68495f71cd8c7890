"""Folding physics on the table plane: a garment is a stack of planar layers.

A fold along a line lifts, in the layers it takes, the part on the moving side, reflects it across the
line and lays it on top (the moved stack turned over, so its top layer comes to lie lowest). Landmarks
of the folded state follow the shared convention (paper Sec. III-F): the moving part's vertices are
replaced by the fold endpoints F (`fold<s>-from`) and T (`fold<s>-to`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from drivers.common.plane import FoldLine, mask_iou, signed_area
from drivers.sim.geometry import clip_halfplane, is_clockwise

_MIN_LAYER_AREA = 1e-8   # m^2; slivers smaller than this are dropped


@dataclass(frozen=True)
class Layer:
    """One planar layer: its outline in the table frame and whether the garment's inside faces up."""

    polygon: np.ndarray
    flipped: bool = False


def fold_layers(layers: Sequence[Layer], line: FoldLine, select: Sequence[int] | None = None) -> list[Layer]:
    """Fold the layers `select` (indices, default all) across `line`; returns the new stack, bottom first."""
    chosen = set(range(len(layers)) if select is None else select)
    stay: list[Layer] = []
    moved: list[Layer] = []
    for i, layer in enumerate(layers):
        if i not in chosen:
            stay.append(layer)
            continue
        keep = clip_halfplane(layer.polygon, line, keep_positive=False)
        move = clip_halfplane(layer.polygon, line, keep_positive=True)
        if len(keep) >= 3 and abs(signed_area(keep)) > _MIN_LAYER_AREA:
            stay.append(Layer(keep, layer.flipped))
        if len(move) >= 3 and abs(signed_area(move)) > _MIN_LAYER_AREA:
            moved.append(Layer(line.reflect(move), not layer.flipped))
    return stay + moved[::-1]


def crumpled_fold_layers(layers: Sequence[Layer], moves: Sequence[tuple[np.ndarray, np.ndarray]],
                         crumple: float, noise: float, rng: np.random.Generator) -> list[Layer]:
    """A fold whose grippers disagree on the line: each moved point follows a blend of the grippers'
    reflections (by where it lies between them), shrunk towards the moved part's centre and jittered."""
    lines = [FoldLine.from_move(g, p) for g, p in moves]
    mean = average_line(lines)
    grasps = np.array([g for g, _ in moves], dtype=float)
    axis = grasps[-1] - grasps[0]
    span = max(float(axis @ axis), 1e-12)
    stay: list[Layer] = []
    moved: list[Layer] = []
    for layer in layers:
        keep = clip_halfplane(layer.polygon, mean, keep_positive=False)
        move = clip_halfplane(layer.polygon, mean, keep_positive=True)
        if len(keep) >= 3 and abs(signed_area(keep)) > _MIN_LAYER_AREA:
            stay.append(Layer(keep, layer.flipped))
        if len(move) >= 3 and abs(signed_area(move)) > _MIN_LAYER_AREA:
            w = np.clip(((move - grasps[0]) @ axis) / span, 0.0, 1.0)[:, None]
            r = (1.0 - w) * lines[0].reflect(move) + w * lines[-1].reflect(move)
            centre = r.mean(0)
            r = centre + (1.0 - crumple) * (r - centre) + rng.normal(0.0, noise, size=r.shape)
            moved.append(Layer(r, not layer.flipped))
    return stay + moved[::-1]


def average_line(lines: Sequence[FoldLine]) -> FoldLine:
    n = np.sum([ln.normal for ln in lines], axis=0)
    norm = float(np.linalg.norm(n))
    if norm < 1e-9:
        raise ValueError("moves: the fold lines point in opposite directions")
    return FoldLine(point=np.mean([ln.point for ln in lines], axis=0), normal=n / norm)


def lines_agree(lines: Sequence[FoldLine], max_angle: float, max_offset: float) -> bool:
    """Whether several grippers' moves imply one fold line within the tolerances."""
    for a in lines[1:]:
        b = lines[0]
        ang = float(np.arccos(np.clip(a.normal @ b.normal, -1.0, 1.0)))
        if ang > max_angle:
            return False
        if abs(float(b.side(a.point)[0])) > max_offset or abs(float(a.side(b.point)[0])) > max_offset:
            return False
    return True


def fold_line_of_moves(moves: Sequence[tuple[np.ndarray, np.ndarray]]) -> FoldLine:
    """The common fold line of one fold's moves (grasp, place): the mean of their bisectors."""
    return average_line([FoldLine.from_move(g, p) for g, p in moves])


def fold_landmarks(names: Sequence[str], points: np.ndarray, line: FoldLine, fold_number: int,
                   merge_distance: float) -> tuple[list[str], np.ndarray]:
    """The folded polygon's landmarks by the shared convention (see module docstring).

    The result keeps the input's orientation (a counter-clockwise towel stays counter-clockwise).
    """
    pts = np.asarray(points, dtype=float)
    names = list(names)
    reverse = not is_clockwise(pts)
    if reverse:
        pts, names = pts[::-1], names[::-1]
    s = line.side(pts)
    moving = s > 0
    if not moving.any():
        out_n, out_p = names, pts
    elif moving.all():
        out_n, out_p = names, line.reflect(pts)
    else:
        n = len(pts)
        out_names: list[str] = []
        out_pts: list[np.ndarray] = []
        cuts: list[int] = []          # indices in the output of F and T
        run = 0
        start = int(np.argmax(~moving))   # begin at a stationary vertex
        for k in range(n):
            i = (start + k) % n
            j = (i + 1) % n
            if not moving[i]:
                out_names.append(names[i])
                out_pts.append(pts[i])
            if moving[i] != moving[j]:
                t = s[i] / (s[i] - s[j])
                x = pts[i] + t * (pts[j] - pts[i])
                if not moving[i]:
                    run += 1
                    suffix = "" if run == 1 else f"-{run}"
                    out_names.append(f"fold{fold_number}-from{suffix}")
                else:
                    suffix = "" if run <= 1 else f"-{run}"
                    out_names.append(f"fold{fold_number}-to{suffix}")
                out_pts.append(x)
                cuts.append(len(out_pts) - 1)
        p = np.array(out_pts)
        keep = np.ones(len(p), dtype=bool)
        cut_pts = p[cuts]
        for i in range(len(p)):
            if i not in cuts and np.min(np.linalg.norm(cut_pts - p[i], axis=1)) < merge_distance:
                keep[i] = False
        out_n = [nm for nm, k in zip(out_names, keep, strict=True) if k]
        out_p = p[keep]
    if reverse:
        out_n, out_p = out_n[::-1], out_p[::-1]
    return list(out_n), np.array(out_p)


def union_mask(polygons: Sequence[np.ndarray], origin: np.ndarray, resolution: float,
               shape: tuple[int, int]) -> np.ndarray:
    """Rasterise the union of table-frame polygons on a grid (row = y, column = x) as uint8 0/1."""
    mask = np.zeros(shape, dtype=np.uint8)
    for poly in polygons:
        px = np.round((np.asarray(poly) - origin) / resolution * 16).astype(np.int32)
        cv2.fillPoly(mask, [px.reshape(-1, 1, 2)], 1, lineType=cv2.LINE_8, shift=4)
    return mask


def _grid(polygon_sets: Sequence[Sequence[np.ndarray]], resolution: float) -> tuple[np.ndarray, tuple[int,
                                                                                                      int]]:
    allpts = np.vstack([np.asarray(p) for ps in polygon_sets for p in ps])
    lo = allpts.min(0) - 4 * resolution
    hi = allpts.max(0) + 4 * resolution
    size = np.ceil((hi - lo) / resolution).astype(int) + 1
    return lo, (int(size[1]), int(size[0]))


def area_of_union(polygons: Sequence[np.ndarray], resolution: float) -> float:
    origin, shape = _grid([polygons], resolution)
    return float(union_mask(polygons, origin, resolution, shape).sum()) * resolution * resolution


def iou(polys_a: Sequence[np.ndarray], polys_b: Sequence[np.ndarray], resolution: float) -> float:
    """Intersection over union of two sets of table-frame polygons (each set united)."""
    origin, shape = _grid([polys_a, polys_b], resolution)
    a = union_mask(polys_a, origin, resolution, shape).astype(bool)
    b = union_mask(polys_b, origin, resolution, shape).astype(bool)
    return mask_iou(a, b, empty=1.0)


def outline_of_union(polygons: Sequence[np.ndarray], resolution: float) -> np.ndarray:
    """The outer outline of the union (largest external contour), table frame, clockwise from above."""
    origin, shape = _grid([polygons], resolution)
    mask = union_mask(polygons, origin, resolution, shape)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return np.zeros((0, 2))
    c = max(contours, key=cv2.contourArea).reshape(-1, 2).astype(float)
    out = c * resolution + origin
    return out[::-1] if not is_clockwise(out) else out


def recipe_moves(category: str, lm: dict[str, np.ndarray]) -> list[list[tuple[np.ndarray, np.ndarray]]]:
    """The two-arm folds (grasp, place moves; table frame) of the paper's recipes on a flat garment's
    landmarks `lm`, named as the cell names them (a garment lying face down is folded as its mirror
    image): the folds of `config/garments/*.yaml` written out here, because the sim knows no planner."""
    folds: list[list[tuple[np.ndarray, np.ndarray]]] = []

    def mid(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return (a + b) / 2.0

    if category == "towel":
        bl, br, tr, tl = lm["bottom-left"], lm["bottom-right"], lm["top-right"], lm["top-left"]
        folds.append([(bl, tl), (br, tr)])                         # bottom onto top
        ml, mr = mid(bl, tl), mid(br, tr)
        folds.append([(ml, mr), (tl, tr)])                         # then left onto right
    elif category == "pants":
        lo, ro, tl, tr = lm["left-leg-outer"], lm["right-leg-outer"], lm["top-left"], lm["top-right"]
        folds.append([(lo, ro), (tl, tr)])                         # left leg onto right leg
        folds.append([(ro, tr), (mid(lo, ro), mid(tl, tr))])       # hems onto the waist
    else:
        bl, br = lm["bottom-left"], lm["bottom-right"]
        ls, rs = lm["left-shoulder"], lm["right-shoulder"]
        # a side with its sleeve onto the back, the fold line a quarter of the body in from the side
        left_line = (bl + (br - bl) * 0.25, ls + (rs - ls) * 0.25)
        right_line = (bl + (br - bl) * 0.75, ls + (rs - ls) * 0.75)
        for (line_start, line_end), bottom, shoulder in ((left_line, bl, ls), (right_line, br, rs)):
            along = (line_end - line_start) / np.linalg.norm(line_end - line_start)
            moves = []
            for grasp in (bottom, shoulder):
                foot = line_start + ((grasp - line_start) @ along) * along
                moves.append((grasp, 2 * foot - grasp))    # its mirror image across the line
            folds.append(moves)
        up = (ls + rs) / 2.0 - (bl + br) / 2.0
        quarter, three_quarters = bl + (br - bl) * 0.25, bl + (br - bl) * 0.75
        # bottom onto top
        folds.append([(quarter, quarter + up * 0.95), (three_quarters, three_quarters + up * 0.95)])
    return folds
