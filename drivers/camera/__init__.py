"""Cameras: the interface, a folder of images, an OpenCV device, the camera process and its client.

The simulated world's camera is in `drivers.sim.camera`.
"""

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError, CameraNotConnectedError, CameraSourceError
from drivers.camera.source import SourceSpec, parse_source

__all__ = ["Camera", "CameraError", "CameraNotConnectedError", "CameraSourceError", "Frame", "SourceSpec",
           "parse_source"]
