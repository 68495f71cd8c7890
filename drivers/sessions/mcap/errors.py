"""Errors of the session-log area (MCAP writer, reader, info, recover)."""

from __future__ import annotations

from pathlib import Path


class McapLogError(Exception):
    """Base class of every session-log error."""


class LogFileError(McapLogError):
    """A log file cannot be used: missing, unreadable, not MCAP, or cut short where a whole file is needed.

    Carries the path and the reason so the CLI can print one line.
    """

    def __init__(self, path: str | Path, reason: str):
        self.path = str(path)
        self.reason = reason
        super().__init__(f"{self.path}: {reason}")


class LogWriteError(McapLogError, ValueError):
    """A write was refused: bad argument (named in the message) or the type of a topic changed."""


class WriterClosedError(McapLogError):
    """The session writer was used after `close()`."""
