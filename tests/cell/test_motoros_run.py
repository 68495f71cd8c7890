"""The cell over MotoROS (`foldcell run --controller motoros://HOST:PORT`): the demo folds through the
emulator's MotoROS server, and the robot the cell publishes on Zenoh is the one MotoROS reports."""

from __future__ import annotations

import signal
import socket
import subprocess
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cell.config import load_cell_config
from drivers.common.configfile import ConfigError
from drivers.controller.codes import Command
from drivers.controller.interface import MotionStatus
from drivers.controller.link import controller_address
from drivers.controller.zenoh_client import ZenohController
from drivers.robot.config import default_robot_config
from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.bench.bench_cell import min_final_iou
from tests.cell.cell_states import CellStates
from tests.cell.test_e2e import run_demo
from tests.conftest import DEMO_TIMEOUT_S, Endpoint, foldcell_argv, wait_until
from tests.motoros import client as raw
from tests.motoros.test_process import free_ports

ROBOT = default_robot_config()


@pytest.mark.slow
@pytest.mark.timeout(DEMO_TIMEOUT_S + 60)
def test_the_secured_demo_over_motoros_folds_a_towel(tmp_path: Path) -> None:
    # secured: the cell publishes what MotoROS reports (joints, status, grippers) under its own role,
    # and the simulated world folds only if those samples pass the router's access control
    security = tmp_path / "security"
    subprocess.run(foldcell_argv("security", "init", str(security)), check=True, capture_output=True,
                   timeout=60)
    summary = run_demo(tmp_path, 1, "towel", extra=("--controller", "motoros", "--security", str(security)))
    (towel,) = summary["garments"]
    assert towel["outcome"] == "done" and towel["final_iou"] >= min_final_iou("towel"), towel
    assert summary["_returncode"] == 0
    log = (summary["_out"] / "logs" / "cell.log").read_text()
    assert "controller: MotoROS (upstream) at 127.0.0.1:" in log  # the cell drove MotoROS, not Zenoh


class JointStates:
    """The cell's `controller/joint_states` and `controller/status` as they arrive."""

    def __init__(self, wire: Wire):
        self.lock = threading.Lock()
        self.latest: Any = None
        self.status: Any = None
        wire.subscribe("controller/joint_states", self._on)
        wire.subscribe("controller/status", self._on_status)

    def _on(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.lock:
            self.latest = msg

    def _on_status(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.lock:
            self.status = msg

    def positions(self) -> np.ndarray | None:
        with self.lock:
            return None if self.latest is None else np.array(self.latest.position)


def raw_positions(reader: raw.StateReader) -> np.ndarray | None:
    """The project-order joint positions of the last JOINT_FEEDBACK of every group (section 9), read
    with struct by the test's own client; None until every group has reported. The CloPeMa dialect
    sends one feedback of group 0 for all 13 joints (r1 s..t, r2 s..t, ext_axis; section 10)."""
    with reader.lock:
        if reader.slots == len(ROBOT.joint_names):
            return np.array(reader.positions[0]) if 0 in reader.positions else None
        if len(reader.positions) < len(ROBOT.groups):
            return None
        q = np.zeros(len(ROBOT.joint_names))
        for number, group in enumerate(ROBOT.groups):
            for slot, joint in enumerate(group.joints):
                q[ROBOT.joint_names.index(joint)] = reader.positions[number][slot]
        return q


@pytest.mark.timeout(180)
@pytest.mark.parametrize("dialect", ["upstream", "clopema"])
def test_the_cell_publishes_the_joint_states_motoros_reports(spawn, tmp_path: Path, dialect: str) -> None:
    cell = Endpoint("cell")
    port = free_ports()
    # the controller keeps off the cell's keys (another cell id), as a real DX100 is off its Zenoh
    spawn(foldcell_argv("controller", "serve", "--role", "both", "--time-scale", "5", "--motoros",
                        f"127.0.0.1:{port}", "--motoros-dialect", dialect, *cell.args("dx100")))
    with Wire(cell.settings("dx100"), "test-mover") as dx100, Wire(cell.settings(), "test-watcher") as wire:
        mover = ZenohController(dx100)
        mover.connect(timeout=60)
        assert wait_until(lambda: _listening(port + 1), 30)
        daemon = spawn(foldcell_argv("run", "--no-record", "--job", str(tmp_path / "job.json"),
                                     "--controller", f"motoros://127.0.0.1:{port}?dialect={dialect}",
                                     *cell.args()))
        published = JointStates(wire)
        assert wait_until(lambda: published.positions() is not None, 60), daemon.stderr()[-2000:]
        reader = raw.StateReader(port + 1, slots=13 if dialect == "clopema" else 10)
        try:
            goal = np.linspace(-0.3, 0.3, len(ROBOT.joint_names))
            mover.acquire_lease()
            mover.command(Command.START_TRAJ_MODE)
            assert mover.move_to(goal).wait(60) == MotionStatus.SUCCEEDED
            # at rest: both views settle on the goal, the cell's to the raw stream's float32 values
            assert wait_until(lambda: _close(raw_positions(reader), goal, 1e-6), 30)
            # the last float32 bits may still settle: the two views agree once both have the same burst
            assert wait_until(lambda: _close(published.positions(), raw_positions(reader), 0.0), 30), \
                (published.positions(), raw_positions(reader))
            with published.lock:
                msg, status = published.latest, published.status
            assert list(msg.name) == list(ROBOT.joint_names)
            stamp_s = messages.stamp_to_ns(msg.header.stamp) * 1e-9
            assert abs(stamp_s - time.time()) < 60  # stamped with wall time, as a ROS driver stamps
            # ROBOT_STATUS (section 4, 13): drives_powered, e_stopped, error_code, in_error, in_motion, mode
            with reader.lock:
                drives_powered, e_stopped, error_code, in_error, _, mode, _ = reader.status
            seen = (status.drives_powered, status.e_stopped, status.error_code, status.in_error, status.mode)
            assert seen == (drives_powered, e_stopped, error_code, in_error, mode)
            assert [g.name for g in status.groups] == [g.name for g in ROBOT.groups]
        finally:
            reader.close()
            mover.disconnect()


@pytest.mark.timeout(240)
def test_losing_the_motoros_connection_mid_fold_faults_the_cell_naming_it(spawn, tmp_path: Path) -> None:
    cell = Endpoint("cell")
    port = free_ports()
    controller = spawn(foldcell_argv("controller", "serve", "--role", "both", "--time-scale", "5",
                                     "--motoros", f"127.0.0.1:{port}", *cell.args("dx100")))
    assert wait_until(lambda: _listening(port + 1), 60), controller.stderr()[-2000:]
    spawn(foldcell_argv("camera", "serve", "--garment", "towel", "--seed", "2", "--folding", "geometric",
                        *cell.args()))
    daemon = spawn(foldcell_argv("run", "--no-record", "--job", str(tmp_path / "job.json"),
                                 "--controller", f"motoros://127.0.0.1:{port}", *cell.args()))
    with Wire(cell.settings(), "test-operator") as wire:
        states = CellStates(wire)
        alive = lambda: {key.rsplit("/", 1)[1] for key in wire.alive()}  # noqa: E731
        assert wait_until(lambda: {"camera", "cell"} <= alive(), 60), daemon.stderr()[-2000:]
        reply = wire.request("cell/command", messages.new("foldcell_msgs/msg/CellCommand", command="fold",
                                                           argument="towel"), timeout=10)
        assert reply.accepted, reply.text
        assert states.first({"folding"}, 0.0, 60), states.last()
        killed = time.monotonic()
        controller.popen.send_signal(signal.SIGKILL)
        fault = states.first({"fault", "done", "failed"}, killed, 30)
        assert fault is not None and fault[1].state == "fault", fault
        assert f"127.0.0.1:{port}" in fault[1].reason, fault[1].reason


@pytest.mark.timeout(180)
def test_after_an_estop_the_cell_over_motoros_says_where_to_clear_it_and_enables_only_on_reset(
        spawn, tmp_path: Path) -> None:
    # MotoROS has no e-stop reset (it is a button); once it is released the servos stay off until an
    # operator's reset: the cell never switches them on by itself (MotoROS's re-enable bug)
    cell = Endpoint("cell")
    port = free_ports()
    spawn(foldcell_argv("controller", "serve", "--role", "both", "--time-scale", "5", "--motoros",
                        f"127.0.0.1:{port}", *cell.args("dx100")))
    with Wire(cell.settings("dx100"), "test-pendant") as dx100, \
            Wire(cell.settings(), "test-operator") as wire:
        pendant = ZenohController(dx100)   # the emulator's own side stands for the pendant and the button
        pendant.connect(timeout=60)
        assert wait_until(lambda: _listening(port + 1), 30)
        daemon = spawn(foldcell_argv("run", "--no-record", "--job", str(tmp_path / "job.json"),
                                     "--controller", f"motoros://127.0.0.1:{port}", *cell.args()))
        reader = raw.StateReader(port + 1)

        def robot_status() -> tuple[int, ...]:   # ROBOT_STATUS as the test's own client reads it
            with reader.lock:
                return reader.status

        def cell_command(command: str, argument: str = "") -> Any:
            return wire.request("cell/command", messages.new("foldcell_msgs/msg/CellCommand", command=command,
                                                              argument=argument), timeout=20)
        try:
            assert wait_until(lambda: "cell" in {k.rsplit("/", 1)[1] for k in wire.alive()}, 60), \
                daemon.stderr()[-2000:]
            pendant.command(Command.ESTOP)
            assert wait_until(lambda: robot_status()[1:2] == (1,), 30), robot_status()   # e_stopped
            reply = cell_command("reset")
            assert reply.accepted and "the e-stop cannot be reset remotely" in reply.text, reply.text
            pendant.acquire_lease()
            pendant.command(Command.ESTOP_RESET)   # the button released
            pendant.release_lease()
            assert wait_until(lambda: robot_status()[:2] == (0, 0), 30), robot_status()   # servos off
            refused = cell_command("fold", "towel")
            assert not refused.accepted and "servos are off since an e-stop" in refused.text, refused.text
            assert robot_status()[0] == 0   # the refused fold switched nothing on
            reply = cell_command("reset")
            assert reply.accepted and "servos on" in reply.text, reply.text
            assert wait_until(lambda: robot_status()[:2] == (1, 0), 30), robot_status()
        finally:
            reader.close()
            pendant.disconnect()


def _close(a: np.ndarray | None, b: np.ndarray | None, tolerance: float) -> bool:
    return a is not None and b is not None and bool(np.allclose(a, b, rtol=0.0, atol=tolerance))


def _listening(port: int) -> bool:
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=1.0):
            return True
    except OSError:
        return False


def test_a_bad_controller_url_is_refused_naming_the_field(tmp_path: Path) -> None:
    config = tmp_path / "cell.yaml"
    config.write_text("cell:\n  controller: motoros://dx100:fifty\n")
    with pytest.raises(ConfigError, match=r"cell\.controller.*PORT must be a number"):
        load_cell_config(config)
    config.write_text("cell:\n  controller: tcp://dx100\n")
    with pytest.raises(ConfigError, match=r"must be zenoh or motoros://HOST\[:PORT\]"):
        load_cell_config(config)
    config.write_text("cell:\n  controller: motoros://dx100\n")
    assert load_cell_config(config).controller == "motoros://dx100"
    for url, reason in (("motoros://dx100?dialect=fanuc",
                         r"dialect must be one of upstream, clopema, got 'fanuc'"),
                        ("motoros://dx100:50240?mode=fast",
                         r"the only option is \?dialect=upstream\|clopema")):
        config.write_text(f"cell:\n  controller: {url}\n")
        with pytest.raises(ConfigError, match=rf"cell\.controller.*{reason}"):
            load_cell_config(config)
    address = controller_address("motoros://[::1]:50300?dialect=clopema")
    assert (address.host, address.port, address.dialect) == ("::1", 50300, "clopema")
    assert controller_address("motoros://dx100").dialect is None   # config/motoros.yaml's



def test_the_physics_demo_over_motoros_runs_at_time_scale_1_or_says_why_not(tmp_path: Path) -> None:
    # MotoROS carries no robot time: the cloth, following the wall-clock stamps, would see a faster
    # robot move too fast; a demo asked for that is refused before anything starts
    result = subprocess.run(foldcell_argv("demo", "--controller", "motoros", "--folding", "physics",
                                          "--time-scale", "10", "--output", str(tmp_path / "d")),
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2, result.stderr[-2000:]
    assert "--time-scale: must be 1 for the cloth physics over --controller motoros, got 10" in result.stderr
    assert not (tmp_path / "d" / "logs").exists()
