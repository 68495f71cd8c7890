"""The cell's kinematic model (pinocchio, from `config/robot/cell.urdf`) and forward kinematics.

Joint vectors are always in the project order of `config/robot/joints.yaml` (13 values, rad);
pinocchio's own order (URDF tree order) stays inside this module. Poses are 4x4 homogeneous
matrices in `world` (m). Lives in `drivers/` because the controller emulator publishes TCP poses.
"""

from __future__ import annotations

import logging
from functools import lru_cache
from pathlib import Path

import numpy as np
import pinocchio as pin

from drivers.robot.config import RobotConfig, default_robot_config

log = logging.getLogger(__name__)


class KinematicsError(ValueError):
    """The URDF does not match the joint configuration, or a joint vector is malformed."""


class CellKinematics:
    """Pinocchio model of the whole cell with FK for any frame, in project joint order."""

    def __init__(self, robot: RobotConfig | None = None, urdf_path: str | Path | None = None):
        self.robot = robot or default_robot_config()
        self.urdf_path = Path(urdf_path) if urdf_path else self.robot.urdf_path
        if not self.urdf_path.exists():
            raise KinematicsError(f"{self.urdf_path}: URDF not found")
        self.model = pin.buildModelFromUrdf(str(self.urdf_path))
        self.data = self.model.createData()
        names = self.robot.joint_names
        # project index i -> pinocchio q index
        perm = []
        for name in names:
            if not self.model.existJointName(name):
                raise KinematicsError(f"{self.urdf_path}: joint {name!r} of joints.yaml is missing")
            jid = self.model.getJointId(name)
            if self.model.joints[jid].nq != 1:
                raise KinematicsError(f"{self.urdf_path}: joint {name!r} must have one DOF")
            perm.append(self.model.joints[jid].idx_q)
        if self.model.nq != len(names):
            raise KinematicsError(
                f"{self.urdf_path}: model has {self.model.nq} DOF, joints.yaml names {len(names)}")
        self.pin_index = np.array(perm, dtype=int)  # q_pin[pin_index[i]] = q_project[i]
        self.tcp_frames = {a.name: a.tcp_frame for a in self.robot.arms}
        self._frame_ids: dict[str, int] = {}
        for frame in self.tcp_frames.values():
            self.frame_id(frame)

    def frame_id(self, frame: str) -> int:
        fid = self._frame_ids.get(frame)
        if fid is None:
            if not self.model.existFrame(frame):
                raise KinematicsError(f"{self.urdf_path}: no frame {frame!r}")
            fid = self.model.getFrameId(frame)
            self._frame_ids[frame] = fid
        return fid

    def to_pin(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (len(self.pin_index),):
            raise KinematicsError(f"joint vector must have {len(self.pin_index)} values, got shape {q.shape}")
        out = np.empty(len(q))
        out[self.pin_index] = q
        return out

    def update(self, q: np.ndarray) -> None:
        """Compute all frame placements for joint vector q (project order)."""
        pin.framesForwardKinematics(self.model, self.data, self.to_pin(q))

    def frame_pose(self, frame: str) -> np.ndarray:
        """Pose of a frame after `update` (4x4, world)."""
        return self.data.oMf[self.frame_id(frame)].homogeneous.copy()

    def fk(self, q: np.ndarray, frame: str) -> np.ndarray:
        """Pose (4x4, world) of `frame` at joint vector q (project order, rad)."""
        self.update(q)
        return self.frame_pose(frame)

    def tcp_pose(self, q: np.ndarray, arm: str) -> np.ndarray:
        """Pose (4x4, world) of the arm's TCP; arm is 'r1' or 'r2'."""
        if arm not in self.tcp_frames:
            raise KinematicsError(f"unknown arm {arm!r} (known: {', '.join(self.tcp_frames)})")
        return self.fk(q, self.tcp_frames[arm])

    def tcp_poses(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Both TCP poses at q, one FK pass."""
        self.update(q)
        return {arm: self.frame_pose(frame) for arm, frame in self.tcp_frames.items()}


@lru_cache(maxsize=1)
def default_kinematics() -> CellKinematics:
    """The cell model from the default config (built once per process; not thread-safe)."""
    return CellKinematics()


__all__ = ["CellKinematics", "KinematicsError", "default_kinematics"]
