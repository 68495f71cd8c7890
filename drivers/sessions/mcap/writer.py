"""The session writer: ROS 2 messages (CDR) into chunked, compressed MCAP files, rotated by size.

Files are what rosbag2 writes: profile `ros2`, schema encoding `ros2msg` (the full definition text,
dependencies appended), message encoding `cdr`, schema name `pkg/msg/Type`. Log time is the
receive time, publish time the sender's stamp.

A session (`bag=True`, what the recorder writes) is a rosbag2 bag (drivers/sessions/mcap/bag.py):
the folder `NAME/` with `NAME_0.mcap`, and, each time a file holds `rotate_bytes` bytes, the next
split file `NAME_1.mcap`, ...; `metadata.yaml` is rewritten whenever a file is opened and when the
session closes, so a crash leaves a bag that lists every file (`log recover` finishes it). Every
split file is a complete MCAP file with its own schemas, channels, metadata and summary. Without
`bag`, the writer makes the one file it is given (an export), which does not rotate.

Durability: each chunk is handed to the operating system as soon as it is closed, so a killed
process loses at most the open chunk (plus the summary, which `recover` rebuilds). A chunk is closed
when it holds `chunk_size` bytes or, with `flush_interval_s`, once its oldest message is that old (on
the next write, or by a timer calling `flush_if_due`): a crash then loses at most that much time.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata
import logging
import os
import re
import threading
import time
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from drivers.sessions.mcap.bag import (
    FileStats,
    TopicStats,
    bag_file,
    bag_folder,
    clear_bag,
    qos_text,
    type_hash,
    write_metadata,
)
from drivers.sessions.mcap.config import COMPRESSIONS, SessionLogConfig
from drivers.sessions.mcap.errors import LogFileError, LogWriteError, WriterClosedError

logger = logging.getLogger(__name__)

PROFILE = "ros2"
SCHEMA_ENCODING = "ros2msg"
MESSAGE_ENCODING = "cdr"
METADATA_NAME = "foldcell_session"
DEFAULT_CHUNK_SIZE = 1024 * 1024  # the mcap library's own default: good compression, bounded loss

_TYPE_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_]*/msg/[A-Za-z][A-Za-z0-9_]*$")
_U64 = 2**64
_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}


def foldcell_version() -> str:
    """The installed foldcell version, or the one in the repository's pyproject.toml."""
    try:
        return importlib.metadata.version("foldcell")
    except importlib.metadata.PackageNotFoundError:
        pass
    pyproject = Path(__file__).resolve().parents[3] / "pyproject.toml"
    try:
        import tomllib

        return str(tomllib.loads(pyproject.read_text())["project"]["version"])
    except (OSError, KeyError, ValueError):
        return "unknown"


def channel_metadata(topic: str, type_name: str) -> dict[str, str]:
    """What rosbag2's MCAP storage writes in a channel's metadata: the offered QoS (YAML) and the
    type hash; readers of the bag (rosbags) match a channel to `metadata.yaml` by them."""
    return {"offered_qos_profiles": qos_text(topic), "topic_type_hash": type_hash(type_name)}


class _FlushingStream:
    """Hands every write to the OS at once (a chunk is written in a few large writes)."""

    def __init__(self, f: BinaryIO, fsync: bool):
        self._f = f
        self._fsync = fsync

    def write(self, data: bytes) -> int:
        if not data:
            return 0
        n = self._f.write(data)
        self._f.flush()
        if self._fsync:
            os.fsync(self._f.fileno())
        return n

    def tell(self) -> int:
        return self._f.tell()

    def flush(self) -> None:
        self._f.flush()

    def close(self) -> None:
        self._f.close()


class SessionWriter:
    """Writes one recording session, possibly as several rotated files. Thread-safe.

    Use as a context manager or call `close()` (idempotent) so the last file gets its summary and
    footer. On SIGINT/SIGTERM the recorder should set an event in the handler and close from its
    loop; a `close()` called inside a handler that interrupted `write()` in the same thread is
    deferred to the end of that write (no deadlock), and later writes raise WriterClosedError.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        chunk_size: int = DEFAULT_CHUNK_SIZE,
        compression: str = "zstd",
        rotate_bytes: int | None = None,
        metadata: dict[str, str] | None = None,
        cell: str | None = None,
        flush_interval_s: float | None = None,
        fsync: bool = False,
        bag: bool = False,
    ):
        # SessionLogConfig validates the numbers and names the bad one.
        try:
            SessionLogConfig(chunk_size, compression, rotate_bytes, flush_interval_s, fsync)
        except ValueError as exc:
            raise LogWriteError(str(exc)) from None
        if metadata is not None and not all(isinstance(k, str) and isinstance(v, str)
                                            for k, v in metadata.items()):
            raise LogWriteError("metadata: keys and values must be strings")
        if rotate_bytes is not None and not bag:
            raise LogWriteError("rotate_bytes: only a session (a bag folder) is split into files")
        # A bag: the folder and its split files; else the one file given.
        self._bag = bag_folder(path) if bag else None
        self._first = Path(path)
        self._chunk_size = chunk_size
        self._compression = compression
        self._rotate_bytes = rotate_bytes
        self._flush_interval_s = flush_interval_s
        self._fsync = fsync
        # Reentrant so that close() from a signal handler, which runs in the thread that may be
        # inside write(), does not deadlock; it is then deferred to the end of that write().
        self._lock = threading.RLock()
        self._busy = False
        self._close_requested = False
        self._closed = False
        self._start_ns = time.time_ns()
        # The `foldcell_session` metadata record of every part: cell id, start time, version.
        self._session_metadata = {
            **({"cell": cell} if cell is not None else {}),
            "start_time": _dt.datetime.fromtimestamp(self._start_ns / 1e9, _dt.timezone.utc).isoformat(),
            "start_time_ns": str(self._start_ns),
            "foldcell_version": foldcell_version(),
            **(metadata or {}),
        }
        self._library = f"foldcell/{self._session_metadata['foldcell_version']}; {LIBRARY_IDENTIFIER}"
        # Per session (not per file): topic -> (type_name, msgdef) and next sequence number.
        self._topic_types: dict[str, tuple[str, str]] = {}
        self._sequence: dict[str, int] = {}
        self._type_defs: dict[str, str] = {}
        self._paths: list[Path] = []
        self._messages_total = 0
        self._file_stats: list[FileStats] = []
        self._topic_counts: dict[str, int] = {}
        if self._bag is not None:
            self._prepare_bag(self._bag)
        # Per file, set by _open_part: ids of the schemas and channels written, and when the
        # chunk now filling took its first message (None: no message since the last chunk).
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._chunk_opened: float | None = None
        self._open_part(0)

    @classmethod
    def from_config(cls, path: str | Path, config: SessionLogConfig, *,
                    metadata: dict[str, str] | None = None, cell: str | None = None) -> SessionWriter:
        """A session (a bag) at `path`, written as `config` says."""
        return cls(path, chunk_size=config.chunk_size, compression=config.compression,
                   rotate_bytes=config.rotate_bytes, metadata=metadata, cell=cell,
                   flush_interval_s=config.flush_interval_s, fsync=config.fsync, bag=True)

    # -- public -----------------------------------------------------------------------------------

    @property
    def paths(self) -> list[Path]:
        """Every file of this session so far, in order (the last one is open until `close()`)."""
        with self._lock:
            return list(self._paths)

    @property
    def bag(self) -> Path | None:
        """The bag folder of a session; None for a single file."""
        return self._bag

    @property
    def message_count(self) -> int:
        with self._lock:
            return self._messages_total

    @property
    def closed(self) -> bool:
        return self._closed

    def write(self, topic: str, type_name: str, msgdef: str, data: bytes,
              log_time_ns: int, publish_time_ns: int) -> None:
        """Append one CDR-encoded message; the first message of a topic registers its schema and channel.

        topic: MCAP channel topic, `/` + key expression. type_name: `pkg/msg/Type`.
        msgdef: the full `ros2msg` definition text. log_time_ns: receive time; publish_time_ns:
        the sender's stamp (both ns since the Unix epoch).
        """
        _check_message(topic, type_name, msgdef, data, log_time_ns, publish_time_ns)
        with self._lock:
            self._busy = True
            try:
                # Checked after setting _busy: a signal handler may have closed us in between.
                if self._closed:
                    raise WriterClosedError(f"session writer for {self._first} is closed")
                self._write_locked(topic, type_name, msgdef, data, log_time_ns, publish_time_ns)
            finally:
                self._busy = False
                if self._close_requested:
                    self._close_locked()

    def _write_locked(self, topic: str, type_name: str, msgdef: str, data: bytes,
                      log_time_ns: int, publish_time_ns: int) -> None:
        known = self._topic_types.get(topic)
        if known is not None and known[0] != type_name:
            raise LogWriteError(f"topic {topic!r}: type changed (was {known[0]}, now {type_name}); "
                                "one topic carries one type")
        defined = self._type_defs.get(type_name)
        if defined is not None and defined != msgdef:
            raise LogWriteError(f"type {type_name}: message definition differs from the one "
                                "already recorded for it")
        if known is None:
            self._topic_types[topic] = (type_name, msgdef)
            self._type_defs[type_name] = msgdef
            self._sequence[topic] = 0
        channel_id = self._channel_id(topic, type_name, msgdef)
        self._sequence[topic] += 1
        before = self._stream.tell()
        self._writer.add_message(channel_id=channel_id, log_time=log_time_ns, data=bytes(data),
                                 publish_time=publish_time_ns, sequence=self._sequence[topic])
        self._messages_total += 1
        self._file_stats[-1].add(log_time_ns)
        self._topic_counts[topic] = self._topic_counts.get(topic, 0) + 1
        if self._stream.tell() != before:
            self._chunk_opened = None  # the chunk holding this message was just written out
        elif self._chunk_opened is None:
            self._chunk_opened = time.monotonic()
        elif (self._flush_interval_s is not None
              and time.monotonic() - self._chunk_opened >= self._flush_interval_s):
            self._flush_locked()
        if self._rotate_bytes is not None and self._stream.tell() >= self._rotate_bytes:
            self._rotate()

    def flush(self) -> None:
        """Write out the open chunk now (e.g. from a timer) so a crash cannot lose it."""
        with self._lock:
            if not self._closed and not self._busy:
                self._flush_locked()

    def flush_if_due(self) -> float | None:
        """Write out the open chunk once its oldest message is `flush_interval_s` old. Returns the
        seconds until the next chunk can be due (the whole interval when none is open), so a timer
        sleeping that long bounds the age of what a crash loses; None without a flush interval."""
        interval = self._flush_interval_s
        if interval is None:
            return None
        with self._lock:
            if self._closed or self._busy or self._chunk_opened is None:
                return interval
            age = time.monotonic() - self._chunk_opened
            if age < interval:
                return interval - age
            self._flush_locked()
            return interval

    def close(self) -> None:
        """Finish the current file (summary, footer) and close it. Safe to call twice."""
        with self._lock:
            if self._busy:
                # Called from a signal handler that interrupted write() in this thread.
                self._close_requested = True
                return
            self._close_locked()

    def _close_locked(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._finish_part()
        self._write_bag_metadata()
        logger.info("session log closed: %d messages in %d file(s), last %s",
                    self._messages_total, len(self._paths), self._paths[-1])

    def __enter__(self) -> SessionWriter:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    # -- internals (lock held) --------------------------------------------------------------------

    def _prepare_bag(self, folder: Path) -> None:
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise LogFileError(folder, f"cannot create the bag folder: {exc.strerror or exc}") from exc
        replaced = clear_bag(folder)
        if replaced:
            logger.warning("%s: replacing the session recorded there before (%d file(s))",
                           folder, len(replaced))

    def _write_bag_metadata(self) -> None:
        if self._bag is None:
            return
        topics = [TopicStats(topic, type_name, self._topic_counts.get(topic, 0))
                  for topic, (type_name, _) in self._topic_types.items()]
        write_metadata(self._bag, self._file_stats, topics, self._session_metadata)

    def _open_part(self, index: int) -> None:
        path = bag_file(self._bag, index) if self._bag is not None else self._first
        try:
            f = open(path, "wb")  # noqa: SIM115 - closed in _finish_part
        except OSError as exc:
            raise LogFileError(path, f"cannot create: {exc.strerror or exc}") from exc
        self._stream = _FlushingStream(f, self._fsync)
        self._writer = Writer(self._stream, chunk_size=self._chunk_size,  # type: ignore[arg-type]
                              compression=_COMPRESSION[self._compression])
        self._writer.start(profile=PROFILE, library=self._library)
        self._writer.add_metadata(METADATA_NAME, {**self._session_metadata, "part": str(index)})
        self._schema_ids = {}
        self._channel_ids = {}
        self._chunk_opened = None
        self._part = index
        self._paths.append(path)
        self._file_stats.append(FileStats(path.name))
        self._write_bag_metadata()  # lists the new file at once: a crash leaves a bag naming it
        logger.info("session log file %s opened", path)

    def _finish_part(self) -> None:
        self._writer.finish()
        self._stream.flush()
        if self._fsync:
            os.fsync(self._stream._f.fileno())
        self._stream.close()

    def _rotate(self) -> None:
        self._finish_part()
        try:
            self._open_part(self._part + 1)
        except LogFileError:
            self._closed = True  # the finished parts stay valid; nothing more can be written
            raise

    def _flush_locked(self) -> None:
        self._writer.flush()
        self._chunk_opened = None

    def _channel_id(self, topic: str, type_name: str, msgdef: str) -> int:
        channel_id = self._channel_ids.get(topic)
        if channel_id is not None:
            return channel_id
        schema_id = self._schema_ids.get(type_name)
        if schema_id is None:
            schema_id = self._writer.register_schema(name=type_name, encoding=SCHEMA_ENCODING,
                                                     data=msgdef.encode())
            self._schema_ids[type_name] = schema_id
        channel_id = self._writer.register_channel(topic=topic, message_encoding=MESSAGE_ENCODING,
                                                   schema_id=schema_id,
                                                   metadata=channel_metadata(topic, type_name))
        self._channel_ids[topic] = channel_id
        return channel_id


def _check_message(topic: str, type_name: str, msgdef: str, data: bytes,
                   log_time_ns: int, publish_time_ns: int) -> None:
    if not isinstance(topic, str) or not topic:
        raise LogWriteError(f"topic: must be a non-empty string, got {topic!r}")
    if not isinstance(type_name, str) or not _TYPE_NAME.match(type_name):
        raise LogWriteError(f"type_name: must look like pkg/msg/Type, got {type_name!r}")
    if not isinstance(msgdef, str):
        raise LogWriteError(f"msgdef: must be the ros2msg definition text, got {type(msgdef).__name__}")
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise LogWriteError(f"data: must be bytes, got {type(data).__name__}")
    for name, value in (("log_time_ns", log_time_ns), ("publish_time_ns", publish_time_ns)):
        if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < _U64:
            raise LogWriteError(f"{name}: must be an integer in [0, 2**64), got {value!r}")


__all__ = ["COMPRESSIONS", "DEFAULT_CHUNK_SIZE", "MESSAGE_ENCODING", "METADATA_NAME", "PROFILE",
           "SCHEMA_ENCODING", "SessionWriter", "channel_metadata", "foldcell_version"]
