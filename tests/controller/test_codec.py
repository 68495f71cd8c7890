"""Pure tests of the emulator's wire codec and robot clock (no Zenoh)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.controller import codec
from drivers.controller.codes import Command, Reply, Result, Subcode
from drivers.controller.config import default_controller_config
from drivers.controller.trajectory import JointTrajectory
from drivers.emulator.clock import RobotClock
from drivers.emulator.core import ControllerCore
from drivers.robot.config import default_robot_config
from drivers.wire import messages


def test_status_round_trip_keeps_flags_and_groups():
    rc, cfg = default_robot_config(), default_controller_config()
    core = ControllerCore(rc, cfg, "both")
    core.command(300030, "alive/x")  # lease
    core.command(200121, "alive/x")  # servo on
    core.estop()
    msg = codec.status_msg(core.status(), 123_000_000, 4.0, {"R2": False})
    back = codec.status_from_msg(messages.decode(codec.STATUS_TYPE, messages.encode(codec.STATUS_TYPE, msg)))
    assert back.e_stopped and not back.drives_powered and back.lease_holder == "alive/x"
    assert [g.name for g in back.groups] == ["R1", "R2", "B1"]
    assert msg.groups[1].link_ok == 0 and msg.groups[0].link_ok == 1 and msg.time_scale == 4.0
    assert back.stamp == pytest.approx(0.123)


@pytest.mark.parametrize("with_velocities", [True, False])
def test_trajectory_round_trip(with_velocities):
    rng = np.random.default_rng(3)
    names = default_robot_config().joint_names
    for _ in range(20):
        k = int(rng.integers(2, 9))
        pos = rng.uniform(-1, 1, (k, 13))
        vel = rng.uniform(-1, 1, (k, 13)) if with_velocities else None
        times = np.cumsum(rng.uniform(0.01, 1.0, k)) - 0.01
        times[0] = 0.0
        msg = codec.trajectory_msg(JointTrajectory(names, times, pos[:, ::1], vel, "fold"), 8_000_000)
        data = messages.encode(codec.TRAJECTORY_TYPE, msg)
        back = codec.trajectory_from_msg(messages.decode(codec.TRAJECTORY_TYPE, data))
        assert back.joint_names == names and back.label == "fold"
        assert messages.stamp_to_ns(msg.header.stamp) == 8_000_000
        np.testing.assert_array_equal(back.positions, pos)
        np.testing.assert_allclose(back.times, times, atol=1e-9)
        assert (back.velocities is None) == (not with_velocities)


def test_trajectory_from_column_slice_encodes():
    names = default_robot_config().joint_names
    pos = np.zeros((3, 13))
    traj = JointTrajectory(names[:6], np.array([0.0, 1.0, 2.0]), pos[:, :6], pos[:, :6])
    messages.encode(codec.TRAJECTORY_TYPE, codec.trajectory_msg(traj))


def test_short_point_is_named():
    names = default_robot_config().joint_names
    msg = codec.trajectory_msg(JointTrajectory(names, np.array([0.0, 1.0]), np.zeros((2, 13))))
    msg.points[1].positions = np.zeros(12)
    with pytest.raises(codec.MalformedTrajectory) as err:
        codec.trajectory_from_msg(msg)
    assert err.value.point == 1


def test_time_from_start_is_exact_to_the_nanosecond():
    cases = ((0.0, 0, 0), (1.5, 1, 500_000_000), (2.000000001, 2, 1), (0.004, 0, 4_000_000))
    for seconds, sec, nanosec in cases:
        duration = messages.duration_from_s(seconds)
        assert (duration.sec, duration.nanosec) == (sec, nanosec)
        assert messages.duration_to_s(duration) == pytest.approx(seconds, abs=1e-12)


def test_command_round_trip():
    msg = codec.command_msg(Command.JOG, "alive/me", joint="r1_joint_s", values=np.array([0.25]),
                            stamp_ns=7)
    back = messages.decode(codec.COMMAND_TYPE, messages.encode(codec.COMMAND_TYPE, msg))
    assert (back.command, back.client, back.joint) == (Command.JOG, "alive/me", "r1_joint_s")
    assert list(back.values) == [0.25]
    assert messages.stamp_to_ns(back.header.stamp) == 7


def test_reply_round_trip():
    r = Reply(Result.INVALID, Subcode.INVALID_DATA_SPEED, "too fast", 3, "r1_joint_s", 0)
    assert codec.reply_from_msg(codec.reply_msg(r, 5, 0)) == r


def test_robot_clock_two_instances_agree_and_scale():
    a, b = RobotClock(5.0, 0.004), RobotClock(5.0, 0.004)
    assert abs(a.tick() - b.tick()) <= 1
    t0 = a.robot_time(100.0)
    assert a.robot_time(101.0) - t0 == pytest.approx(5.0)
    assert a.tick_ns(123456789) == 123456789 * 4_000_000
    with pytest.raises(ValueError):
        RobotClock(0.0, 0.004)
