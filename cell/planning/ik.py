"""Inverse kinematics of a TCP: damped least squares within joint limits, several seeds.

Works on the arm's six joints, optionally with the turn-table (`ext_axis`) as a seventh DOF.
Joint vectors are 13 values in project order (see drivers/kinematics.py).
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from drivers.common.configfile import rule
from drivers.robot.kinematics import CellKinematics

log = logging.getLogger(__name__)

# np.linalg.solve's own kernel (LAPACK gesv), called without the wrapper's per-call checks, which
# cost 2.4 of the 3.2 us it takes on a 6x6 system: the same result, bit for bit. The DLS matrix
# J J^T + damping^2 I is positive definite (damping > 0), so the wrapper's singular-matrix error
# cannot arise. A numpy without it: the public function.
_solve: Callable[[np.ndarray, np.ndarray], np.ndarray]
try:
    from numpy.linalg._umath_linalg import solve1
    _solve = functools.partial(solve1, signature="dd->d")
except ImportError:
    _solve = np.linalg.solve


@dataclass(frozen=True)
class IkParams:
    """Solver settings (config/planning.yaml, `ik`)."""

    max_iterations: int = rule(min=1)
    damping: float = rule(positive=True)
    position_tolerance: float = rule(positive=True)    # m
    angle_tolerance: float = rule(positive=True)       # rad
    max_step: float = rule(positive=True)              # rad per iteration, per joint
    limit_margin: float = rule(min=0.0)                # rad kept from each joint limit


@dataclass(frozen=True)
class IkResult:
    q: np.ndarray
    success: bool
    position_error: float
    angle_error: float
    iterations: int


WORLD_DOWN = np.array([0.0, 0.0, -1.0])
WORLD_DOWN.setflags(write=False)  # a shared default argument


def look_rotation(approach: np.ndarray, down: np.ndarray = WORLD_DOWN) -> np.ndarray:
    """TCP orientation whose z axis is `approach` and whose x axis (jaw, lower finger side) is as
    close to `down` as possible."""
    z = np.asarray(approach, dtype=float)
    z = z / np.linalg.norm(z)
    x = down - np.dot(down, z) * z
    n = np.linalg.norm(x)
    if n < 1e-9:  # approach vertical: any jaw direction, pick world x
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
        n = np.linalg.norm(x)
    x = x / n
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


class IkSolver:
    """DLS IK for the cell's arms; one solver per kinematics model (not thread-safe)."""

    def __init__(self, kin: CellKinematics, params: IkParams):
        self.kin = kin
        self.params = params
        self.model = kin.model
        self.data = kin.model.createData()
        robot = kin.robot
        self.lower = robot.lower + params.limit_margin
        self.upper = robot.upper - params.limit_margin
        self.ext_index = robot.index("ext_axis")
        self.arm_indices = {a.name: robot.group_indices(a.group) for a in robot.arms}
        self.frame_ids = {a.name: kin.frame_id(a.tcp_frame) for a in robot.arms}

    def tcp_pose(self, q: np.ndarray, arm: str) -> np.ndarray:
        pin.framesForwardKinematics(self.model, self.data, self.kin.to_pin(q))
        return self.data.oMf[self.frame_ids[arm]].homogeneous.copy()

    def solve(self, arm: str, target: np.ndarray, seed: np.ndarray, use_turntable: bool = False,
              max_iterations: int | None = None) -> IkResult:
        """Joint vector putting `arm`'s TCP at `target` (4x4, world), starting from `seed` (13)."""
        p = self.params
        fid = self.frame_ids[arm]
        idx = list(self.arm_indices[arm]) + ([self.ext_index] if use_turntable else [])
        idx_arr = np.array(idx)
        pin_cols = self.kin.pin_index[idx_arr]
        q = np.clip(np.asarray(seed, dtype=float).copy(), self.lower, self.upper)
        lower, upper = self.lower[idx_arr], self.upper[idx_arr]
        qp = self.kin.to_pin(q)   # pinocchio order; only the solved joints (pin_cols) change below
        R_t = target[:3, :3]
        p_t = target[:3, 3]
        damping = (p.damping ** 2) * np.eye(6)
        iters = max_iterations or p.max_iterations
        pos_err = ang_err = np.inf
        # An iteration is a function of the solved joints alone (the rest of q stays). When they come
        # back to a value they had (bit for bit), every later iteration repeats that cycle, none of
        # whose states was within tolerance: the result of running all `iters` is known exactly
        # (the state and errors at the matching place in the cycle), so it is returned at once.
        seen: dict[bytes, int] = {}
        states: list[np.ndarray] = []
        errors: list[tuple[float, float]] = []
        x = q[idx_arr]   # the solved joints (written back into q on return)
        for it in range(iters):
            key = x.tobytes()
            start = seen.get(key)
            if start is not None:
                period = it - start
                q[idx_arr] = states[start + (iters - start) % period]
                pos_err, ang_err = errors[start + (iters - 1 - start) % period]
                return IkResult(q, False, pos_err, ang_err, iters)
            seen[key] = it
            states.append(x)
            J6 = pin.computeFrameJacobian(self.model, self.data, qp, fid, pin.LOCAL_WORLD_ALIGNED)
            M = self.data.oMf[fid]
            e_pos = p_t - M.translation
            e_rot = pin.log3(R_t @ M.rotation.T)
            pos_err = math.sqrt(e_pos.dot(e_pos))   # = np.linalg.norm, bit for bit
            ang_err = math.sqrt(e_rot.dot(e_rot))
            if pos_err < p.position_tolerance and ang_err < p.angle_tolerance:
                q[idx_arr] = x
                return IkResult(q, True, pos_err, ang_err, it)
            errors.append((pos_err, ang_err))
            J = J6[:, pin_cols]
            e = np.concatenate([e_pos, e_rot])
            dq = J.T @ _solve(J @ J.T + damping, e)
            m = np.abs(dq).max()
            if m > p.max_step:
                dq *= p.max_step / m
            # np.clip(x + dq, lower, upper), faster; the same bits (they could differ only in the sign
            # of a zero at a limit of exactly 0.0)
            x = np.minimum(np.maximum(x + dq, lower), upper)
            qp[pin_cols] = x
        q[idx_arr] = x
        ok = pos_err < p.position_tolerance and ang_err < p.angle_tolerance
        return IkResult(q, ok, pos_err, ang_err, iters)

    def solve_multi(self, arm: str, target: np.ndarray, seeds: list[np.ndarray],
                    use_turntable: bool = False) -> IkResult:
        """Try seeds in order; the first success, else the closest failure."""
        best: IkResult | None = None
        for seed in seeds:
            r = self.solve(arm, target, seed, use_turntable)
            if r.success:
                return r
            if best is None or r.position_error < best.position_error:
                best = r
        assert best is not None
        return best


__all__ = ["IkParams", "IkResult", "IkSolver", "look_rotation"]
