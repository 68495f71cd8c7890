"""`sim`: the simulated garment world, rendered on every capture."""

from __future__ import annotations

import threading

import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError
from drivers.camera.model import MOUNTS, CameraInfo, CameraModel, default_camera_config
from drivers.sim.config import SimConfig, default_sim_config
from drivers.sim.dataset import build_world
from drivers.sim.render import encode_png
from drivers.sim.world import GarmentWorld, GraspResult


class SimCamera(Camera):
    """Renders `world` (default: the scene of `seed` and `category`, as `dataset generate` draws it).

    `mount` ("fixed" or "wrist"; default config/camera.yaml's): with a wrist mount, set
    `camera_pose_world` (4x4 optical frame in `world`) from the arm's state before a capture; until
    then a wrist camera has no pose and a capture is an error.
    """

    def __init__(self, seed: int = 0, category: str = "towel", folded: bool = False,
                 world: GarmentWorld | None = None, config: SimConfig | None = None,
                 folding: str | None = None, mount: str | None = None):
        super().__init__()
        if mount not in (None, *MOUNTS):
            raise ValueError(f"mount: must be one of {', '.join(MOUNTS)}, got {mount!r}")
        self.seed, self.category, self.folded, self.folding = seed, category, folded, folding
        self.mount = mount or default_camera_config().mount
        self.config = config or default_sim_config()
        self.world = world
        self.camera_pose_world: np.ndarray | None = None
        # gripper events arrive on the wire's threads while a capture renders; readers of the
        # world's state (its ground truth) take this lock too
        self.lock = threading.Lock()

    def _open(self) -> None:
        if self.world is None:
            self.world = build_world(self.seed, self.category, self.folded, self.config,
                                     folding=self.folding or self.config.folding)
        # the first image pays for the table's texture (about 0.5 s, several on a loaded machine):
        # paid here, on connecting, not by the first capture a cell waits for
        self.world.render()

    def _close(self) -> None:
        pass

    def scene(self) -> GarmentWorld:
        """The simulated world this camera renders (built on first use)."""
        if self.world is None:
            self._open()
        assert self.world is not None
        return self.world

    def gripper_event(self, arm: str, closed: bool, tcp_position_world: np.ndarray) -> GraspResult | None:
        """Forward an emulated gripper's state change to the world; a closing gives its grasp result."""
        world = self.scene()
        with self.lock:
            return world.gripper_event(arm, closed, tcp_position_world)

    def _camera_model(self, pose: np.ndarray | None) -> CameraModel | None:
        """The camera at `pose` (None: the world's fixed camera); None for a wrist camera without one."""
        world = self.scene()
        assert world.camera is not None
        if pose is None:
            return None if self.mount == "wrist" else world.camera
        return CameraModel(world.camera.config, pose_in_world=pose, table=world.table)

    def current_info(self) -> CameraInfo | None:
        model = self._camera_model(self.camera_pose_world)
        return None if model is None else model.camera_info()

    def _capture(self) -> Frame:
        pose = self.camera_pose_world  # set from another thread: one read for the image and its info
        model = self._camera_model(pose)
        if model is None:
            raise CameraError("wrist camera: no arm state yet (controller/joint_states), so no camera pose")
        world = self.scene()
        with self.lock:
            image = world.render(pose)
        return Frame(image=image, stamp=self.now(), info=model.camera_info(),
                     png=encode_png(image, self.config.render.png_compression))
