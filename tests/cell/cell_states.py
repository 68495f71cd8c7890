"""A watcher's record of every `cell/state`, with its arrival time: what the fault tests and benches wait
on (tests/cell/partition_run.py, tests/bench/bench_faults.py, tests/bench/bench_chaos.py)."""

from __future__ import annotations

import threading
import time
from typing import Any

from drivers.wire.transport import Wire


class CellStates:
    def __init__(self, wire: Wire):
        self.seen: list[tuple[float, Any]] = []   # (monotonic arrival, CellState)
        self.changed = threading.Condition()
        wire.subscribe("cell/state", self._on)

    def _on(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.changed:
            self.seen.append((time.monotonic(), msg))
            self.changed.notify_all()

    def first(self, states: set[str], since: float, timeout: float) -> tuple[float, Any] | None:
        """The first state in `states` that arrived at or after `since` (monotonic), waiting up to
        `timeout` s; None if none came."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for at, msg in self.seen:
                    if at >= since and msg.state in states:
                        return at, msg
                if time.monotonic() > deadline:
                    return None
                self.changed.wait(0.1)

    def last(self) -> str:
        with self.changed:
            return self.seen[-1][1].state if self.seen else ""
