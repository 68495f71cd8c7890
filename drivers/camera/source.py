"""Parsing `--source sim|dir:PATH|device:N` into a camera."""

from __future__ import annotations

from dataclasses import dataclass

from drivers.camera.errors import CameraSourceError

SOURCE_HELP = "sim | dir:PATH | device:N"


@dataclass(frozen=True)
class SourceSpec:
    kind: str             # "sim", "dir" or "device"
    path: str = ""
    index: int = -1


def parse_source(text: str) -> SourceSpec:
    """Parse a `--source` string; a clear CameraSourceError for anything else."""
    if not isinstance(text, str) or not text:
        raise CameraSourceError(f"--source: must be one of {SOURCE_HELP}, got {text!r}")
    if text == "sim":
        return SourceSpec("sim")
    if text.startswith("dir:"):
        path = text[4:]
        if not path:
            raise CameraSourceError("--source: dir: needs a folder, as in dir:PATH")
        return SourceSpec("dir", path=path)
    if text.startswith("device:"):
        num = text[7:]
        if not num.isdigit():
            raise CameraSourceError(f"--source: device: needs a non-negative integer index, got {num!r}")
        return SourceSpec("device", index=int(num))
    raise CameraSourceError(f"--source: must be one of {SOURCE_HELP}, got {text!r}")
