"""The `Controller` interface over the in-process core, and trajectory files."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.common.configfile import ConfigError
from drivers.controller.codes import Command, Subcode
from drivers.controller.errors import InvalidArgument, LeaseHeld, NotConnected, NotReady, TrajectoryRejected
from drivers.controller.interface import MotionStatus
from drivers.controller.trajectory import JointTrajectory
from drivers.controller.trajfile import load_trajectory
from drivers.emulator.local import LocalController
from drivers.robot.config import default_robot_config

RC = default_robot_config()
N = len(RC.joint_names)


def ready() -> LocalController:
    c = LocalController()
    c.connect()
    c.acquire_lease()
    c.command(Command.START_TRAJ_MODE)
    return c


def test_life_cycle_and_not_connected():
    c = LocalController()
    assert not c.is_connected
    with pytest.raises(NotConnected):
        c.status()
    with c:
        assert c.is_connected
        assert c.status().lease_holder == ""
    assert not c.is_connected


def test_move_to_and_wait():
    c = ready()
    target = np.linspace(-0.3, 0.3, N)
    h = c.move_to(target)
    assert h.wait(timeout=0.1) == MotionStatus.RUNNING and not h.done
    assert h.wait(timeout=10.0) == MotionStatus.SUCCEEDED and h.done
    assert np.allclose(c.joint_state().positions, target)


def test_execute_rejections_are_typed():
    c = ready()
    t = np.array([0.0, 1.0])
    p = np.zeros((2, N))
    p[0, 3] = 0.5  # not the current position
    with pytest.raises(TrajectoryRejected) as err:
        c.execute(JointTrajectory(RC.joint_names, t, p))
    assert err.value.subcode == Subcode.INVALID_DATA_START_POS and err.value.joint == RC.joint_names[3]
    c.command(Command.ESTOP)
    p[0, 3] = 0.0
    with pytest.raises(NotReady) as err:
        c.execute(JointTrajectory(RC.joint_names, t, p))
    assert err.value.subcode == Subcode.NOT_READY_ESTOP


def test_second_session_and_disconnect_stop():
    c = ready()
    other = LocalController(session="other")
    other.core = c.core  # same controller, another client
    other.connect()
    with pytest.raises(LeaseHeld):
        other.acquire_lease()
    h = c.move_to(np.full(N, 0.5))
    h.wait(timeout=0.2)
    assert c.status().in_motion
    c.disconnect()  # the holder goes away: the robot stops
    assert h.wait(timeout=2.0) == MotionStatus.ABORTED
    assert not other.status().in_motion
    other.acquire_lease()


def test_cancel():
    c = ready()
    h = c.move_to(np.full(N, 0.5))
    h.wait(timeout=0.2)
    h.cancel()
    assert h.wait(timeout=2.0) == MotionStatus.CANCELLED
    assert not c.status().in_motion and c.status().queue_count == 0


def test_grip():
    c = ready()
    c.grip("r2", True)
    assert c.core.grippers["r2"]
    with pytest.raises(InvalidArgument, match="r9"):
        c.grip("r9", True)


def test_trajectory_file(tmp_path):
    path = tmp_path / "t.yaml"
    zeros, tenths = [0.0] * N, [0.1] * N
    path.write_text(f"points:\n  - {{time: 0.0, positions: {zeros}}}\n"
                    f"  - {{time: 2.0, positions: {tenths}}}\n")
    traj = load_trajectory(path, RC)
    assert traj.joint_names == RC.joint_names and traj.velocities is None
    c = ready()
    assert c.execute(traj).wait(timeout=5.0) == MotionStatus.SUCCEEDED
    path.write_text("points:\n  - {time: 0.0, positions: [1, 2]}\n")
    with pytest.raises(ConfigError) as err:
        load_trajectory(path, RC)
    assert err.value.field == "points[0].positions"
    path.write_text(f"points:\n  - {{time: 0.0, positions: {zeros}, velocities: {zeros}}}\n"
                    f"  - {{time: 1.0, positions: {zeros}}}\n")
    with pytest.raises(ConfigError, match="velocities"):
        load_trajectory(path, RC)
