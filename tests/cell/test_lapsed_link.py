"""A cell at rest (paused) and the camera's liveliness token: a token that goes and comes back (the
camera stopped past its link's lease, as a process starved of CPU is) is no fault; a camera that is
gone faults the cell, and once it is started again `resume` finishes the garment. The token's going and
coming are read on the wire by an observer, not from the cell."""

from __future__ import annotations

import signal
import threading
import time

import pytest

from cell.config import load_cell_config
from statemachine.machine import WORK_STATES
from tests.cell.test_e2e import Cell
from tests.conftest import wait_until

pytestmark = pytest.mark.slow

STOPPED_S = 0.8    # twice Zenoh's link lease (0.4 s): the camera's token goes


class Tokens:
    """The camera's token as an observer sees it: True (there) and False (gone), in order."""

    def __init__(self, cell: Cell):
        self.lock = threading.Lock()
        self.camera: list[bool] = []
        cell.wire.watch_alive(self._on)

    def _on(self, key: str, alive: bool) -> None:
        if key.endswith("/alive/camera"):
            with self.lock:
                self.camera.append(alive)

    def since(self, index: int) -> list[bool]:
        with self.lock:
            return self.camera[index:]


def starve_the_camera(cell: Cell, tokens: Tokens) -> None:
    """Stop the camera past its link's lease and let it run again: its token goes and comes back."""
    camera = cell.procs["camera"].popen
    before = len(tokens.since(0))
    camera.send_signal(signal.SIGSTOP)
    time.sleep(STOPPED_S)
    camera.send_signal(signal.SIGCONT)
    assert wait_until(lambda: tokens.since(before)[-2:] == [False, True], 30), tokens.since(before)


def test_a_paused_cell_rides_out_a_lapsed_link_and_faults_on_a_lost_camera_until_it_is_back(
        spawn, endpoint, tmp_path):
    grace = load_cell_config().lost_grace_s
    cell = Cell(spawn, endpoint, tmp_path)
    try:
        tokens = Tokens(cell)
        assert cell.command("fold", "towel").accepted
        cell.wait_state({"perceiving"}, 60)
        assert cell.command("pause").accepted
        cell.wait_state({"paused"}, 60)
        starve_the_camera(cell, tokens)
        # the cell's check a grace period after the loss has passed, with the camera back
        time.sleep(2 * grace)
        with cell.changed:
            assert {msg.state for _, msg in cell.states} == {"paused"}, [m.reason for _, m in cell.states]
        cell.kill("camera")
        _, msg = cell.wait_state({"fault"}, 30)
        assert f"process camera is gone (not back within {grace:g} s)" in msg.reason, msg.reason
        assert list(msg.processes_lost) == ["camera"]   # the cell's own view, as the monitor shows it

        def lost_now() -> list[str]:
            with cell.changed:
                return list(cell.states[-1][1].processes_lost)

        cell.restart("camera")
        assert wait_until(lambda: lost_now() == [], 30), lost_now()
        reply = cell.command("resume")
        assert reply.accepted, reply.text
        cell.wait_state(set(WORK_STATES), 30)   # at work again: the fault before is forgotten
        _, msg = cell.wait_state({"done", "failed", "fault"}, 180)
        assert msg.state == "done", msg.reason
    finally:
        cell.close()


# Mid-fold, the camera starved past its link's lease is no fault either: no motion needs it, and it is
# back long before the next capture.
def test_a_folding_cell_rides_out_a_lapsed_camera_link(spawn, endpoint, tmp_path):
    cell = Cell(spawn, endpoint, tmp_path)
    try:
        tokens = Tokens(cell)
        assert cell.command("fold", "towel").accepted
        cell.wait_state({"grasping", "folding"}, 60)
        starve_the_camera(cell, tokens)
        _, msg = cell.wait_state({"done", "failed", "fault"}, 180)
        assert msg.state == "done", msg.reason
    finally:
        cell.close()
