"""The session recorder: every valid sample on a cell's key space into MCAP, as the design says.

Topic `/` + key expression, schema `pkg/msg/Type` in `ros2msg`, message encoding `cdr`,
log time = receive time, publish time = the sender's stamp. The session is a rosbag2 bag folder
(`path`, or `path` without `.mcap`; see drivers/sessions/mcap/bag.py). Usable inside any process (the cell
daemon records its own session) or alone (`foldcell log record`).

Only a sample that decodes as its key's type (checked for size first, as every receiver does) is
logged as data. Anything else goes to `/diagnostics/rejected` (`foldcell_msgs/RejectedSample`: key,
size, reason, its first bytes), at most `rejected.per_second` a second (config/limits.yaml), so a
stranger's flood neither enters the session's data nor fills the disk.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from drivers.common.configfile import config_dir, load_fields, load_yaml, rule
from drivers.sessions.mcap.config import SessionLogConfig
from drivers.sessions.mcap.writer import SessionWriter
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import ROOT, check_size, type_for_full_key
from drivers.wire.transport import RawSample, Wire

log = logging.getLogger(__name__)

REJECTED_TOPIC = "/diagnostics/rejected"
REJECTED_TYPE = "foldcell_msgs/msg/RejectedSample"
NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class RejectionBounds:
    """How much of the refused samples the session keeps (config/limits.yaml `rejected`)."""

    per_second: int = rule(min=1)
    head_bytes: int = rule(min=0)


def load_rejection_bounds(path: Path | None = None) -> RejectionBounds:
    return load_fields(RejectionBounds, load_yaml(path or config_dir() / "limits.yaml").sub("rejected"))


@dataclass(frozen=True)
class RecorderStats:
    recorded: int
    rejected: int       # samples refused as data (logged or counted in /diagnostics/rejected)
    files: tuple[Path, ...]
    dropped: int = 0    # samples not recorded because the recorder was behind (max_backlog_bytes)
    bag: Path | None = None  # the bag folder holding `files` and metadata.yaml


class SessionRecorder:
    """Subscribes to `foldcell/<cell>/**` (cell may be `*`) and writes each valid sample as received."""

    def __init__(self, wire: Wire, path: Path, config: SessionLogConfig, *, cell: str | None = None,
                 metadata: dict[str, str] | None = None, rejection: RejectionBounds | None = None):
        self.cell = cell or wire.cell_id
        self.writer = SessionWriter.from_config(path, config, cell=self.cell, metadata=metadata)
        self.rejection = rejection or load_rejection_bounds()
        self.lock = threading.Lock()
        self.recorded = 0
        self.rejected = 0
        self.unlogged_rejections = 0  # over the rate bound since the last logged one
        self.rejection_second = -1
        self.last_unlogged: tuple[RawSample, str] | None = None
        self.rejections_this_second = 0
        self.closed = False
        self.known_types = set(messages.typestore().types)
        self.stop_flushing = threading.Event()
        if config.flush_interval_s:
            # a quiet moment must not keep the open chunk in memory: a timer writes it out when due
            threading.Thread(target=self._flush_when_due, name="recorder-flush", daemon=True).start()
        self.max_backlog_bytes = config.max_backlog_bytes
        self.drops_logged = 0   # backlog refusals already logged in the session
        self.validated: dict[str, bytes] = {}   # key -> the last valid sample's bytes after its stamp
        self.lane = wire.subscribe_raw(f"{ROOT}/{self.cell}/**", self._on_sample, name="recorder",
                                       max_backlog_bytes=config.max_backlog_bytes,
                                       batch_s=config.receive_batch_s)

    def _flush_when_due(self) -> None:
        wait = self.writer.flush_if_due()
        while wait is not None and not self.stop_flushing.wait(wait):
            wait = self.writer.flush_if_due()

    def _type_of(self, raw: RawSample) -> str:
        """The type the sample must decode as; WireError when there is none or it claims another."""
        try:
            type_name = type_for_full_key(raw.key)
        except WireError:
            # A key outside the registry: trust the type its encoding names, if we know it.
            if raw.type_name in self.known_types:
                return raw.type_name
            raise WireError(raw.key, f"carries no known ROS 2 type (encoding {raw.encoding!r})") from None
        if raw.type_name and raw.type_name != type_name:
            raise WireError(raw.key, f"sample is a {raw.type_name}, this key carries {type_name}")
        return type_name

    def _on_sample(self, raw: RawSample) -> None:
        if self.lane.dropped > self.drops_logged:
            self._log_backlog_drops(raw.receive_ns)
        if raw.is_delete:
            return
        try:
            type_name = self._type_of(raw)
            if not self._same_but_stamp(raw):
                check_size(raw.key, type_name, len(raw.payload))
                messages.decode(type_name, raw.payload, raw.key)
                if messages.has_leading_header(type_name):
                    self.validated[raw.key] = raw.payload[messages.HEADER_STAMP_END:]
        except WireError as err:
            self._reject(raw, err.problem)
            return
        with self.lock:
            if self.closed:
                return
            self.writer.write("/" + raw.key, type_name, messages.msgdef(type_name), raw.payload,
                              raw.receive_ns, raw.stamp_ns or raw.receive_ns)
            self.recorded += 1

    def _same_but_stamp(self, raw: RawSample) -> bool:
        """The sample repeats the last valid one on its key but for a valid stamp (a stream at rest):
        it is valid too, without decoding it again."""
        last = self.validated.get(raw.key)
        return (last is not None and raw.payload[messages.HEADER_STAMP_END:] == last
                and messages.leading_stamp_ns(raw.payload) is not None)

    def _reject(self, raw: RawSample, reason: str) -> None:
        """Log the refusal in /diagnostics/rejected, within the rate bound; count it either way."""
        with self.lock:
            if self.closed:
                return
            self.rejected += 1
            second = raw.receive_ns // NS_PER_S
            if second != self.rejection_second:
                self.rejection_second, self.rejections_this_second = second, 0
            if self.rejections_this_second >= self.rejection.per_second:
                self.unlogged_rejections += 1
                self.last_unlogged = (raw, reason)
                return
            self.rejections_this_second += 1
            self._write_rejected(raw, reason, dropped_before=self.unlogged_rejections)
            self.unlogged_rejections = 0
        log.warning("not logged as data: %s (%d bytes): %s", raw.key, len(raw.payload), reason)

    def _write_rejected(self, raw: RawSample, reason: str, dropped_before: int) -> None:
        entry = messages.new(REJECTED_TYPE, stamp=messages.stamp_from_ns(raw.receive_ns), key=raw.key,
                             encoding=raw.encoding, size=len(raw.payload), reason=reason,
                             head=np.frombuffer(raw.payload[:self.rejection.head_bytes], dtype=np.uint8),
                             dropped_before=dropped_before)
        self.writer.write(REJECTED_TOPIC, REJECTED_TYPE, messages.msgdef(REJECTED_TYPE),
                          messages.encode(REJECTED_TYPE, entry), raw.receive_ns, raw.receive_ns)

    def _log_backlog_drops(self, receive_ns: int) -> None:
        """Put the samples the lane refused while the recorder was behind on record in the session."""
        dropped = self.lane.dropped
        count, self.drops_logged = dropped - self.drops_logged, dropped
        reason = (f"the recorder fell behind: {count} sample(s) not recorded (more than "
                  f"{self.max_backlog_bytes} bytes waiting; log.max_backlog_bytes)")
        entry = messages.new(REJECTED_TYPE, stamp=messages.stamp_from_ns(receive_ns),
                             key=f"{ROOT}/{self.cell}/**", encoding="", size=0, reason=reason,
                             head=np.zeros(0, dtype=np.uint8), dropped_before=count - 1)
        with self.lock:
            if self.closed:
                return
            self.writer.write(REJECTED_TOPIC, REJECTED_TYPE, messages.msgdef(REJECTED_TYPE),
                              messages.encode(REJECTED_TYPE, entry), receive_ns, receive_ns)
        log.warning("%s", reason)

    def backlog(self) -> tuple[int, int]:
        """(samples, bytes) received and not yet written."""
        return self.lane.backlog()

    def stats(self) -> RecorderStats:
        with self.lock:
            return RecorderStats(self.recorded, self.rejected, tuple(self.writer.paths), self.lane.dropped,
                                 self.writer.bag)

    def close(self) -> RecorderStats:
        """Finish the file (summary and footer) and the bag's metadata. Close the Wire first so no
        sample is in flight."""
        self.stop_flushing.set()
        if self.lane.dropped > self.drops_logged:
            self._log_backlog_drops(time.time_ns())
        with self.lock:
            if not self.closed:
                if self.last_unlogged is not None and self.unlogged_rejections:
                    # the rejections over the last second's bound: described by the last, counted in it
                    raw, reason = self.last_unlogged
                    self._write_rejected(raw, reason, dropped_before=self.unlogged_rejections - 1)
                    self.unlogged_rejections = 0
                self.closed = True
                self.writer.close()
        return self.stats()
