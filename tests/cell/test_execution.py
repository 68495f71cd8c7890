"""The cell's motion executor against the emulator as a real process: a trajectory sent while a stop is
still braking (the controller answers BUSY) is sent again and runs to its end."""

from __future__ import annotations

import numpy as np
import pytest

from cell.config import load_cell_config
from cell.errors import StepFailed
from cell.execution import MotionExecutor
from drivers.controller.codes import Command, Result
from drivers.controller.errors import ControllerError
from drivers.controller.motion import plan_point_to_point
from drivers.controller.trajectory import JointTrajectory
from drivers.controller.zenoh_client import ZenohController
from drivers.wire.transport import Wire
from tests.conftest import Endpoint, Proc, foldcell_argv, wait_until
from tests.emulator.test_process import CFG, RC, make_ready


@pytest.fixture(scope="module")
def controller(tmp_path_factory):
    ep = Endpoint("exec")
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", *ep.args()),
                tmp_path_factory.mktemp("exec") / "serve.log")
    wire = Wire(ep.settings(), "executor")
    ctl = ZenohController(wire)
    try:
        ctl.connect(timeout=30)
        ctl.acquire_lease()
        yield ctl
    finally:
        wire.close()
        proc.stop()


def motion(start: np.ndarray, delta: float) -> JointTrajectory:
    times, positions, velocities = plan_point_to_point(start, start + delta, RC.max_velocity * 0.5,
                                                       RC.max_acceleration * 0.5, RC.max_jerk * 0.5,
                                                       CFG.max_points)
    return JointTrajectory(RC.joint_names, times, positions, velocities, "away")


def stopped_under_way(ctl: ZenohController, start: np.ndarray) -> None:
    """A motion away from `start`, stopped (smoothly) once it is going."""
    ctl.execute(motion(start, 0.3))
    assert wait_until(lambda: np.abs(ctl.joint_state().velocities).max() > 0.2, 20), "it never got going"
    ctl.command(Command.STOP_MOTION)


def test_a_motion_sent_while_a_stop_brakes_runs_once_the_robot_is_still(controller):
    """The executor's way back to a trajectory's start (its rejoin), asked for while the robot brakes."""
    ctl = controller
    make_ready(ctl)
    start = ctl.joint_state().positions.copy()
    stopped_under_way(ctl, start)
    with pytest.raises(ControllerError) as refused:   # the controller's own answer while it brakes
        ctl.move_to(start)
    assert refused.value.result == Result.BUSY, refused.value
    assert ctl.wait_status(lambda s: not s.in_motion, 20)
    ctl.move_to(start).wait(30)
    failures: list[str] = []
    executor = MotionExecutor(ctl, load_cell_config(), lambda: 1.0, failures.append, failures.append,
                              lambda: True)
    stopped_under_way(ctl, start)
    try:
        executor.rejoin(motion(start, 0.05))   # back to its first point, `start`
    except StepFailed as exc:
        pytest.fail(f"the step failed instead of waiting for the stop: {exc}")
    assert wait_until(lambda: np.abs(ctl.joint_state().positions - start).max() <= CFG.goal_tolerance, 20)
    assert not failures, failures
