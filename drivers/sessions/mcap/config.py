"""Session-log settings, read from a `log:` mapping of a config file into a frozen dataclass."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_yaml_over

COMPRESSIONS = ("zstd", "lz4", "none")


@dataclass(frozen=True)
class SessionLogConfig:
    """How the recorder writes MCAP.

    chunk_size: bytes of uncompressed messages per chunk; a crash loses at most the open chunk.
    compression: 'zstd', 'lz4' or 'none'.
    rotate_bytes: start a new numbered file once the current one holds this many bytes (None: never).
    flush_interval_s: also close the open chunk once its oldest message is this old, so a slow topic
        does not keep data in memory for long (None: only by size).
    fsync: fsync after every chunk (survives power loss, not only a process crash).
    max_backlog_bytes: payload bytes received and not yet written the recorder may hold; past it, new
        samples are not recorded and the loss is logged in the session (as rosbag2's cache bound;
        None: no bound).
    receive_batch_s: the recorder handles what arrived in batches at most this far apart, instead of
        waking for each of hundreds of samples a second (0: at once); a crash also loses these.
    """

    chunk_size: int
    compression: str
    rotate_bytes: int | None
    flush_interval_s: float | None
    fsync: bool
    max_backlog_bytes: int | None = None
    receive_batch_s: float = 0.0

    def __post_init__(self) -> None:
        if self.chunk_size <= 0:
            raise ValueError(f"chunk_size: must be > 0, got {self.chunk_size}")
        if self.compression not in COMPRESSIONS:
            raise ValueError(f"compression: must be one of {', '.join(COMPRESSIONS)}, "
                             f"got {self.compression!r}")
        if self.rotate_bytes is not None and self.rotate_bytes <= 0:
            raise ValueError(f"rotate_bytes: must be > 0 or null, got {self.rotate_bytes}")
        if self.flush_interval_s is not None and self.flush_interval_s <= 0:
            raise ValueError(f"flush_interval_s: must be > 0 or null, got {self.flush_interval_s}")
        if self.max_backlog_bytes is not None and self.max_backlog_bytes <= 0:
            raise ValueError(f"max_backlog_bytes: must be > 0, got {self.max_backlog_bytes}")
        if self.receive_batch_s < 0:
            raise ValueError(f"receive_batch_s: must be >= 0, got {self.receive_batch_s}")


def session_log_config_from_fields(fields: Fields) -> SessionLogConfig:
    """Read the `log:` mapping of a config file (see the report for the proposed YAML keys).

    Every key but receive_batch_s (0: at once) is required, so the values live in the YAML file.
    """
    fields.reject_unknown({"chunk_size", "compression", "rotate_bytes", "flush_interval_s", "fsync",
                           "max_backlog_bytes", "receive_batch_s"})
    rotate = fields.raw("rotate_bytes")
    flush = fields.raw("flush_interval_s")
    return SessionLogConfig(
        chunk_size=fields.int("chunk_size", min=1),
        compression=fields.str("compression", choices=COMPRESSIONS),
        rotate_bytes=None if rotate is None else fields.int("rotate_bytes", min=1),
        flush_interval_s=None if flush is None else fields.float("flush_interval_s", positive=True),
        fsync=fields.bool("fsync"),
        max_backlog_bytes=fields.int("max_backlog_bytes", min=1),
        receive_batch_s=fields.float("receive_batch_s", 0.0, min=0.0),
    )


def load_session_log_config(path: str | Path | None = None) -> SessionLogConfig:
    """The `log:` section of `config/cell.yaml` (or of `path`)."""
    fields = load_yaml_over(path, config_dir() / "cell.yaml")
    return session_log_config_from_fields(fields.sub("log"))
