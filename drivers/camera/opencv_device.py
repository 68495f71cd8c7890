"""`device:N`: an OpenCV capture device (V4L2/USB camera)."""

from __future__ import annotations

import cv2

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError, CameraSourceError
from drivers.camera.model import CameraModel


class OpenCVDeviceCamera(Camera):
    def __init__(self, index: int, camera: CameraModel | None = None):
        super().__init__()
        self.index = index
        self._model = camera
        self._cap: cv2.VideoCapture | None = None

    def _open(self) -> None:
        model = self._model or CameraModel()
        cap = cv2.VideoCapture(self.index)
        if not cap.isOpened():
            cap.release()
            raise CameraSourceError(f"device:{self.index}: cannot open the capture device")
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, model.config.width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, model.config.height)
        self._cap = cap
        self._info = model.camera_info()

    def _close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None

    def _capture(self) -> Frame:
        assert self._cap is not None
        ok, img = self._cap.read()
        if not ok or img is None:
            raise CameraError(f"device:{self.index}: read failed")
        return Frame(image=img, stamp=self.now(), info=self._info)
