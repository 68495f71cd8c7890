"""Measuring a fold in the cloth physics: a square folded in half along the planner's triangular path,
its final silhouette against the ideal half."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from drivers.sim.physics.cloth import ClothWorld, iou, polygon_mask, rectangle
from drivers.sim.physics.config import PhysicsConfig
from drivers.sim.physics.mesh import cut_mesh


@dataclass(frozen=True)
class HalfFold:
    lift_fraction: float
    iou: float                # final silhouette against the ideal half
    wall_time: float          # s to simulate the fold
    simulated_time: float     # s simulated


def fold_square_in_half(side: float, lift_fraction: float, config: PhysicsConfig, *,
                        grasp_inset: float, grasp_height: float) -> HalfFold:
    """Fold a `side` square centred at the origin bottom (-y) onto top (+y): both grippers close
    `grasp_inset` inside the bottom corners and place on their mirror images across y = 0, as the
    planner does (its grasp `depth` and `height`)."""
    half = side / 2.0
    grasps = np.array([[-half + grasp_inset, -half + grasp_inset], [half - grasp_inset, -half + grasp_inset]])
    places = grasps * np.array([1.0, -1.0])
    world = ClothWorld(cut_mesh(rectangle(side, side), config.cloth.vertex_spacing), config)
    start = time.perf_counter()
    result = world.fold(grasps, places, lift_fraction, grasp_height)
    wall_time = time.perf_counter() - start
    silhouette = world.silhouette((-side, -side), (2 * side, 2 * side))
    ideal = polygon_mask(np.array([[-half, 0.0], [half, 0.0], [half, half], [-half, half]]), silhouette)
    return HalfFold(lift_fraction, iou(silhouette.mask, ideal), wall_time, result.simulated_time)
