"""The MotoROS server without the Zenoh node: a core stepped to robot time on a thread (tests, benches)."""

from __future__ import annotations

import threading
from collections.abc import Callable

from drivers.emulator.clock import RobotClock
from drivers.emulator.core import ControllerCore


class CoreLoop:
    """Steps a core to robot time on a thread of its own and calls `on_tick` after every tick, as the
    node's loop does in a process."""

    def __init__(self, core: ControllerCore, lock: threading.RLock, on_tick: Callable[[], None],
                 time_scale: float = 1.0):
        self.core, self.lock, self.on_tick = core, lock, on_tick
        self.clock = RobotClock(time_scale, core.period)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True, name="motoros-core-loop")

    def start(self) -> None:
        with self.lock:
            self.core.tick = self.clock.tick()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)

    def _run(self) -> None:
        while not self._stop.is_set():
            with self.lock:
                for _ in range(max(self.clock.tick() - self.core.tick, 0)):
                    self.core.step()
                    self.on_tick()
            self._stop.wait(self.core.period)
