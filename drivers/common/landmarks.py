"""A garment's named landmarks in one stated frame: what perception finds, planning folds by, the
fold check expects and the simulated world knows as the truth."""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

TABLE = "table"   # the table frame, metres (x to the robot's right, y away from it)
IMAGE = "image"   # an image's pixels (x right, y down)
FRAMES = (TABLE, IMAGE)


class Landmarks(Mapping[str, tuple[float, float]]):
    """Name -> (x, y) in `frame`, in the order given. Read as a mapping; `array()` gives the points
    as an (N, 2) array, in the order of the names asked for."""

    __slots__ = ("frame", "names", "points")

    def __init__(self, frame: str, names: Sequence[str], points: ArrayLike):
        if frame not in FRAMES:
            raise ValueError(f"landmarks: frame must be one of {', '.join(FRAMES)}, got {frame!r}")
        names = tuple(str(n) for n in names)
        xy = np.array(points, dtype=float).reshape(-1, 2) if len(names) else np.zeros((0, 2))
        if xy.shape != (len(names), 2):
            raise ValueError(f"landmarks: {len(names)} names need ({len(names)}, 2) points, got {xy.shape}")
        if len(set(names)) != len(names):
            raise ValueError(f"landmarks: a name is given twice in {', '.join(names)}")
        if not np.isfinite(xy).all():
            raise ValueError("landmarks: a point is not finite")
        xy.setflags(write=False)
        self.frame, self.names, self.points = frame, names, xy

    @staticmethod
    def of(frame: str, named: Mapping[str, ArrayLike]) -> Landmarks:
        """From a mapping of name -> (x, y) (a Landmarks of that frame comes back as it is)."""
        if isinstance(named, Landmarks):
            return named.require(frame)
        return Landmarks(frame, list(named), [np.asarray(p, dtype=float)[:2] for p in named.values()])

    def __getitem__(self, name: str) -> tuple[float, float]:
        try:
            x, y = self.points[self.names.index(name)]
        except ValueError:
            raise KeyError(name) from None
        return float(x), float(y)

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def __len__(self) -> int:
        return len(self.names)

    def array(self, names: Sequence[str] | None = None) -> NDArray[np.float64]:
        """(N, 2) points of `names` (default: all), in that order."""
        if names is None:
            return self.points.copy()
        return np.array([self[n] for n in names], dtype=float).reshape(-1, 2)

    def require(self, frame: str) -> Landmarks:
        """These landmarks, which must be in `frame` (ValueError naming both otherwise)."""
        if self.frame != frame:
            raise ValueError(f"landmarks: in the {self.frame} frame, {frame} needed")
        return self

    def __repr__(self) -> str:
        shown = ", ".join(f"{n}=({x:.4g}, {y:.4g})" for n, (x, y) in self.items())
        return f"Landmarks({self.frame}: {shown})"
