"""`dir:PATH`: serves a folder's images in name order, cycling."""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError, CameraSourceError
from drivers.camera.model import CameraInfo, CameraModel

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp")


class DirectoryCamera(Camera):
    def __init__(self, path: str | Path, camera: CameraModel | None = None):
        super().__init__()
        self.path = Path(path)
        self._model = camera
        self._files: list[Path] = []
        self._next = 0

    def _open(self) -> None:
        if not self.path.is_dir():
            raise CameraSourceError(f"dir:{self.path}: not a directory")
        self._files = sorted(p for p in self.path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if not self._files:
            raise CameraSourceError(f"dir:{self.path}: holds no images ({', '.join(IMAGE_SUFFIXES)})")
        self._next = 0
        self._info = (self._model or CameraModel()).camera_info()

    def _close(self) -> None:
        self._files = []

    @property
    def files(self) -> list[Path]:
        return list(self._files)

    def _capture(self) -> Frame:
        path = self._files[self._next % len(self._files)]
        self._next += 1
        data = path.read_bytes()
        img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
        if img is None:
            raise CameraError(f"dir:{self.path}: cannot decode {path.name}")
        info: CameraInfo = self._info
        if (img.shape[1], img.shape[0]) != (info.width, info.height):
            log.warning("%s is %dx%d, the camera info says %dx%d", path.name, img.shape[1], img.shape[0],
                        info.width, info.height)
        return Frame(image=img, stamp=self.now(), info=info,
                     png=data if path.suffix.lower() == ".png" else None)
