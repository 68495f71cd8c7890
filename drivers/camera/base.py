"""The camera device interface (lerobot-style life cycle) and the frame it returns."""

from __future__ import annotations

import abc
import time
from dataclasses import dataclass
from types import TracebackType

import numpy as np

from drivers.camera.errors import CameraNotConnectedError
from drivers.camera.model import CameraInfo


@dataclass(frozen=True)
class Frame:
    """One captured image: BGR uint8 (height, width, 3), capture stamp (s, UNIX time), camera info."""

    image: np.ndarray
    stamp: float
    info: CameraInfo
    # the PNG bytes when the source has them already (a sim or a folder of PNGs), so a server can
    # publish exactly those bytes instead of re-encoding
    png: bytes | None = None


class Camera(abc.ABC):
    """A camera: `connect()`, `capture()`, `disconnect()`; usable as a context manager."""

    def __init__(self) -> None:
        self._connected = False

    @property
    def is_connected(self) -> bool:
        return self._connected

    def connect(self) -> None:
        if not self._connected:
            self._open()
            self._connected = True

    def disconnect(self) -> None:
        if self._connected:
            self._close()
            self._connected = False

    def capture(self) -> Frame:
        """A fresh frame (blocking)."""
        if not self._connected:
            raise CameraNotConnectedError(f"{type(self).__name__}: capture() before connect()")
        return self._capture()

    def current_info(self) -> CameraInfo | None:
        """The info the next frame will carry, when known without capturing (else None): a camera
        process publishes it before the first capture."""
        return None

    def __enter__(self) -> Camera:
        self.connect()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.disconnect()

    @abc.abstractmethod
    def _open(self) -> None: ...

    @abc.abstractmethod
    def _close(self) -> None: ...

    @abc.abstractmethod
    def _capture(self) -> Frame: ...

    @staticmethod
    def now() -> float:
        return time.time()
