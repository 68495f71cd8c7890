"""Inverse kinematics of a TCP: damped least squares within joint limits, several seeds.

Works on the arm's six joints, optionally with the turn-table (`ext_axis`) as a seventh DOF.
Joint vectors are 13 values in project order (see drivers/kinematics.py).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from drivers.common.configfile import rule
from drivers.robot.kinematics import CellKinematics

log = logging.getLogger(__name__)


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
        R_t = target[:3, :3]
        p_t = target[:3, 3]
        lam2 = p.damping ** 2
        iters = max_iterations or p.max_iterations
        pos_err = ang_err = np.inf
        for it in range(iters):
            qp = self.kin.to_pin(q)
            J6 = pin.computeFrameJacobian(self.model, self.data, qp, fid, pin.LOCAL_WORLD_ALIGNED)
            M = self.data.oMf[fid]
            e_pos = p_t - M.translation
            e_rot = pin.log3(R_t @ M.rotation.T)
            pos_err = float(np.linalg.norm(e_pos))
            ang_err = float(np.linalg.norm(e_rot))
            if pos_err < p.position_tolerance and ang_err < p.angle_tolerance:
                return IkResult(q, True, pos_err, ang_err, it)
            J = J6[:, pin_cols]
            e = np.concatenate([e_pos, e_rot])
            dq = J.T @ np.linalg.solve(J @ J.T + lam2 * np.eye(6), e)
            m = np.max(np.abs(dq))
            if m > p.max_step:
                dq *= p.max_step / m
            q[idx_arr] = np.clip(q[idx_arr] + dq, self.lower[idx_arr], self.upper[idx_arr])
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
