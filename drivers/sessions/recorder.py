"""The session recorder: every sample on a cell's key space into MCAP, as the design says.

Topic `/` + key expression, schema `pkg/msg/Type` in `ros2msg`, message encoding `cdr`,
log time = receive time, publish time = the sender's stamp. Usable inside any process (the cell
daemon records its own session) or alone (`foldcell log record`).
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from pathlib import Path

from drivers.sessions.mcap.config import SessionLogConfig
from drivers.sessions.mcap.writer import SessionWriter
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import ROOT, type_for_full_key
from drivers.wire.transport import RawSample, Wire

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecorderStats:
    recorded: int
    skipped: int
    files: tuple[Path, ...]


class SessionRecorder:
    """Subscribes to `foldcell/<cell>/**` (cell may be `*`) and writes each sample as received."""

    def __init__(self, wire: Wire, path: Path, config: SessionLogConfig, *, cell: str | None = None,
                 metadata: dict[str, str] | None = None):
        self.cell = cell or wire.cell_id
        path.parent.mkdir(parents=True, exist_ok=True)
        self.writer = SessionWriter.from_config(path, config, cell=self.cell, metadata=metadata)
        self.lock = threading.Lock()
        self.recorded = 0
        self.skipped = 0
        self.closed = False
        self.known_types = set(messages.typestore().types)
        self.stop_flushing = threading.Event()
        if config.flush_interval_s:
            # a quiet topic must not keep its chunk in memory: write chunks out on a timer too
            threading.Thread(target=self._flush_periodically, args=(config.flush_interval_s,),
                             name="recorder-flush", daemon=True).start()
        wire.subscribe_raw(f"{ROOT}/{self.cell}/**", self._on_sample, name="recorder")

    def _flush_periodically(self, interval: float) -> None:
        while not self.stop_flushing.wait(interval):
            self.writer.flush()

    def _type_of(self, raw: RawSample) -> str | None:
        try:
            return type_for_full_key(raw.key)
        except WireError:
            pass
        # A key outside the registry: trust the type its encoding names, if we know it.
        return raw.type_name if raw.type_name in self.known_types else None

    def _on_sample(self, raw: RawSample) -> None:
        if raw.is_delete:
            return
        type_name = self._type_of(raw)
        with self.lock:
            if self.closed:
                return
            if type_name is None:
                self.skipped += 1
                log.warning("not recorded: %s carries no known ROS 2 type (encoding %r)",
                            raw.key, raw.encoding)
                return
            self.writer.write("/" + raw.key, type_name, messages.msgdef(type_name), raw.payload,
                              raw.receive_ns, raw.stamp_ns or raw.receive_ns)
            self.recorded += 1

    def stats(self) -> RecorderStats:
        with self.lock:
            return RecorderStats(self.recorded, self.skipped, tuple(self.writer.paths))

    def close(self) -> RecorderStats:
        """Finish the file (summary and footer). Close the Wire first so no sample is in flight."""
        self.stop_flushing.set()
        with self.lock:
            if not self.closed:
                self.closed = True
                self.writer.close()
        return self.stats()
