"""Linear, record-by-record reading of an MCAP file that may be cut short or damaged.

Used by `info` (files without a summary) and `recover`. Reading stops at the first record whose
framing does not fit in the file or does not parse; a chunk whose framing is whole but whose
CRC or compression fails is reported and skipped (its length is still trusted to find the next record).
"""

from __future__ import annotations

import io
import logging
import struct
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import breakup_chunk

from drivers.sessions.mcap.errors import LogFileError

logger = logging.getLogger(__name__)

MAGIC = b"\x89MCAP0\r\n"
_RECORD_PREFIX = 9  # opcode (1) + length (8)

_READERS: dict[int, Callable[[ReadDataStream], McapRecord]] = {
    Opcode.ATTACHMENT: Attachment.read,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex.read,
    Opcode.CHANNEL: Channel.read,
    Opcode.CHUNK: Chunk.read,
    Opcode.CHUNK_INDEX: ChunkIndex.read,
    Opcode.DATA_END: DataEnd.read,
    Opcode.FOOTER: Footer.read,
    Opcode.HEADER: Header.read,
    Opcode.MESSAGE_INDEX: MessageIndex.read,
    Opcode.METADATA: Metadata.read,
    Opcode.METADATA_INDEX: MetadataIndex.read,
    Opcode.SCHEMA: Schema.read,
    Opcode.STATISTICS: Statistics.read,
    Opcode.SUMMARY_OFFSET: SummaryOffset.read,
}


@dataclass(frozen=True)
class ScannedRecord:
    """One whole record at `offset` (of `length` bytes including its 9-byte prefix).

    For a chunk whose CRC and compression check, `inner` holds its schemas, channels and messages;
    for a damaged chunk `inner` is None and `damage` says why.
    """

    offset: int
    length: int
    record: McapRecord
    inner: list[McapRecord] | None = None
    damage: str | None = None


@dataclass
class ScanState:
    """What the scan found besides the records: where it stopped and why."""

    size: int
    end_offset: int = 0          # offset just past the last whole record read
    footer: Footer | None = None  # set when the file ends properly
    stop_reason: str | None = None  # why reading stopped early (None: reached the footer and end magic)
    in_summary: bool = False      # a DataEnd record was seen
    damaged_chunks: list[int] = field(default_factory=list)  # offsets of chunks skipped

    @property
    def bytes_unread(self) -> int:
        return self.size - self.end_offset

    @property
    def data_section_cut(self) -> bool:
        """True when reading stopped before the data section's end (DataEnd): later data is gone."""
        return self.footer is None and not self.in_summary


def open_log(path: str | Path) -> tuple[BinaryIO, int]:
    """Open a log file for reading and check its magic; errors name the path."""
    p = Path(path)
    try:
        f = open(p, "rb")  # noqa: SIM115 - handed to the caller
    except OSError as exc:
        raise LogFileError(p, f"cannot open: {exc.strerror or exc}") from exc
    try:
        size = p.stat().st_size
        head = f.read(len(MAGIC))
    except OSError as exc:
        f.close()
        raise LogFileError(p, f"cannot read: {exc.strerror or exc}") from exc
    if head != MAGIC:
        f.close()
        if len(head) < len(MAGIC):
            raise LogFileError(p, f"not an MCAP file (only {len(head)} bytes, fewer than the 8-byte magic)")
        raise LogFileError(p, "not an MCAP file (bad magic bytes at the start)")
    return f, size


def scan(f: BinaryIO, size: int, state: ScanState,
         progress: Callable[[int], None] | None = None) -> Iterator[ScannedRecord]:
    """Yield every whole record after the magic, in file order; fill `state` on the way.

    `f` must be positioned just after the leading magic. `progress(n)` is called with bytes consumed.
    """
    offset = len(MAGIC)
    state.end_offset = offset
    while True:
        prefix = f.read(_RECORD_PREFIX)
        if len(prefix) == 0:
            state.stop_reason = "file ends without a footer"
            return
        if len(prefix) < _RECORD_PREFIX:
            state.stop_reason = f"record prefix cut short at byte {offset}"
            return
        opcode, length = struct.unpack("<BQ", prefix)
        if offset + _RECORD_PREFIX + length > size:
            state.stop_reason = (f"{_name(opcode)} record at byte {offset} needs {length} bytes, "
                                 f"only {size - offset - _RECORD_PREFIX} left")
            return
        body = f.read(length)
        if len(body) < length:
            state.stop_reason = f"{_name(opcode)} record at byte {offset} cut short while reading"
            return
        try:
            record = _parse(opcode, body)
        except Exception as exc:  # any parse failure means the record is corrupt
            state.stop_reason = f"{_name(opcode)} record at byte {offset} is corrupt: {exc}"
            return
        whole = _RECORD_PREFIX + length
        item: ScannedRecord | None = None
        if isinstance(record, Chunk):
            try:
                inner = breakup_chunk(record, validate_crc=True)
                item = ScannedRecord(offset, whole, record, inner=inner)
            except Exception as exc:  # CRC, zstd, lz4 or framing failure inside
                logger.warning("chunk at byte %d is damaged, skipped: %s", offset, exc)
                state.damaged_chunks.append(offset)
                item = ScannedRecord(offset, whole, record, damage=str(exc) or type(exc).__name__)
        elif record is not None:
            item = ScannedRecord(offset, whole, record)
        offset += whole
        state.end_offset = offset
        if progress is not None:
            progress(whole)
        if isinstance(record, DataEnd):
            state.in_summary = True
        if item is not None:
            yield item
        if isinstance(record, Footer):
            end_magic = f.read(len(MAGIC))
            if end_magic != MAGIC:
                state.stop_reason = "footer is not followed by the closing magic bytes"
                return
            state.footer = record
            state.end_offset = offset + len(MAGIC)
            state.stop_reason = None
            return


def _parse(opcode: int, body: bytes) -> McapRecord | None:
    stream = ReadDataStream(io.BytesIO(body))
    if opcode == Opcode.MESSAGE:
        return Message.read(stream, len(body))
    reader = _READERS.get(opcode)
    if reader is None:
        return None  # unknown record kinds are skipped, as the MCAP spec asks
    record = reader(stream)
    if stream.count > len(body):
        raise ValueError("fields run past the record's length")
    if isinstance(record, Chunk) and len(record.data) != _chunk_data_len(body):
        raise ValueError("chunk data shorter than its declared size")
    return record


def _chunk_data_len(body: bytes) -> int:
    # Chunk layout: start(8) end(8) uncompressed_size(8) crc(4) compression(str) compressed_size(8) data
    (clen,) = struct.unpack_from("<I", body, 28)
    (dlen,) = struct.unpack_from("<Q", body, 32 + clen)
    return dlen


def _name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"unknown (opcode {opcode:#x})"


