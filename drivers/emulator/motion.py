"""A trajectory the emulator has accepted, prepared for per-tick Hermite interpolation."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drivers.controller.trajectory import FloatArray, JointTrajectory, hermite_coefficients

IntArray = NDArray[np.int_]


@dataclass(frozen=True)
class PreparedTrajectory:
    """An accepted trajectory with its Hermite coefficients per segment, ready for per-tick evaluation.

    It holds the whole path of a coordinated motion (every joint the master and the slave move
    together, `joint_names`); `columns` picks the joints of the controller that runs it. Evaluating the
    whole path lets each controller compute the same stop profile (`drivers.emulator.core`).
    """

    joint_names: tuple[str, ...]  # the path's joints
    times: FloatArray  # (K,)
    positions: FloatArray  # (K, n) over the path's joints
    velocities: FloatArray  # (K, n)
    a1: FloatArray  # (K-1, n) acceleration at each segment start
    a2: FloatArray  # (K-1, n) jerk of each segment
    columns: IntArray  # this controller's joints within the path's, in its order
    start_tick: int | None  # not before this interpolation tick; None: pre-loaded, waits for a release
    ident: int = 0  # the controller's id of the accepted trajectory

    @staticmethod
    def build(trajectory: JointTrajectory, start_tick: int | None, ident: int = 0,
              joints: Sequence[str] | None = None) -> PreparedTrajectory:
        """`joints`: the controller's joints (default: all of the trajectory's), each in the path."""
        names = tuple(trajectory.joint_names)
        own = names if joints is None else tuple(joints)
        missing = [j for j in own if j not in names]
        if missing:
            raise ValueError(f"joint_names: the path lacks {missing[0]!r}")
        columns = np.array([names.index(j) for j in own], dtype=int)
        times = np.array(trajectory.times, dtype=float)
        positions = np.array(trajectory.positions, dtype=float)
        velocities = trajectory.point_velocities.copy()
        T = np.diff(times)[:, None]
        a1, a2 = hermite_coefficients(positions[:-1], velocities[:-1], positions[1:], velocities[1:], T)
        return PreparedTrajectory(names, times, positions, velocities, a1, a2, columns, start_tick, ident)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    @property
    def end_position(self) -> FloatArray:
        """The controller's joints at the last point."""
        return self.positions[-1, self.columns].copy()

    def evaluate(self, t: float) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Position, path velocity, path acceleration of every path joint at trajectory time `t`
        (clamped to the ends)."""
        if t >= self.times[-1]:
            return self.positions[-1].copy(), self.velocities[-1].copy(), np.zeros(self.positions.shape[1])
        t = max(t, 0.0)
        seg = min(int(np.searchsorted(self.times, t, side="right")) - 1, len(self.times) - 2)
        tau = t - self.times[seg]
        p0, v0, a1, a2 = self.positions[seg], self.velocities[seg], self.a1[seg], self.a2[seg]
        p = p0 + tau * (v0 + tau * (a1 / 2.0 + tau * a2 / 6.0))
        v = v0 + tau * (a1 + tau * a2 / 2.0)
        a = a1 + tau * a2
        return p, v, a
