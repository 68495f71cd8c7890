"""Wall-clock stamps and robot time: the emulator's clock stamps a tick with its wall time, and the
time base a status states gives robot time back; checked against exact rational arithmetic."""

from __future__ import annotations

import datetime as dt
import math
import time
from fractions import Fraction

import numpy as np
import pytest

from drivers.controller import codec
from drivers.controller.config import default_controller_config
from drivers.emulator.clock import RobotClock
from drivers.emulator.core import ControllerCore
from drivers.robot.config import default_robot_config
from drivers.wire import messages
from drivers.wire.timebase import TimeBase, timebase_of

PERIOD_NS = 4_000_000


def utc_midnight_ns() -> int:
    today = dt.datetime.now(dt.timezone.utc).replace(hour=0, minute=0, second=0, microsecond=0)
    return int(today.timestamp()) * 1_000_000_000


def exact_wall_ns(robot_ns: int, anchor_ns: int, scale: float) -> int:
    """robot = anchor + K (wall - anchor), solved for wall in exact rationals."""
    return round(anchor_ns + (robot_ns - anchor_ns) / Fraction(scale))


def exact_robot_ns(wall_ns: int, anchor_ns: int, scale: float) -> int:
    return round(anchor_ns + (wall_ns - anchor_ns) * Fraction(scale))


@pytest.mark.parametrize("scale", [1.0, 10.0, 3.7, 0.5])
def test_clock_stamps_a_tick_with_its_wall_time(scale: float):
    clock = RobotClock(scale, PERIOD_NS / 1e9)
    anchor = utc_midnight_ns()
    if round(clock.anchor * 1e9) != anchor:
        pytest.skip("the UTC day changed under the test")
    now = clock.tick()
    for tick in (now - 250_000, now - 1, now, now + 1, now + 37_501):
        stamp = clock.stamp_ns(tick)
        assert abs(stamp - exact_wall_ns(tick * PERIOD_NS, anchor, scale)) <= 1
        assert clock.stamp_tick(stamp) == tick
    # the stamp of the tick robot time is in is now on the wall clock, not hours away
    wall_tick_ns = PERIOD_NS / scale
    assert abs(clock.stamp_ns(clock.tick()) - time.time_ns()) <= wall_tick_ns + 50_000_000


def test_time_base_against_exact_arithmetic():
    rng = np.random.default_rng(7)
    anchor = utc_midnight_ns()
    for scale in (1.0, 10.0, 2.5, 0.25):
        # a status of this controller: its stamp and the robot time of that stamp
        status_wall = anchor + int(rng.integers(0, 86_400 * 10**9))
        base = TimeBase(status_wall, exact_robot_ns(status_wall, anchor, scale), scale)
        for _ in range(50):
            wall = status_wall + int(rng.integers(-10**12, 10**12))
            assert abs(base.robot(wall) - exact_robot_ns(wall, anchor, scale)) <= math.ceil(scale)
            robot = exact_robot_ns(wall, anchor, scale)
            assert abs(base.wall(robot) - wall) <= 1 + math.ceil(0.5 / scale)  # robot was rounded


def test_status_states_robot_time_and_joint_states_follow_it():
    rc, cfg = default_robot_config(), default_controller_config()
    clock = RobotClock(10.0, PERIOD_NS / 1e9)
    tick = clock.tick()
    core = ControllerCore(rc, cfg, "both", tick=tick)
    msg = codec.status_msg(core.status(), clock.stamp_ns(tick), 10.0, robot_ns=clock.tick_ns(tick))
    msg = messages.decode(codec.STATUS_TYPE, messages.encode(codec.STATUS_TYPE, msg))
    assert messages.stamp_to_ns(msg.header.stamp) == clock.stamp_ns(tick)
    assert msg.robot_time_ns == tick * PERIOD_NS
    assert codec.status_from_msg(msg).stamp == pytest.approx(tick * PERIOD_NS * 1e-9, abs=1e-9)
    js = codec.joint_state_msg(rc.joint_names)
    later = tick + 1234
    js.header.stamp = messages.stamp_from_ns(clock.stamp_ns(later))
    feedback = codec.feedback_from_msg(js, timebase_of(msg))
    assert feedback.stamp == pytest.approx(later * PERIOD_NS * 1e-9, abs=1e-7)


def test_status_without_robot_time_is_wall_time():
    rc, cfg = default_robot_config(), default_controller_config()
    msg = codec.status_msg(ControllerCore(rc, cfg, "both").status(), 5_000_000_000, 1.0)
    assert msg.robot_time_ns == 5_000_000_000
    msg.robot_time_ns = 0  # an older controller or session: robot time is the stamp
    assert timebase_of(msg) == TimeBase(5_000_000_000, 5_000_000_000, 1.0)
