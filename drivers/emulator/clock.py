"""Robot time for emulator processes: shared by master and slave, running `time_scale` x wall time.

Robot time = anchor + K * (wall - anchor), with the anchor at the UTC midnight before the process
started. At K = 1 robot time is wall time; at any K two processes of one machine (or of NTP-synced
machines) started the same day agree on every tick, so the master and the slave can start their halves
of a trajectory on the same interpolation tick without a handshake. A monotonic clock drives it after
start-up, so wall-clock steps do not make the robot jump.

Robot time never goes on the wire as a stamp: a tick is stamped with the wall time it corresponds to
(`stamp_ns`), and a stamp read back names its tick (`stamp_tick`); the status carries the robot time.
"""

from __future__ import annotations

import math
import time

from drivers.wire.timebase import TimeBase

_DAY_S = 86400.0


class RobotClock:
    def __init__(self, time_scale: float, period: float, anchor: float | None = None):
        if not (time_scale > 0 and math.isfinite(time_scale)):
            raise ValueError(f"time_scale must be a finite number > 0, got {time_scale}")
        self.time_scale = float(time_scale)
        self.period = float(period)
        self.period_ns = round(period * 1e9)
        wall = time.time()
        self._mono0 = time.monotonic()
        self._wall0 = wall
        self.anchor = math.floor(wall / _DAY_S) * _DAY_S if anchor is None else float(anchor)
        anchor_ns = round(self.anchor * 1e9)
        self.timebase = TimeBase(anchor_ns, anchor_ns, self.time_scale)

    def robot_time(self, mono: float | None = None) -> float:
        """Robot time (s) at monotonic time `mono` (default now)."""
        mono = time.monotonic() if mono is None else mono
        wall = self._wall0 + (mono - self._mono0)
        return self.anchor + self.time_scale * (wall - self.anchor)

    def tick(self, mono: float | None = None) -> int:
        """The interpolation tick robot time is in."""
        return math.floor(self.robot_time(mono) / self.period)

    def tick_ns(self, tick: int) -> int:
        """Robot time of a tick in ns (exact integer arithmetic)."""
        return int(tick) * self.period_ns

    def stamp_ns(self, tick: int) -> int:
        """The wall-clock stamp (ns since the epoch) of a tick."""
        return self.timebase.wall(self.tick_ns(tick))

    def stamp_tick(self, stamp_ns: int) -> int:
        """The tick a wall-clock stamp of this clock names."""
        return round(self.timebase.robot(stamp_ns) / self.period_ns)
