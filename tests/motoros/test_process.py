"""`foldcell controller serve --motoros`: one emulator process, a MotoROS client on TCP and a Zenoh
client on the same robot (one core behind both), and the lease covering both sides."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from drivers.controller.errors import ControllerError
from drivers.controller.interface import MotionStatus
from drivers.controller.zenoh_client import ZenohController
from drivers.wire.transport import Wire
from tests.conftest import Endpoint, Proc, foldcell_argv, wait_until
from tests.motoros import client as mc
from tools.demo_cli import free_ports


@pytest.mark.timeout(120)
def test_serve_with_motoros_moves_the_robot_both_sides_see(tmp_path: Path) -> None:
    ep = Endpoint("motoros")
    port = free_ports()
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", "--motoros", f"127.0.0.1:{port}",
                              *ep.args()), tmp_path / "serve.log")
    wire = Wire(ep.settings(), "tester")
    state = client = None
    try:
        ctl = ZenohController(wire)
        ctl.connect(timeout=30)
        assert wait_until(lambda: "MotoROS (upstream)" in proc.stderr(), 30), proc.stderr()
        client = mc.MotionClient(port)
        state = mc.StateReader(port + 1)
        assert client.ctrl(mc.START_TRAJ_MODE).result == mc.SUCCESS
        assert client.point(1, 0, 0.0, [0.0] * 6, [0.0] * 6).result == mc.SUCCESS
        goal = [0.0625, -0.0625, 0.125, 0.0, 0.0625, 0.25]
        assert client.point(1, 1, 0.5, goal, [0.0] * 6).result == mc.SUCCESS
        assert state.wait_for(lambda s: np.allclose(s.positions.get(1, (9.0,) * 10)[:6], goal, atol=1e-4))
        # the Zenoh side sees the same robot (R2 is joints 6..11)
        assert wait_until(lambda: np.allclose(ctl.joint_state().positions[6:12], goal, atol=1e-6), 10)
        # the MotoROS client holds the lease: the Zenoh side may not command motion
        with pytest.raises(ControllerError):
            ctl.acquire_lease()
        # the client goes: the lease is free again
        client.close()
        client = None
        assert wait_until(lambda: _acquired(ctl), 10)
        # and the Zenoh side drives the same robot home
        assert ctl.move_to(np.zeros(13)).wait(30) == MotionStatus.SUCCEEDED
        assert state.wait_for(lambda s: np.allclose(s.positions.get(1, (9.0,) * 10)[:6], 0.0, atol=1e-6))
    finally:
        for closable in (client, state):
            if closable is not None:
                closable.close()
        wire.close()
        assert proc.stop() == 0, proc.stderr()


def _acquired(ctl: ZenohController) -> bool:
    try:
        ctl.acquire_lease()
    except ControllerError:
        return False
    return True

