"""Exceptions of the planning layer: one family, each naming what failed and why."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class PlanningError(RuntimeError):
    """Planning failed; the message says what to check."""


class Unreachable(PlanningError):
    """A table point cannot be reached: IK, collision or limits. Carries the point (table frame, m)."""

    def __init__(self, point_xy: Sequence[float] | np.ndarray, reason: str, what: str = "point"):
        self.point = (float(point_xy[0]), float(point_xy[1]))
        self.reason = reason
        self.what = what
        super().__init__(
            f"unreachable {what} at table ({self.point[0]:.3f}, {self.point[1]:.3f}) m: {reason}")


class InvalidTrajectory(PlanningError):
    """A trajectory breaks a rule of the controller (names, limits, timing, size)."""


class PlanningInputError(ValueError):
    """Bad input to the planner (landmarks, fold index, joint vector); names the argument."""


__all__ = ["InvalidTrajectory", "PlanningError", "PlanningInputError", "Unreachable"]
