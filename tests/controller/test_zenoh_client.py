"""`ZenohController` types every failed request by the wire's error, never by its text: real Zenoh
sessions on loopback, a stand-in controller that publishes a status and joint states and answers
requests the way a test asks (refuse, or stay silent)."""

from __future__ import annotations

import dataclasses
import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from drivers.controller import codec
from drivers.controller.codes import Command, Reply, Result, Subcode
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
    answering by `self.answer`: 'refuse' (an error reply), 'hang' (no reply until released) or 'lease'
    (a lease granted to anyone; see `_lease`)."""

    def __init__(self, endpoint: Endpoint, name: str = "stand-in"):
        self.answer = "refuse"
        self.release = threading.Event()
        self.stop = threading.Event()
        self.wire = Wire(endpoint.settings(), name, announce=False)
        self.wire.serve("controller/trajectory", self._answer)
        self.wire.serve("controller/command", self._answer)
        self.wire.announce()
        core = ControllerCore(RC, CFG)
        self.status = core.status()
        self.status_msg = codec.status_msg(self.status, 1_000_000, 1.0)
        joints = codec.joint_state_msg(RC.joint_names)
        status_pub = self.wire.publisher("controller/status")
        joints_pub = self.wire.publisher("controller/joint_states")

        def publish() -> None:
            while not self.stop.wait(0.02):
                if self.quiet:
                    continue
                status_pub.put(self.status_msg)
                joints_pub.put(joints)

        self.thread = threading.Thread(target=publish, daemon=True)
        self.thread.start()

    def _answer(self, request: Any, info: RequestInfo) -> object:
        if self.answer == "lease":
            return self._lease(request)
        if self.answer == "hang":
            self.release.wait(30.0)
        raise ValueError("refused by the stand-in: values[0] is nan")

    def _lease(self, request: Any) -> object:
        """Accept every trajectory and grant every lease; with `hold_renewals`, keep each renewal
        until `release`, then refuse it as a controller that dropped the lease does."""
        if not hasattr(request, "command"):   # a trajectory: accepted
            if self.silent_after_trajectory:
                self.answer = "hang"
            return codec.reply_msg(Reply(Result.SUCCESS, trajectory_id=1), time.time_ns())
        if request.command == Command.LEASE_RENEW and self.hold_renewals:
            self.held += 1
            self.release.wait(30.0)
            self.held -= 1
            reply = Reply(Result.FAILURE, Subcode.LEASE_HELD, "the lease was dropped")
        else:
            reply = Reply(Result.SUCCESS)
        return codec.reply_msg(reply, time.time_ns(), request.command)

    hold_renewals = False
    silent_after_trajectory = False   # answer nothing once a trajectory was accepted
    quiet = False   # publish nothing (a status stream that lags)
    held = 0   # renewals kept unanswered now

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


def test_a_refusal_of_a_renewal_sent_before_the_lease_was_taken_again_keeps_the_new_lease(linked, endpoint):
    """The controller drops the lease while a renewal is on its way; the cell takes the lease again (here
    from a second controller session, the first being busy) before that renewal's refusal comes. The
    refusal speaks of the old grant: the new lease is kept and nothing says it was taken."""
    first, ctl, wire = linked
    first.answer = "lease"
    taken: list[str] = []
    ctl.add_lease_listener(taken.append)
    ctl.acquire_lease()
    first.hold_renewals = True
    assert wait_until(lambda: first.held == 1, 10), "no renewal reached the controller"
    # the controller's status says the lease is gone (stamped after the grant): the one loss there was
    dropped = dataclasses.replace(first.status, lease_note="dropped")
    first.status_msg = codec.status_msg(dropped, time.time_ns(), 1.0)
    assert wait_until(lambda: not ctl.holds_lease, 10) and taken == ["dropped"]
    second = StandIn(endpoint, "stand-in-2")
    try:
        second.answer = "lease"
        assert wait_until(lambda: any(k.endswith("alive/stand-in-2") for k in wire.alive()), 10)
        ctl.acquire_lease()   # the first controller is busy with the held renewals: the second grants it
        first.release.set()   # now the refusals of the old grant's renewals come
        assert wait_until(lambda: first.held == 0, 10)
        time.sleep(1.0)       # the refusals are handled on the client's renewal threads
        assert ctl.holds_lease and taken == ["dropped"], taken
    finally:
        second.close()


def test_a_fresh_status_is_the_next_one_reported_not_the_last_one_seen(linked):
    stand_in, ctl, _ = linked
    stand_in.quiet = True
    time.sleep(0.2)   # what was on its way has come
    stand_in.status_msg = codec.status_msg(dataclasses.replace(stand_in.status, lease_note="released"),
                                           time.time_ns(), 1.0)
    assert ctl.status().lease_note == ""   # the last one seen is the old one
    fresh: list[Any] = []
    asking = threading.Thread(target=lambda: fresh.append(ctl.fresh_status(timeout=30.0)))
    asking.start()
    time.sleep(0.3)
    assert not fresh, "answered before the controller reported again"
    stand_in.quiet = False
    asking.join(30.0)
    assert fresh and fresh[0].lease_note == "released", fresh
