"""A cell that stops answering loses the control lease, and says so: the controller takes the lease away
and stops the robot when the cell's process is stopped (SIGSTOP) for 2 s; the cell, running again,
faults with the controller's reason and spends no retry on it; `resume` takes the lease again and
finishes the garment. What the controller did is read on the wire (its status and joint states), not
from the cell."""

from __future__ import annotations

import signal
import threading
import time

import numpy as np
import pytest

from statemachine.machine import WORK_STATES
from tests.cell.test_e2e import Cell
from tests.conftest import wait_until

pytestmark = pytest.mark.slow

STOPPED_S = 2.0
STILL_S = 0.3     # the joint states must not move for this long while the cell is stopped


class Controller:
    """The controller's statuses and joint states as they arrive at an observer."""

    def __init__(self, cell: Cell):
        self.lock = threading.Condition()
        self.statuses: list[tuple[float, object]] = []
        self.joints: list[tuple[float, np.ndarray]] = []
        cell.wire.subscribe("controller/status", self._on_status)
        cell.wire.subscribe("controller/joint_states", self._on_joints)

    def _on_status(self, _k, msg, _r) -> None:
        with self.lock:
            self.statuses.append((time.monotonic(), msg))

    def _on_joints(self, _k, msg, _r) -> None:
        with self.lock:
            self.joints.append((time.monotonic(), np.array(msg.position)))

    def lease_dropped_since(self, since: float) -> object | None:
        with self.lock:
            return next((msg for at, msg in self.statuses if at >= since and not msg.lease_holder), None)

    def moved_within(self, first: float, last: float) -> float:
        """The largest joint change (rad) between samples that arrived in [first, last]."""
        with self.lock:
            window = [q for at, q in self.joints if first <= at <= last]
        assert len(window) >= 10, f"only {len(window)} joint states in {last - first:.2f} s"
        return float(np.max(np.abs(np.array(window) - window[0])))


@pytest.fixture
def cell(spawn, endpoint, tmp_path):
    c = Cell(spawn, endpoint, tmp_path, controller_roles=("master", "slave"))
    yield c
    c.close()


def test_a_cell_stopped_for_2_s_loses_the_lease_faults_with_the_reason_and_resume_finishes(cell):
    controller = Controller(cell)
    assert cell.command("fold", "towel").accepted
    cell.wait_state({"folding"}, 120)
    process = cell.procs["cell"].popen
    stopped_at = time.monotonic()
    process.send_signal(signal.SIGSTOP)
    try:
        # the controller notices the silent session, drops the lease and stops the robot on its own
        assert wait_until(lambda: controller.lease_dropped_since(stopped_at) is not None, STOPPED_S)
        dropped = controller.lease_dropped_since(stopped_at)
        assert "alive/cell" in dropped.lease_note and "no longer seen" in dropped.lease_note, dropped
        time.sleep(max(0.0, stopped_at + STOPPED_S - time.monotonic()))
        now = time.monotonic()
        assert controller.moved_within(now - STILL_S, now) == 0.0, "the robot moved without its commander"
    finally:
        process.send_signal(signal.SIGCONT)
    _, msg = cell.wait_state({"fault", "failed", "done"}, 30)
    assert msg.state == "fault", (msg.state, msg.reason)
    # the cell's own words (it could not run; its peers lost sight of it) or the controller's
    assert msg.reason.startswith("lease lost: "), msg.reason
    assert "this cell could not run for 2." in msg.reason or "alive/cell was no longer seen" in msg.reason
    assert msg.attempt == 1, "the lost lease was spent on a retry"
    # the links to the others are made again first (Zenoh retries, backing off to seconds)
    replies = []
    assert wait_until(lambda: replies.append(cell.command("resume")) or replies[-1].accepted, 60, 0.5), \
        replies[-1].text
    cell.wait_state(set(WORK_STATES), 30)   # at work again: the fault before is forgotten
    _, msg = cell.wait_state({"done", "failed", "fault"}, 180)
    assert msg.state == "done", (msg.state, msg.reason)
    assert cell.command("status").accepted
