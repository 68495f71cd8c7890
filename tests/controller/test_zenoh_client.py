"""`ZenohController` types every failed request by the wire's error, never by its text: real Zenoh
sessions on loopback, a stand-in controller that publishes a status and joint states and answers
requests the way a test asks (refuse, or stay silent)."""

from __future__ import annotations

import dataclasses
import threading
from collections.abc import Iterator

import numpy as np
import pytest

from drivers.controller import codec
from drivers.controller.codes import Command, Result, Subcode
from drivers.controller.config import default_controller_config
from drivers.controller.errors import ControllerGone, ControllerTimeout, InvalidArgument, TrajectoryRejected
from drivers.controller.trajectory import JointTrajectory
from drivers.controller.zenoh_client import ZenohController
from drivers.emulator.core import ControllerCore
from drivers.robot.config import default_robot_config
from drivers.wire.transport import RequestInfo, Wire
from tests.conftest import Endpoint, wait_until

RC = default_robot_config()
# replies that come get a generous wait; the one test of silence shortens it
CFG = dataclasses.replace(default_controller_config(), reply_timeout=20.0)


class StandIn:
    """A controller's streams (from an idle emulator core) on its own session, and its two queryables
    answering by `self.answer`: 'refuse' (an error reply) or 'hang' (no reply until released)."""

    def __init__(self, endpoint: Endpoint):
        self.answer = "refuse"
        self.release = threading.Event()
        self.stop = threading.Event()
        self.wire = Wire(endpoint.settings(), "stand-in", announce=False)
        self.wire.serve("controller/trajectory", self._answer)
        self.wire.serve("controller/command", self._answer)
        self.wire.announce()
        core = ControllerCore(RC, CFG)
        status = codec.status_msg(core.status(), 1_000_000, 1.0)
        joints = codec.joint_state_msg(RC.joint_names)
        status_pub = self.wire.publisher("controller/status")
        joints_pub = self.wire.publisher("controller/joint_states")

        def publish() -> None:
            while not self.stop.wait(0.02):
                status_pub.put(status)
                joints_pub.put(joints)

        self.thread = threading.Thread(target=publish, daemon=True)
        self.thread.start()

    def _answer(self, request: object, info: RequestInfo) -> object:
        if self.answer == "hang":
            self.release.wait(30.0)
        raise ValueError("refused by the stand-in: values[0] is nan")

    def close(self) -> None:
        self.stop.set()
        self.release.set()
        self.thread.join(5.0)
        self.wire.close()


@pytest.fixture
def linked(endpoint: Endpoint) -> Iterator[tuple[StandIn, ZenohController, Wire]]:
    stand_in = StandIn(endpoint)
    wire = Wire(endpoint.settings(), "client")
    try:
        ctl = ZenohController(wire, config=CFG, robot_config=RC)
        ctl.connect(timeout=20.0)
        assert wait_until(lambda: any(k.endswith("alive/stand-in") for k in wire.alive()), 10)
        yield stand_in, ctl, wire
    finally:
        wire.close()
        stand_in.close()


def still(q: np.ndarray) -> JointTrajectory:
    return JointTrajectory(RC.joint_names, np.array([0.0, 1.0]), np.stack([q, q]))


def test_an_error_reply_is_typed_like_the_controllers_invalid_reply(linked):
    _, ctl, _ = linked
    with pytest.raises(TrajectoryRejected) as rejected:
        ctl.execute(still(ctl.joint_state().positions))
    assert (rejected.value.result, rejected.value.subcode) == (Result.INVALID, Subcode.INVALID_DATA)
    assert "values[0] is nan" in rejected.value.text
    with pytest.raises(InvalidArgument) as invalid:
        ctl.command(Command.START_SERVOS)
    assert (invalid.value.result, invalid.value.subcode) == (Result.INVALID, Subcode.INVALID_COMMAND)


def test_no_reply_is_a_timeout(linked):
    stand_in, ctl, _ = linked
    stand_in.answer = "hang"
    ctl.config = dataclasses.replace(CFG, reply_timeout=1.0)
    with pytest.raises(ControllerTimeout, match="no reply within 1 s"):
        ctl.command(Command.CHECK_MOTION_READY)


def test_nobody_serving_is_controller_gone(linked):
    stand_in, ctl, wire = linked
    ctl.config = dataclasses.replace(CFG, reply_timeout=30.0)  # "at once" stays far from the timeout
    stand_in.close()
    assert wait_until(lambda: not any(k.endswith("alive/stand-in") for k in wire.alive()), 10)
    with pytest.raises(ControllerGone, match="nobody serves"):
        ctl.command(Command.CHECK_MOTION_READY)
