"""How the cell gets an image of the table: from the fixed camera once the arms are clear of its view,
or from the wrist camera's views taken in turn and merged into one top-down image of the table."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from cell.config import CellConfig
from cell.errors import CameraFault, StepFailed
from cell.wrist import WristCamera
from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError
from drivers.camera.table_image import merge_views

# moves the arms to a wrist camera's view (its configuration and a label), or clear of the fixed
# camera's view (None)
MoveToView = Callable[[np.ndarray | None, str], None]


class TableViewer:
    def __init__(self, camera: Camera, config: CellConfig, wrist: WristCamera | None,
                 position: Callable[[], np.ndarray]):
        self.camera = camera
        self.config = config
        self.wrist = wrist  # None: the camera is fixed above the table
        self.position = position  # the arms' joints now

    def look(self, move: MoveToView) -> Frame:
        """An image of the table, the arms moved by `move` to where it is taken."""
        if self.wrist is None:
            move(None, "perceive")
            return self.capture()
        views = self.wrist.views
        here = self.position()
        # the nearest view first: a garment's first look starts where the last one ended
        order = sorted(range(len(views)), key=lambda index: float(np.max(np.abs(views[index] - here))))
        frames = []
        for index in order:
            move(views[index], f"view {index + 1}")
            frames.append(self._capture_view(self.wrist.camera_poses[index]))
        try:
            return merge_views(frames, self.wrist.table_image)
        except CameraError as exc:
            raise StepFailed(f"wrist camera: {exc}", retryable=False) from exc

    def capture(self) -> Frame:
        """One image; a camera that fails or is slower than `camera_timeout_s` is a camera fault."""
        start = time.perf_counter()
        try:
            frame = self.camera.capture()
        except CameraError as exc:
            raise CameraFault(str(exc)) from exc
        took = time.perf_counter() - start
        if took > self.config.camera_timeout_s:
            raise CameraFault(f"capture took {took:.1f} s")
        return frame

    def _capture_view(self, expected_pose: np.ndarray) -> Frame:
        """A wrist camera's image once the pose it reports is the view's: the camera follows the
        arm's joint states on its own and may not have heard the end of the move yet."""
        deadline = time.monotonic() + self.config.camera_timeout_s
        while True:
            try:
                frame = self.capture()
                pose = np.asarray(frame.info.pose_in_world, dtype=float).reshape(4, 4)
                off = float(np.max(np.abs(pose - expected_pose)))
                if off <= self.config.view_pose_tolerance:
                    return frame
                reason = f"its pose stays {off:.4f} off the view's"
            except CameraFault as exc:  # e.g. no arm state heard yet
                reason = str(exc)
            if time.monotonic() > deadline:
                raise CameraFault(f"wrist camera: {reason}")
            time.sleep(self.config.view_retry_period_s)
