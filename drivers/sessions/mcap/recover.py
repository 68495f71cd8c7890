"""`log recover`: turn a file cut short (a crash, a full disk) into a valid MCAP file.

The source is read linearly record by record (it has no usable footer), stopping at the first
record that does not fit or does not parse. Every chunk whose CRC and compression check is kept
with all its messages, as is every whole message record outside chunks; schemas, channels,
metadata and attachments are carried over; the output gets fresh chunks, message and chunk
indexes, statistics, a summary and a footer. Like the reference `mcap recover`, the report says
whether data was lost so the CLI can exit 3 in that case.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from mcap.records import Attachment, Channel, Chunk, Header, McapRecord, Message, Metadata, Schema
from mcap.writer import CompressionType, Writer

from drivers.sessions.mcap.config import COMPRESSIONS
from drivers.sessions.mcap.errors import LogFileError
from drivers.sessions.mcap.scan import MAGIC, ScanState, open_log, scan
from drivers.sessions.mcap.writer import DEFAULT_CHUNK_SIZE, foldcell_version

logger = logging.getLogger(__name__)

_COMPRESSION = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}
_PARTIAL_SUFFIX = ".partial"


@dataclass(frozen=True)
class RecoverReport:
    """What `recover` kept and dropped.

    bytes_dropped: bytes of the source after the last whole record (0 for a complete file).
    data_lost: the data section was cut before its end (whatever followed the cut, and the chunk the
    writer held in memory, are gone), a chunk was damaged, or messages were dropped because their
    channel was lost. A complete file, or one cut only inside its summary, loses nothing.
    """

    source: str
    output: str
    source_complete: bool
    messages_kept: int
    chunks_kept: int
    chunks_damaged: int
    messages_without_channel: int
    bytes_read: int
    bytes_dropped: int
    stop_reason: str | None
    data_lost: bool

    def to_json_dict(self) -> dict[str, Any]:
        return asdict(self)


def recover(src: str | Path, dst: str | Path, *, compression: str = "zstd",
            chunk_size: int = DEFAULT_CHUNK_SIZE,
            progress: Callable[[int], None] | None = None) -> RecoverReport:
    """Write what survives of `src` to `dst` as a valid MCAP file and report what was lost.

    Raises LogFileError when `src` is missing, unreadable, not MCAP or has no header, or when
    `dst` is `src` or cannot be written. `dst` is replaced only once the new file is complete.
    """
    src_p, dst_p = Path(src), Path(dst)
    if compression not in COMPRESSIONS:
        raise ValueError(f"compression: must be one of {', '.join(COMPRESSIONS)}, got {compression!r}")
    if chunk_size <= 0:
        raise ValueError(f"chunk_size: must be > 0, got {chunk_size}")
    f, size = open_log(src_p)
    with f:
        if dst_p.exists() and dst_p.resolve() == src_p.resolve():
            raise LogFileError(dst_p, "the output must not be the file being recovered")
        partial = dst_p.with_name(dst_p.name + _PARTIAL_SUFFIX)
        try:
            out = open(partial, "wb")  # noqa: SIM115 - closed below
        except OSError as exc:
            raise LogFileError(dst_p, f"cannot create: {exc.strerror or exc}") from exc
        try:
            with out:
                report = _copy(src_p, dst_p, f, size, out, compression, chunk_size, progress)
            os.replace(partial, dst_p)
        except BaseException:
            partial.unlink(missing_ok=True)
            raise
    # Info, not warning: callers (the CLI, the daemon) report loss from the returned report.
    logger.info("recovered %s -> %s: %d messages in %d chunks kept, %d bytes dropped (%s)", src_p, dst_p,
        report.messages_kept, report.chunks_kept, report.bytes_dropped, report.stop_reason or "complete")
    return report


class _Copier:
    """Re-registers schemas and channels under new ids and copies messages into a fresh writer."""

    def __init__(self, writer: Writer):
        self.writer = writer
        self.schema_ids: dict[int, int] = {0: 0}
        self.channel_ids: dict[int, int] = {}
        self.messages = 0
        self.orphans = 0

    def take(self, record: McapRecord) -> None:
        if isinstance(record, Schema):
            if record.id not in self.schema_ids:
                self.schema_ids[record.id] = self.writer.register_schema(
                    name=record.name, encoding=record.encoding, data=record.data)
        elif isinstance(record, Channel):
            if record.id not in self.channel_ids and record.schema_id in self.schema_ids:
                self.channel_ids[record.id] = self.writer.register_channel(
                    topic=record.topic, message_encoding=record.message_encoding,
                    schema_id=self.schema_ids[record.schema_id], metadata=dict(record.metadata))
        elif isinstance(record, Message):
            channel_id = self.channel_ids.get(record.channel_id)
            if channel_id is None:
                self.orphans += 1
                return
            self.writer.add_message(channel_id=channel_id, log_time=record.log_time, data=record.data,
                                    publish_time=record.publish_time, sequence=record.sequence)
            self.messages += 1
        elif isinstance(record, Metadata):
            self.writer.add_metadata(record.name, dict(record.metadata))
        elif isinstance(record, Attachment):
            self.writer.add_attachment(create_time=record.create_time, log_time=record.log_time,
                                       name=record.name, media_type=record.media_type, data=record.data)


def _copy(src_p: Path, dst_p: Path, f: Any, size: int, out: Any, compression: str, chunk_size: int,
          progress: Callable[[int], None] | None) -> RecoverReport:
    state = ScanState(size)
    f.seek(len(MAGIC))
    records = scan(f, size, state, progress)
    first = next(records, None)
    if first is None or not isinstance(first.record, Header):
        raise LogFileError(src_p, "no header record after the magic bytes; nothing to recover")
    header = first.record
    writer = Writer(out, chunk_size=chunk_size, compression=_COMPRESSION[compression])
    library = f"{header.library} (recovered by foldcell/{foldcell_version()})".strip()
    writer.start(profile=header.profile, library=library)
    copier = _Copier(writer)
    chunks_kept = 0
    for item in records:
        if state.in_summary:
            continue  # the summary repeats data-section records; the writer makes a new one
        if isinstance(item.record, Chunk):
            if item.inner is None:
                continue  # damaged: counted by the scan
            chunks_kept += 1
            for inner in item.inner:
                copier.take(inner)
        else:
            copier.take(item.record)
    writer.finish()
    lost = bool(state.damaged_chunks) or copier.orphans > 0 or state.data_section_cut
    return RecoverReport(
        source=str(src_p), output=str(dst_p), source_complete=state.footer is not None,
        messages_kept=copier.messages, chunks_kept=chunks_kept, chunks_damaged=len(state.damaged_chunks),
        messages_without_channel=copier.orphans, bytes_read=state.end_offset,
        bytes_dropped=state.bytes_unread, stop_reason=state.stop_reason, data_lost=lost,
    )
