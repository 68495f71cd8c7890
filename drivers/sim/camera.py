"""`sim`: the simulated garment world, rendered on every capture."""

from __future__ import annotations

import threading

import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.model import CameraModel
from drivers.sim.config import SimConfig, default_sim_config
from drivers.sim.dataset import build_world
from drivers.sim.render import encode_png
from drivers.sim.world import GarmentWorld, GraspResult


class SimCamera(Camera):
    """Renders `world` (default: the scene of `seed` and `category`, as `dataset generate` draws it).

    With a wrist mount, set `camera_pose_world` (4x4) before each capture from the arm's state.
    """

    def __init__(self, seed: int = 0, category: str = "towel", folded: bool = False,
                 world: GarmentWorld | None = None, config: SimConfig | None = None):
        super().__init__()
        self.seed, self.category, self.folded = seed, category, folded
        self.config = config or default_sim_config()
        self.world = world
        self.camera_pose_world: np.ndarray | None = None
        # gripper events arrive on the wire's threads while a capture renders
        self._lock = threading.Lock()

    def _open(self) -> None:
        if self.world is None:
            self.world = build_world(self.seed, self.category, self.folded, self.config)

    def _close(self) -> None:
        pass

    def gripper_event(self, arm: str, closed: bool, tcp_position_world: np.ndarray) -> GraspResult | None:
        """Forward an emulated gripper's state change to the world; a closing gives its grasp result."""
        if self.world is None:
            self._open()
        assert self.world is not None
        with self._lock:
            return self.world.gripper_event(arm, closed, tcp_position_world)

    def _capture(self) -> Frame:
        assert self.world is not None and self.world.camera is not None
        with self._lock:
            img = self.world.render(self.camera_pose_world)
        model = self.world.camera if self.camera_pose_world is None else CameraModel(
            self.world.camera.config, pose_in_world=self.camera_pose_world, table=self.world.table)
        return Frame(image=img, stamp=self.now(), info=model.camera_info(),
                     png=encode_png(img, self.config.render.png_compression))
