"""Camera errors."""

from __future__ import annotations


class CameraError(Exception):
    """Base of camera errors."""


class CameraNotConnectedError(CameraError):
    """A capture or query on a camera that is not connected."""


class CameraSourceError(CameraError, ValueError):
    """A bad `--source` string or a source that cannot be opened; the message says why."""
