"""The camera process: answers `camera/capture`, publishes images, intrinsics and pose.

What drives a simulated world (grippers, a wrist camera's pose, the ground truth) is the sim's own
node, `drivers.sim.node.SimWorldNode`, composed beside this one by `foldcell camera serve`.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import cv2
import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.model import CameraInfo
from drivers.wire import messages
from drivers.wire.poses import pose_stamped_msg
from drivers.wire.transport import RequestInfo, Wire

log = logging.getLogger(__name__)

PROCESS_NAME = "camera"


def camera_info_message(info: CameraInfo, stamp_ns: int) -> Any:
    return messages.new(
        "sensor_msgs/msg/CameraInfo", header=messages.header(stamp_ns, info.frame_id), height=info.height,
        width=info.width, distortion_model=info.distortion_model, d=list(info.d), k=list(info.k),
        r=list(info.r), p=list(info.p))


def png_of(frame: Frame) -> bytes:
    if frame.png is not None:
        return frame.png
    ok, data = cv2.imencode(".png", frame.image)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


class CameraNode:
    """Serves one camera on the wire: `camera/capture` answered with the image, which also goes to
    `camera/image`; `camera/info` and `camera/pose` on every change and every `info_period_s`."""

    def __init__(self, wire: Wire, camera: Camera, info_period_s: float):
        self.wire = wire
        self.camera = camera
        self.info_period_s = info_period_s
        self.image_pub = wire.publisher("camera/image")
        self.info_pub = wire.publisher("camera/info")
        self.pose_pub = wire.publisher("camera/pose")
        self.last_info: CameraInfo | None = None
        self.stop = threading.Event()
        wire.serve("camera/capture", self._on_capture)
        self.ticker = threading.Thread(target=self._tick, name="camera-info", daemon=True)

    def start(self) -> None:
        self.ticker.start()

    def close(self) -> None:
        self.stop.set()
        self.ticker.join(2.0)

    def _on_capture(self, _request: Any, _info: RequestInfo) -> Any:
        frame = self.camera.capture()
        stamp_ns = int(frame.stamp * 1e9)
        msg = messages.new("sensor_msgs/msg/CompressedImage",
                           header=messages.header(stamp_ns, frame.info.frame_id), format="png",
                           data=np.frombuffer(png_of(frame), dtype=np.uint8))
        # before the image and with its stamp, every time: a moving (wrist) camera's client takes the
        # pose of this very image, not the latest one it happened to receive
        self.last_info = frame.info
        self._publish_info(frame.info, stamp_ns)
        self.image_pub.put(msg)
        return msg

    def _publish_info(self, info: CameraInfo, stamp_ns: int) -> None:
        self.info_pub.put(camera_info_message(info, stamp_ns))
        self.pose_pub.put(pose_stamped_msg(np.array(info.pose_in_world).reshape(4, 4), stamp_ns))

    def _tick(self) -> None:
        """Repeat the info for late joiners; before the first capture, the camera's own if it knows it."""
        while not self.stop.wait(0 if self.last_info is None else self.info_period_s):
            info = self.last_info
            if info is None:
                try:
                    info = self.camera.current_info()
                except Exception:  # a device that is not ready yet: the next capture publishes it
                    info = None
                if info is None:
                    self.stop.wait(self.info_period_s)
                    continue
                self.last_info = info
            self._publish_info(info, time.time_ns())
