"""`foldcell controller status|servo|estop|watch --motoros`: the CLI as a process against a
`foldcell controller serve --motoros` process, checked against what the Zenoh side of the same
emulator reports; and the Zenoh side's status showing motion streamed over MotoROS."""

from __future__ import annotations

import json
import signal
import subprocess
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from drivers.controller.codes import Command
from drivers.controller.interface import ControllerStatus, MotionStatus
from drivers.controller.zenoh_client import ZenohController
from drivers.wire.transport import Wire
from tests.conftest import REPO, Endpoint, Proc, foldcell_argv, wait_until
from tests.motoros import client as mc
from tests.motoros.test_process import free_ports

CLI_TIMEOUT_S = 60
# R1 somewhere off home, so positions are compared on values that differ from the zeros of no data
OFF_HOME = np.array([0.125, -0.25, 0.0625, 0.0, 0.1875, -0.125] + [0.0] * 7)
# status fields both sides report from the same core (the MotoROS side has no hold, lease or faults)
SHARED_FIELDS = ("drives_powered", "e_stopped", "in_error", "error_code", "in_motion", "mode",
                 "motion_possible", "queue_count")


@dataclass
class Served:
    port: int
    proc: Proc
    zenoh: ZenohController
    statuses: list[ControllerStatus]
    lock: threading.Lock

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def cli(self, *args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(foldcell_argv("controller", *args), capture_output=True, text=True, cwd=REPO,
                              timeout=CLI_TIMEOUT_S)

    def status_json(self) -> dict:
        done = self.cli("status", "--motoros", self.address, "--json")
        assert done.returncode == 0, done.stderr
        answer = json.loads(done.stdout)
        assert answer["ok"] is True
        return dict(answer["status"])

    def with_lease(self, code: Command) -> None:
        self.zenoh.acquire_lease()
        try:
            self.zenoh.command(code)
        finally:
            self.zenoh.release_lease()

    def move_off_home(self) -> None:
        """From the Zenoh side, then the lease is free again."""
        zenoh = self.zenoh
        zenoh.acquire_lease()
        try:
            zenoh.command(Command.START_SERVOS)
            zenoh.command(Command.START_TRAJ_MODE)
            assert zenoh.move_to(OFF_HOME).wait(30) == MotionStatus.SUCCEEDED
        finally:
            zenoh.release_lease()
        assert wait_until(lambda: not zenoh.status().in_motion and zenoh.status().lease_holder == "", 10)


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    ep = Endpoint("motoros-cli")
    port = free_ports()
    log = tmp_path_factory.mktemp("serve") / "serve.log"
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", "--motoros", f"127.0.0.1:{port}",
                              *ep.args()), log)
    wire = Wire(ep.settings(), "tester")
    try:
        zenoh = ZenohController(wire)
        zenoh.connect(timeout=30)
        assert wait_until(lambda: "MotoROS (upstream)" in proc.stderr(), 30), proc.stderr()
        statuses: list[ControllerStatus] = []
        lock = threading.Lock()

        def record(status: ControllerStatus) -> None:
            with lock:
                statuses.append(status)

        zenoh.add_status_listener(record)
        yield Served(port, proc, zenoh, statuses, lock)
    finally:
        wire.close()
        assert proc.stop() == 0, proc.stderr()


@pytest.mark.timeout(180)
def test_status_json_is_what_the_zenoh_side_reports(served: Served) -> None:
    zenoh = served.zenoh
    served.move_off_home()
    status = served.status_json()
    reference = zenoh.status()
    for name in SHARED_FIELDS:
        assert status[name] == int(getattr(reference, name)), name
    assert status["drives_powered"] == 1 and status["motion_possible"] == 1
    assert [g["name"] for g in status["groups"]] == [g.name for g in reference.groups]
    positions = np.array(list(status["joints"].values()))
    assert list(status["joints"]) == list(zenoh.joint_state().joint_names)
    np.testing.assert_allclose(positions, zenoh.joint_state().positions, atol=1e-6)  # float32 on the wire
    np.testing.assert_allclose(positions, OFF_HOME, atol=1e-6)


@pytest.mark.timeout(180)
def test_servo_off_then_status_shows_it_on_both_sides(served: Served) -> None:
    served.with_lease(Command.START_TRAJ_MODE)
    assert wait_until(lambda: served.zenoh.status().drives_powered, 10)
    done = served.cli("servo", "off", "--motoros", served.address)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "servo off"
    assert served.status_json()["drives_powered"] == 0
    assert wait_until(lambda: not served.zenoh.status().drives_powered, 10)
    # and on again, over MotoROS
    done = served.cli("servo", "on", "--motoros", served.address)
    assert done.returncode == 0, done.stderr
    status = served.status_json()
    assert (status["drives_powered"], status["motion_possible"]) == (1, 1)


@pytest.mark.timeout(180)
def test_estop_stops_the_servos_and_only_servo_on_moves_again(served: Served) -> None:
    served.with_lease(Command.START_TRAJ_MODE)
    done = served.cli("estop", "--motoros", served.address)
    assert done.returncode == 0, done.stderr
    assert "STOP_MOTION + STOP_SERVOS" in done.stdout
    assert wait_until(lambda: not served.zenoh.status().drives_powered, 10)
    assert served.status_json()["motion_possible"] == 0
    assert served.cli("servo", "on", "--motoros", served.address).returncode == 0
    assert wait_until(lambda: served.zenoh.status().motion_possible, 10)


@pytest.mark.timeout(180)
def test_watch_prints_states_until_interrupted(served: Served, tmp_path: Path) -> None:
    wanted = 5
    proc = Proc(foldcell_argv("controller", "watch", "--motoros", served.address, "--json", "--rate", "20"),
                tmp_path / "watch.log")
    try:
        assert proc.popen.stdout is not None
        stamps: list[float] = []
        statuses = 0
        while len(stamps) < wanted:
            line = proc.popen.stdout.readline()
            assert line, proc.stderr()
            data = json.loads(line)
            if "joints" in data:
                assert list(data["joints"]) == list(served.zenoh.joint_state().joint_names)
                stamps.append(data["stamp"])
            else:
                assert set(SHARED_FIELDS) <= set(data)
                statuses += 1
        assert statuses >= 1  # the first status is always printed
        assert stamps == sorted(stamps) and len(set(stamps)) == wanted
    finally:
        assert proc.stop(signal.SIGINT) == 0, proc.stderr()


@pytest.mark.timeout(180)
def test_commands_motoros_cannot_carry_are_refused_and_a_silent_host_is_named(served: Served) -> None:
    done = served.cli("hold", "--motoros", served.address)
    assert done.returncode == 2
    assert "hold --motoros: MotoROS has no hold" in done.stderr
    closed = free_ports(2)
    done = served.cli("status", "--motoros", f"127.0.0.1:{closed}")
    assert done.returncode == 1
    assert f"127.0.0.1:{closed}" in done.stderr and "refused" in done.stderr.lower()
    done = served.cli("status", "--motoros", "127.0.0.1:motion")
    assert done.returncode == 2 and "PORT must be a number" in done.stderr


@pytest.mark.timeout(180)
def test_a_motoros_move_is_in_motion_on_controller_status(served: Served) -> None:
    served.with_lease(Command.START_SERVOS)
    served.with_lease(Command.START_TRAJ_MODE)
    here = served.zenoh.joint_state().positions
    client = mc.MotionClient(served.port)
    try:
        with served.lock:
            served.statuses.clear()
        assert client.ctrl(mc.START_TRAJ_MODE).result == mc.SUCCESS
        assert client.point(0, 0, 0.0, here[:6].tolist(), [0.0] * 6).result == mc.SUCCESS
        goal = here[:6] + 0.125
        assert client.point(0, 1, 1.0, goal.tolist(), [0.0] * 6).result == mc.SUCCESS
        assert wait_until(lambda: np.allclose(served.zenoh.joint_state().positions[:6], goal, atol=1e-6), 30)
        assert wait_until(lambda: not served.zenoh.status().in_motion, 10)
        with served.lock:
            seen = list(served.statuses)
        moving = [s for s in seen if s.in_motion]
        assert moving, "no controller/status with in_motion while MotoROS streamed"
        assert all(s.queue_count == 1 for s in moving)
        assert moving[0].lease_holder.startswith("motoros@")
        # at rest: nothing queued on either side
        assert served.zenoh.status().queue_count == 0
    finally:
        client.close()


@pytest.mark.timeout(180)
def test_home_streams_the_motion_over_motoros(served: Served) -> None:
    served.move_off_home()
    done = served.cli("home", "--motoros", served.address)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "home: succeeded"
    home = np.zeros(13)  # config/robot/joints.yaml
    assert wait_until(lambda: np.allclose(served.zenoh.joint_state().positions, home, atol=1e-6), 10)


def test_an_open_motoros_server_beyond_loopback_warns(served: Served, tmp_path: Path) -> None:
    # the module's server, on 127.0.0.1, says nothing; one on every address says it loudly
    assert "MotoROS ports listen beyond this machine" not in served.proc.stderr()
    port = free_ports()
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", "--motoros", f":{port}",
                              *Endpoint("motoros-open").args()), tmp_path / "open.log")
    try:
        assert wait_until(lambda: "MotoROS (upstream)" in proc.stderr(), 60), proc.stderr()
        assert "MotoROS on 0.0.0.0: this process is open (no --security) and its MotoROS ports listen " \
               "beyond this machine" in proc.stderr()
    finally:
        proc.stop()
