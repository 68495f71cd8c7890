"""Camera devices: the interface, a folder of images, an OpenCV device, the simulated world."""

from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError, CameraNotConnectedError, CameraSourceError
from drivers.camera.source import SourceSpec, open_source, parse_source

__all__ = ["Camera", "CameraError", "CameraNotConnectedError", "CameraSourceError", "Frame", "SourceSpec",
           "open_source", "parse_source"]
