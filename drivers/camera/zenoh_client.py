"""A camera reached over Zenoh: `capture()` queries `camera/capture` of the cell's camera process."""

from __future__ import annotations

import threading
from typing import Any

import cv2
import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError
from drivers.camera.model import CameraInfo
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.transport import Wire


class CameraTimeout(CameraError):
    """The camera process did not answer in time (gone, or too slow)."""


def pose_to_matrix(pose: Any) -> np.ndarray:
    q = pose.orientation
    w, x, y, z = q.w, q.x, q.y, q.z
    m = np.eye(4)
    m[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    m[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return m


class ZenohCamera(Camera):
    """The cell's camera process as a `Camera`. Intrinsics and pose come from `camera/info` and `camera/pose`."""

    def __init__(self, wire: Wire, timeout_s: float):
        super().__init__()
        self.wire = wire
        self.timeout_s = timeout_s
        self.lock = threading.Lock()
        self.info_msg: Any = None
        self.pose: np.ndarray | None = None
        self.have_info = threading.Event()

    def _open(self) -> None:
        self.wire.subscribe("camera/info", self._on_info)
        self.wire.subscribe("camera/pose", self._on_pose)

    def _close(self) -> None:
        pass

    def _on_info(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.lock:
            self.info_msg = msg
            if self.pose is not None:
                self.have_info.set()

    def _on_pose(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.lock:
            self.pose = pose_to_matrix(msg.pose)
            if self.info_msg is not None:
                self.have_info.set()

    def camera_info(self) -> CameraInfo:
        if not self.have_info.wait(self.timeout_s):
            raise CameraTimeout(f"no camera/info and camera/pose within {self.timeout_s:g} s")
        with self.lock:
            m, pose = self.info_msg, self.pose
        return CameraInfo(width=int(m.width), height=int(m.height), k=tuple(m.k.tolist()), d=tuple(m.d.tolist()),
                          p=tuple(m.p.tolist()), r=tuple(m.r.tolist()), distortion_model=m.distortion_model,
                          frame_id=m.header.frame_id, pose_in_world=tuple(pose.ravel().tolist()))

    def _capture(self) -> Frame:
        try:
            reply = self.wire.request("camera/capture", messages.new("std_msgs/msg/Empty"), timeout=self.timeout_s)
        except WireError as err:
            raise CameraTimeout(str(err)) from err
        data = reply.data.tobytes()
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise CameraError(f"camera/capture: the reply's {reply.format} image does not decode")
        info = self.camera_info()
        return Frame(image=image, stamp=messages.stamp_to_ns(reply.header.stamp) / 1e9, info=info, png=data)
