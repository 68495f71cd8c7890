"""A camera reached over Zenoh: `capture()` queries `camera/capture` of the cell's camera process."""

from __future__ import annotations

import threading
from typing import Any

import cv2
import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError
from drivers.camera.model import CameraInfo
from drivers.common.rotations import quaternion_to_matrix
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.transport import Wire


class CameraTimeout(CameraError):
    """The camera process did not answer in time (gone, or too slow)."""


def pose_to_matrix(pose: Any) -> np.ndarray:
    """4x4 homogeneous matrix of a `geometry_msgs/Pose`."""
    q = pose.orientation
    matrix = np.eye(4)
    matrix[:3, :3] = quaternion_to_matrix((q.x, q.y, q.z, q.w))
    matrix[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return matrix


class ZenohCamera(Camera):
    """The cell's camera process as a `Camera`; intrinsics and pose come from `camera/info` and
    `camera/pose`."""

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
            info, pose = self.info_msg, self.pose
        assert pose is not None   # have_info is set once both arrived
        return CameraInfo(width=int(info.width), height=int(info.height), k=tuple(info.k.tolist()),
                          d=tuple(info.d.tolist()), p=tuple(info.p.tolist()), r=tuple(info.r.tolist()),
                          distortion_model=info.distortion_model, frame_id=info.header.frame_id,
                          pose_in_world=tuple(pose.ravel().tolist()))

    def _capture(self) -> Frame:
        try:
            reply = self.wire.request("camera/capture", messages.new("std_msgs/msg/Empty"),
                                      timeout=self.timeout_s)
        except WireError as err:
            raise CameraTimeout(str(err)) from err
        data = reply.data.tobytes()
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise CameraError(f"camera/capture: the reply's {reply.format} image does not decode")
        info = self.camera_info()
        return Frame(image=image, stamp=messages.stamp_to_ns(reply.header.stamp) / 1e9, info=info, png=data)
