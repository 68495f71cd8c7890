"""A motion whose controller stops answering: the wait ends at its timeout, and stopping the motion
finds no answer either. That is the controller's fault, which the cell is told; not an error that
escapes the step (it used to end the step in a crash, logged with a traceback). Real Zenoh sessions
on loopback; the controller is a stand-in that accepts the trajectory, then answers nothing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cell.config import load_cell_config
from cell.errors import StepInterrupted
from cell.execution import MotionExecutor
from drivers.controller.trajectory import JointTrajectory
from drivers.controller.zenoh_client import ZenohController
from drivers.wire.transport import Wire
from tests.conftest import Endpoint
from tests.controller.test_zenoh_client import CFG, RC, StandIn


def test_a_motion_whose_controller_went_silent_faults_the_cell_instead_of_escaping_the_step(
        endpoint: Endpoint) -> None:
    stand_in = StandIn(endpoint)
    wire = Wire(endpoint.settings(), "client")
    try:
        stand_in.answer = "lease"
        ctl = ZenohController(wire, config=dataclasses.replace(CFG, reply_timeout=1.0), robot_config=RC)
        ctl.connect(timeout=20.0)
        ctl.acquire_lease()
        faults: list[str] = []
        config = dataclasses.replace(load_cell_config(), motion_timeout_margin_s=0.5)
        motion = MotionExecutor(ctl, config, lambda: 1.0, faults.append, lambda _reason: None, lambda: True)
        q = ctl.joint_state().positions
        stand_in.silent_after_trajectory = True
        with pytest.raises(StepInterrupted):
            motion.run(JointTrajectory(RC.joint_names, np.array([0.0, 0.1]), np.stack([q, q]), label="still"))
        assert len(faults) == 1 and faults[0].startswith("controller: ") and "no reply" in faults[0], faults
    finally:
        wire.close()
        stand_in.close()
