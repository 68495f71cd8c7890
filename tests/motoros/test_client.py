"""`MotorosController` (the cell's controller interface over MotoROS) against the emulator's MotoROS
server on loopback TCP, both dialects: status and joint state from the state port, a streamed trajectory
longer than the queue, refusals as typed errors, grippers as outputs, an e-stop aborting a motion."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from drivers.controller.codes import Command
from drivers.controller.errors import InvalidArgument, NotReady, TrajectoryRejected
from drivers.controller.interface import MotionStatus
from drivers.controller.motoros_client import MotorosController
from drivers.controller.trajectory import JointTrajectory
from drivers.robot.config import default_robot_config
from tests.conftest import wait_until
from tests.motoros.test_server import Cell, running

NAMES = default_robot_config().joint_names


@pytest.fixture(params=["upstream", "clopema"])
def connected(request: pytest.FixtureRequest) -> Iterator[tuple[Cell, MotorosController]]:
    for cell in running(request.param):
        ctl = MotorosController("127.0.0.1", cell.motion_port, request.param)
        ctl.connect(timeout=10)
        yield cell, ctl
        ctl.disconnect()


def blend(goal: np.ndarray, duration: float, count: int) -> JointTrajectory:
    """Rest to rest from home to `goal`, cosine blend, consistent velocities."""
    times = np.linspace(0.0, duration, count)
    s = 0.5 - 0.5 * np.cos(np.pi * times / duration)
    ds = 0.5 * np.pi / duration * np.sin(np.pi * times / duration)
    velocities = np.outer(ds, goal)
    velocities[-1] = 0.0
    return JointTrajectory(NAMES, times, np.outer(s, goal), velocities)


def test_status_joint_state_and_a_streamed_trajectory(connected: tuple[Cell, MotorosController]) -> None:
    cell, ctl = connected
    assert not ctl.status().motion_possible and ctl.status().mode == 2
    with pytest.raises(NotReady) as info:
        ctl.command(Command.CHECK_MOTION_READY)
    ctl.acquire_lease()
    with pytest.raises(NotReady):
        ctl.execute(blend(np.full(13, 0.1), 1.0, 5))
    ctl.command(Command.START_TRAJ_MODE)
    assert wait_until(lambda: ctl.status().motion_possible and ctl.status().drives_powered)
    goal = np.array([0.3, 0.1, -0.2, 0.2, 0.1, -0.3, -0.3, 0.1, 0.2, -0.2, 0.1, 0.3, 0.25])
    handle = ctl.execute(blend(goal, 2.0, 11))  # 2 s against a 0.8 s queue: BUSY retries
    assert handle.wait(30) == MotionStatus.SUCCEEDED
    assert np.allclose(ctl.joint_state().positions, goal, atol=1e-4)
    assert np.allclose(cell.q(), goal, atol=1e-6)
    assert info.value.subcode == (0 if ctl.dialect.name == "clopema" else 5006)  # servos were off; the fork
    # answers FALSE without a subcode


def test_refusals_are_typed_errors(connected: tuple[Cell, MotorosController]) -> None:
    _, ctl = connected
    ctl.command(Command.START_TRAJ_MODE)
    away = blend(np.full(13, 0.2), 1.0, 3)
    shifted = JointTrajectory(NAMES, away.times, away.positions + 0.01, away.velocities)
    with pytest.raises(TrajectoryRejected) as info:
        ctl.execute(shifted)
    assert (info.value.subcode, info.value.point) == (3011, 0)
    with pytest.raises(InvalidArgument):
        ctl.command(Command.HOLD)  # not a MotoROS command


def test_move_to_and_stop(connected: tuple[Cell, MotorosController]) -> None:
    _, ctl = connected
    ctl.command(Command.START_TRAJ_MODE)
    target = np.zeros(13)
    target[0] = 1.5
    handle = ctl.move_to(target)
    assert wait_until(lambda: abs(ctl.joint_state().positions[0]) > 0.05)
    handle.cancel()
    assert handle.wait(10) == MotionStatus.CANCELLED
    assert ctl.joint_state().positions[0] < 1.4
    assert ctl.move_to(ctl.joint_state().positions).wait(10) == MotionStatus.SUCCEEDED


def test_an_estop_aborts_the_motion(connected: tuple[Cell, MotorosController]) -> None:
    cell, ctl = connected
    ctl.command(Command.START_TRAJ_MODE)
    handle = ctl.execute(blend(np.full(13, 0.3), 2.0, 9))
    assert wait_until(lambda: abs(ctl.joint_state().positions[0]) > 0.01)
    with cell.lock:
        cell.core.estop()
    assert handle.wait(10) == MotionStatus.ABORTED
    assert wait_until(lambda: ctl.status().e_stopped)


def test_grippers_are_outputs(connected: tuple[Cell, MotorosController]) -> None:
    cell, ctl = connected
    if ctl.dialect.name == "clopema":
        pytest.skip("the fork takes no IO messages")
    ctl.grip("r2", True)
    with cell.lock:
        assert cell.core.grippers == {"r1": False, "r2": True}
    assert ctl.gripper_states() == {"r1": False, "r2": True}   # read back from the outputs
    ctl.grip("r2", False)
    with cell.lock:
        assert cell.core.grippers == {"r1": False, "r2": False}
    assert ctl.gripper_states() == {"r1": False, "r2": False}
