"""The folding table: its size and the `table` frame in `world`."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from drivers.common.configfile import config_dir, load_fields, load_yaml, rule


@dataclass(frozen=True)
class TableConfig:
    size_x: float = rule(positive=True)
    size_y: float = rule(positive=True)
    height: float = rule(positive=True)
    thickness: float = rule(positive=True)
    near_edge_x: float = rule(min=0.0)

    @property
    def origin_in_world(self) -> np.ndarray:
        """Position of the `table` frame origin (a top corner) in `world`; axes are parallel."""
        return np.array([self.near_edge_x, -self.size_y / 2.0, self.height])

    def table_to_world(self, points_xy: np.ndarray) -> np.ndarray:
        """(N, 2) points on the table top in the `table` frame to (N, 3) in `world`."""
        pts = np.atleast_2d(np.asarray(points_xy, dtype=float))
        return np.column_stack([pts[:, 0], pts[:, 1], np.zeros(len(pts))]) + self.origin_in_world

    def world_to_table(self, points: np.ndarray) -> np.ndarray:
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        return (pts - self.origin_in_world)[:, :2]

    def contains(self, points_xy: np.ndarray, margin: float = 0.0) -> np.ndarray:
        pts = np.atleast_2d(np.asarray(points_xy, dtype=float))
        return ((pts[:, 0] >= margin) & (pts[:, 0] <= self.size_x - margin)
                & (pts[:, 1] >= margin) & (pts[:, 1] <= self.size_y - margin))


def load_table_config(path: str | Path | None = None) -> TableConfig:
    path = Path(path) if path else config_dir() / "table.yaml"
    return load_fields(TableConfig, load_yaml(path))


@lru_cache(maxsize=1)
def default_table_config() -> TableConfig:
    return load_table_config()
