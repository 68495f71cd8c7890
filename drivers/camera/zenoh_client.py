"""A camera reached over Zenoh: `capture()` queries `camera/capture` of the cell's camera process."""

from __future__ import annotations

import threading
import time
from collections import OrderedDict
from typing import Any

import cv2
import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError
from drivers.camera.model import CameraInfo
from drivers.wire import messages
from drivers.wire.messages import NobodyServes, WireError
from drivers.wire.poses import pose_matrix
from drivers.wire.transport import Wire


class CameraTimeout(CameraError):
    """The camera process did not answer in time (gone, or too slow)."""


class ZenohCamera(Camera):
    """The cell's camera process as a `Camera`; intrinsics and pose come from `camera/info` and
    `camera/pose`."""

    def __init__(self, wire: Wire, timeout_s: float, appear_s: float = 2.0):
        super().__init__()
        self.wire = wire
        self.timeout_s = timeout_s
        # a camera process just started (or its link just formed) may not be reachable yet: a capture
        # that finds nobody serving asks again for this long before it gives up
        self.appear_s = appear_s
        self.lock = threading.Condition()
        self.info_msg: Any = None
        self.pose: np.ndarray | None = None
        self.have_info = threading.Event()
        # the latest infos and poses by stamp (ns): a capture takes the ones stamped like its image
        self.recent_info: OrderedDict[int, Any] = OrderedDict()
        self.recent_pose: OrderedDict[int, np.ndarray] = OrderedDict()

    def _open(self) -> None:
        self.wire.subscribe("camera/info", self._on_info)
        self.wire.subscribe("camera/pose", self._on_pose)

    def _close(self) -> None:
        pass

    def _on_info(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.lock:
            self.info_msg = msg
            _remember(self.recent_info, messages.stamp_to_ns(msg.header.stamp), msg)
            if self.pose is not None:
                self.have_info.set()
            self.lock.notify_all()

    def _on_pose(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.lock:
            self.pose = pose_matrix(msg.pose)
            _remember(self.recent_pose, messages.stamp_to_ns(msg.header.stamp), self.pose)
            if self.info_msg is not None:
                self.have_info.set()
            self.lock.notify_all()

    def camera_info(self) -> CameraInfo:
        """The latest intrinsics and pose the camera process published."""
        if not self.have_info.wait(self.timeout_s):
            raise CameraTimeout(f"no camera/info and camera/pose within {self.timeout_s:g} s")
        with self.lock:
            info, pose = self.info_msg, self.pose
        assert pose is not None   # have_info is set once both arrived
        return _camera_info(info, pose)

    def _info_of_image(self, stamp_ns: int) -> CameraInfo:
        """The intrinsics and pose published with the image stamped `stamp_ns` (they precede it)."""
        with self.lock:
            if not self.lock.wait_for(lambda: stamp_ns in self.recent_info and stamp_ns in self.recent_pose,
                                      self.timeout_s):
                raise CameraTimeout(f"no camera/info and camera/pose for the image within "
                                    f"{self.timeout_s:g} s")
            return _camera_info(self.recent_info[stamp_ns], self.recent_pose[stamp_ns])

    def _capture(self) -> Frame:
        appear_by = time.monotonic() + self.appear_s
        while True:
            try:
                reply = self.wire.request("camera/capture", messages.new("std_msgs/msg/Empty"),
                                          timeout=self.timeout_s)
                break
            except NobodyServes as err:
                if time.monotonic() >= appear_by:
                    raise CameraTimeout(str(err)) from err
                time.sleep(APPEAR_POLL_S)
            except WireError as err:
                raise CameraTimeout(str(err)) from err
        data = reply.data.tobytes()
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise CameraError(f"camera/capture: the reply's {reply.format} image does not decode")
        stamp_ns = messages.stamp_to_ns(reply.header.stamp)
        info = self._info_of_image(stamp_ns)
        return Frame(image=image, stamp=stamp_ns / 1e9, info=info, png=data)


APPEAR_POLL_S = 0.05
RECENT = 16  # infos and poses kept by stamp: far more than arrive between an image and its reply


def _remember(recent: OrderedDict[int, Any], stamp_ns: int, value: Any) -> None:
    recent[stamp_ns] = value
    while len(recent) > RECENT:
        recent.popitem(last=False)


def _camera_info(info: Any, pose: np.ndarray) -> CameraInfo:
    return CameraInfo(width=int(info.width), height=int(info.height), k=tuple(info.k.tolist()),
                      d=tuple(info.d.tolist()), p=tuple(info.p.tolist()), r=tuple(info.r.tolist()),
                      distortion_model=info.distortion_model, frame_id=info.header.frame_id,
                      pose_in_world=tuple(pose.ravel().tolist()))
