"""`log info`: topics, types, counts, rates and time span of a session file.

A file with a summary is described from its summary and message indexes (no chunk is decompressed);
a file without one (cut short by a crash, or written without a summary) is scanned record by record.
"""

from __future__ import annotations

import io
import logging
import struct
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.opcode import Opcode
from mcap.reader import SeekingReader
from mcap.records import Channel, Chunk, Header, Message, MessageIndex, Metadata, Schema
from mcap.summary import Summary

from drivers.sessions.mcap.errors import LogFileError
from drivers.sessions.mcap.scan import MAGIC, ScanState, open_log, scan

logger = logging.getLogger(__name__)

_NS_PER_S = 1e9


@dataclass(frozen=True)
class ChannelInfo:
    """One topic of a log. rate_hz = (count - 1) / (last - first log time), 0 with fewer than 2 messages."""

    topic: str
    type_name: str
    schema_encoding: str
    message_encoding: str
    message_count: int
    first_log_time_ns: int | None
    last_log_time_ns: int | None
    rate_hz: float


@dataclass(frozen=True)
class MetadataInfo:
    name: str
    entries: tuple[tuple[str, str], ...]


@dataclass(frozen=True)
class LogInfo:
    """What a log file holds. `complete` is False for a file cut short (then `unreadable_bytes` > 0
    or no footer) or with a damaged chunk (`damaged_chunks` > 0); `has_summary`: the file has one.
    For a session split into a bag's files (session.py), `bag` is its folder, `files` its files in
    order and `incomplete_files` those cut short or damaged; the rest sums or spans them all."""

    path: str
    size_bytes: int
    profile: str
    library: str
    has_summary: bool
    complete: bool
    unreadable_bytes: int
    damaged_chunks: int
    message_count: int
    chunk_count: int
    start_ns: int | None
    end_ns: int | None
    duration_s: float
    compression: tuple[str, ...]
    channels: tuple[ChannelInfo, ...]
    metadata: tuple[MetadataInfo, ...]
    bag: str | None = None
    files: tuple[str, ...] = ()
    incomplete_files: tuple[str, ...] = ()

    def to_json_dict(self) -> dict[str, Any]:
        """A JSON-able dict (metadata as name -> {key: value})."""
        out = asdict(self)
        out["compression"] = list(self.compression)
        out["channels"] = [asdict(c) for c in self.channels]
        out["metadata"] = {m.name: dict(m.entries) for m in self.metadata}
        out["files"] = list(self.files) or [self.path]
        out["incomplete_files"] = list(self.incomplete_files)
        return out


def read_info(path: str | Path, progress: Callable[[int], None] | None = None,
              verify: bool = True) -> LogInfo:
    """Describe a log file. `verify`: read every chunk and check its CRC (a damaged chunk makes the file
    not `complete`); else trust the summary when there is one. `progress(n)` gets bytes scanned.

    Raises LogFileError when the file is missing, unreadable or not MCAP.
    """
    p = Path(path)
    f, size = open_log(p)
    with f:
        summary = _try_summary(f)
        if summary is not None and not verify:
            try:
                info = _from_summary(p, f, size, summary)
            except (McapError, ValueError, EOFError, struct.error) as exc:
                logger.warning("%s: summary or message indexes unreadable (%s), scanning", p, exc)
                info = None
            if info is not None:
                return info
            logger.info("%s: summary lacks message indexes, scanning", p)
        f.seek(len(MAGIC))
        return _from_scan(p, f, size, summary is not None, progress)


def _try_summary(f: BinaryIO) -> Summary | None:
    try:
        f.seek(0)
        return SeekingReader(f).get_summary()
    except (McapError, ValueError, EOFError, OSError):
        return None  # cut short or no footer: scan instead


def rate_hz(count: int, first: int | None, last: int | None) -> float:
    if count < 2 or first is None or last is None or last <= first:
        return 0.0
    return (count - 1) * _NS_PER_S / (last - first)


def _channel_info(channel: Channel, schemas: dict[int, Schema], count: int,
                  first: int | None, last: int | None) -> ChannelInfo:
    schema = schemas.get(channel.schema_id)
    return ChannelInfo(
        topic=channel.topic,
        type_name=schema.name if schema else "",
        schema_encoding=schema.encoding if schema else "",
        message_encoding=channel.message_encoding,
        message_count=count,
        first_log_time_ns=first,
        last_log_time_ns=last,
        rate_hz=rate_hz(count, first, last),
    )


def _read_header(f: BinaryIO, size: int) -> Header | None:
    f.seek(len(MAGIC))
    for item in scan(f, size, ScanState(size)):
        return item.record if isinstance(item.record, Header) else None
    return None


def _from_summary(p: Path, f: BinaryIO, size: int, summary: Summary) -> LogInfo | None:
    counts: dict[int, int] = {}
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    for ci in summary.chunk_indexes:
        if ci.message_index_length == 0:
            return None
        f.seek(ci.chunk_start_offset + ci.chunk_length)
        stream = ReadDataStream(io.BytesIO(f.read(ci.message_index_length)))
        read = 0
        while read < ci.message_index_length:
            opcode = stream.read1()
            length = stream.read8()
            read += 9 + length
            if opcode != Opcode.MESSAGE_INDEX:
                stream.read(length)
                continue
            index = MessageIndex.read(stream)
            if not index.records:
                continue
            times = [t for t, _ in index.records]
            cid = index.channel_id
            counts[cid] = counts.get(cid, 0) + len(times)
            first[cid] = min(first.get(cid, times[0]), min(times))
            last[cid] = max(last.get(cid, times[0]), max(times))
    stats = summary.statistics
    total = sum(counts.values())
    if stats is None or stats.message_count != total:
        return None  # messages outside chunks or missing indexes: only a scan counts them right
    header = _read_header(f, size)
    f.seek(0)
    metadata = tuple(MetadataInfo(m.name, tuple(sorted(m.metadata.items())))
                     for m in SeekingReader(f).iter_metadata())
    channels = tuple(_channel_info(ch, summary.schemas, counts.get(cid, 0), first.get(cid), last.get(cid))
                     for cid, ch in sorted(summary.channels.items()))
    start = stats.message_start_time if total else None
    end = stats.message_end_time if total else None
    return LogInfo(
        path=str(p), size_bytes=size,
        profile=header.profile if header else "", library=header.library if header else "",
        has_summary=True, complete=True, unreadable_bytes=0, damaged_chunks=0,
        message_count=total, chunk_count=len(summary.chunk_indexes),
        start_ns=start, end_ns=end,
        duration_s=(end - start) / _NS_PER_S if start is not None and end is not None else 0.0,
        compression=tuple(sorted({ci.compression or "none" for ci in summary.chunk_indexes})),
        channels=channels, metadata=metadata,
    )


def _from_scan(p: Path, f: BinaryIO, size: int, has_summary: bool,
               progress: Callable[[int], None] | None) -> LogInfo:
    state = ScanState(size)
    header: Header | None = None
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    counts: dict[int, int] = {}
    first: dict[int, int] = {}
    last: dict[int, int] = {}
    metadata: list[MetadataInfo] = []
    compression: set[str] = set()
    chunks = 0

    def take(record: object) -> None:
        if isinstance(record, Schema):
            schemas.setdefault(record.id, record)
        elif isinstance(record, Channel):
            channels.setdefault(record.id, record)
        elif isinstance(record, Message) and not state.in_summary:
            cid, t = record.channel_id, record.log_time
            counts[cid] = counts.get(cid, 0) + 1
            first[cid] = min(first.get(cid, t), t)
            last[cid] = max(last.get(cid, t), t)

    for item in scan(f, size, state, progress):
        rec = item.record
        if isinstance(rec, Header):
            header = rec
        elif isinstance(rec, Metadata) and not state.in_summary:
            metadata.append(MetadataInfo(rec.name, tuple(sorted(rec.metadata.items()))))
        elif isinstance(rec, Chunk):
            if item.inner is None:
                continue
            chunks += 1
            compression.add(rec.compression or "none")
            for inner in item.inner:
                take(inner)
        else:
            take(rec)
    if header is None and state.end_offset <= len(MAGIC):
        raise LogFileError(p, f"no readable record after the magic bytes ({state.stop_reason})")
    known = {cid: n for cid, n in counts.items() if cid in channels}
    total = sum(known.values())
    starts = [first[c] for c in known]
    ends = [last[c] for c in known]
    start = min(starts) if starts else None
    end = max(ends) if ends else None
    return LogInfo(
        path=str(p), size_bytes=size,
        profile=header.profile if header else "", library=header.library if header else "",
        has_summary=has_summary, complete=state.footer is not None and not state.damaged_chunks,
        unreadable_bytes=state.bytes_unread, damaged_chunks=len(state.damaged_chunks),
        message_count=total, chunk_count=chunks, start_ns=start, end_ns=end,
        duration_s=(end - start) / _NS_PER_S if start is not None and end is not None else 0.0,
        compression=tuple(sorted(compression)),
        channels=tuple(_channel_info(ch, schemas, counts.get(cid, 0), first.get(cid), last.get(cid))
                       for cid, ch in sorted(channels.items())),
        metadata=tuple(metadata),
    )
