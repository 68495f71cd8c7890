"""Robot time as data. Every stamp on the wire is wall time (ns since the epoch), the one time base ROS
tools and Foxglove line up; a controller whose robot time runs `time_scale` x faster (the emulator)
says in its `ControllerStatus` which robot time its stamp is, and that pair with the scale is the map
between the two for every stamp it sends."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from drivers.wire import messages


@dataclass(frozen=True)
class TimeBase:
    """robot = robot_ns + scale * (wall - wall_ns): one instant on both clocks and the rate between."""

    wall_ns: int    # a wall-clock instant, ns since the epoch
    robot_ns: int   # robot time at that instant, ns
    scale: float    # robot seconds per wall second

    def robot(self, wall_ns: int) -> int:
        """Robot time (ns) at wall time `wall_ns`."""
        return self.robot_ns + round((int(wall_ns) - self.wall_ns) * self.scale)

    def wall(self, robot_ns: int) -> int:
        """Wall time (ns) at robot time `robot_ns`."""
        return self.wall_ns + round((int(robot_ns) - self.robot_ns) / self.scale)


WALL = TimeBase(0, 0, 1.0)  # robot time is wall time (a real controller)


def timebase_of(status: Any) -> TimeBase:
    """The time base a `foldcell_msgs/ControllerStatus` message states (robot_time_ns 0: wall time)."""
    stamp = messages.stamp_to_ns(status.header.stamp)
    return TimeBase(stamp, int(status.robot_time_ns) or stamp, float(status.time_scale) or 1.0)
