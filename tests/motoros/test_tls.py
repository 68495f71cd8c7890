"""`controller serve --motoros` under `--security`: the MotoROS ports speak simple message only inside TLS,
to certificates of the cell's CA whose role may command the controller. Strangers send the raw frames of
servo on and a motion (plain TCP, TLS without a certificate, another CA's, the cell's observer's); the
robot, read on Zenoh by an observer of the secured cell, does not move. The cell's certificate moves it
while other clients stall in their handshakes; the secured cell and the operator's `controller` commands
drive it over TLS; `--motoros-plain` binds loopback only."""

from __future__ import annotations

import json
import socket
import ssl
import subprocess
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.controller.codes import Command
from drivers.controller.errors import ControllerGone
from drivers.controller.motoros_client import MotorosController
from drivers.controller.zenoh_client import ZenohController
from drivers.wire import messages
from drivers.wire.tls import client_context
from drivers.wire.transport import Wire
from tests.conftest import Endpoint, Proc, foldcell_argv, request_once_served, wait_until
from tests.motoros import client as mc
from tests.wire.test_security import Stream, init, raw_session
from tools.demo_cli import free_ports

CELL = "msec"
R1 = 6  # group 0's joints: the first six


@pytest.fixture(scope="module")
def secured(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple]:
    """A router and a `controller serve --motoros` secured by one CA, another CA, and an observer's
    Zenoh view of the controller's joint states and status."""
    root = tmp_path_factory.mktemp("motoros-tls")
    trusted, other = root / "trusted", root / "other"
    init(trusted)
    init(other)
    ep = Endpoint(CELL)
    port = free_ports()
    procs = [Proc(foldcell_argv("router", *ep.args(), "--security", str(trusted / "router")),
                  root / "router.log")]
    observer = None
    try:
        assert wait_until(lambda: "router serving" in procs[0].stderr(), 60), procs[0].stderr()
        procs.append(Proc(foldcell_argv("controller", "serve", "--role", "both", "--time-scale", "4",
                                        "--motoros", f"127.0.0.1:{port}", *ep.args(), "--security",
                                        str(trusted / "controller")), root / "serve.log"))
        observer = raw_session(ep.port, security=trusted / "observer", role="observer")
        joints = Stream(observer, f"foldcell/{CELL}/controller/joint_states", "sensor_msgs/msg/JointState")
        status = Stream(observer, f"foldcell/{CELL}/controller/status", "foldcell_msgs/msg/ControllerStatus")
        assert wait_until(lambda: joints.last() is not None and status.last() is not None, 60), \
            procs[1].stderr()
        assert "MotoROS (upstream) on 127.0.0.1 over TLS for cell, operator" in procs[1].stderr()
        yield ep, port, trusted, other, procs[1], joints, status
    finally:
        if observer is not None:
            observer.close()
        for proc in reversed(procs):
            proc.stop()


def context(ca: Path | None, certificate: Path | None = None) -> ssl.SSLContext:
    """A client's TLS: the server checked against `ca` (None: not checked, as a stranger does), showing
    `certificate` (DIR/ROLE.pem, its key beside it) if given. Built from `ssl` alone."""
    tls = ssl.create_default_context(cafile=str(ca) if ca else None)
    if ca is None:
        tls.check_hostname = False
        tls.verify_mode = ssl.CERT_NONE
    if certificate is not None:
        tls.load_cert_chain(certificate, certificate.with_suffix(".key"))
    return tls


def try_to_move(port: int, tls: ssl.SSLContext | None, start: np.ndarray) -> str:
    """Servo on, trajectory mode, R1's start point and a point 0.1 rad on, on the motion port: what
    stopped it, or the replies."""
    goal = start + np.r_[0.1, np.zeros(R1 - 1)]
    try:
        client = mc.MotionClient(port, tls=tls)
        try:
            results = [client.ctrl(mc.START_SERVOS).result, client.ctrl(mc.START_TRAJ_MODE).result,
                       client.point(0, 0, 0.0, start, [0.0] * R1).result,
                       client.point(0, 1, 0.5, goal, [0.0] * R1).result]
        finally:
            client.close()
    except OSError as exc:  # ssl.SSLError, a reset, ConnectionError: closed by the server
        return f"stopped: {type(exc).__name__}: {exc}"
    return f"answered: {results}"


def since(stream: Stream, start: int) -> list:
    with stream.lock:
        return stream.items[start:]


def settled(stream: Stream, samples: int = 20) -> bool:
    """`samples` more samples arrived (each built after the attempts before)."""
    count = stream.count()
    return wait_until(lambda: stream.count() >= count + samples, 20)


def test_strangers_cannot_move_the_robot_over_the_motoros_port(secured) -> None:
    _ep, port, trusted, other, controller, joints, status = secured
    before = np.array(joints.last().position)
    strangers = {"plain tcp": None,
                 "tls without a certificate": context(trusted / "observer" / "ca.pem"),
                 "another CA's operator": context(None, other / "operator" / "operator.pem"),
                 "the cell's observer": context(trusted / "observer" / "ca.pem",
                                                     trusted / "observer" / "observer.pem")}
    for name, tls in strangers.items():
        outcome = try_to_move(port, tls, before[:R1])
        assert outcome.startswith("stopped"), f"{name}: {outcome}"
    # foldcell's own client in a role that may not command is told at once, not after its timeout
    observer = MotorosController("127.0.0.1", port, tls=client_context(trusted / "observer", "observer"))
    with pytest.raises(ControllerGone, match="the controller closed the connection before the first state"):
        observer.connect(timeout=30)
    assert settled(joints) and settled(status)
    assert np.array_equal(np.array(joints.last().position), before), "a stranger moved the robot"
    last = status.last()
    assert (last.drives_powered, last.trajectory_mode, last.lease_holder) == (0, 0, ""), last
    log = controller.stderr()
    assert log.count("refused: TLS handshake failed") == 3, log[-3000:]
    assert log.count("refused: its certificate's role 'observer' may not command the controller") == 3, \
        log[-3000:]  # the raw client's motion connection, foldcell's motion and state connections


def test_the_cells_certificate_moves_the_robot_while_others_stall_in_the_handshake(secured) -> None:
    _ep, port, trusted, other, _controller, joints, status = secured
    # connected and silent: were the handshake done on the accept loop, each would hold the next
    # client for the server's handshake timeout, longer than the client below waits
    stallers = [socket.create_connection(("127.0.0.1", port)) for _ in range(2)]
    try:
        start = np.array(joints.last().position)
        goal = start[:R1] + np.r_[0.1, np.zeros(R1 - 1)]
        cell = trusted / "cell"
        client = mc.MotionClient(port, tls=context(cell / "ca.pem", cell / "cell.pem"))
        try:
            assert client.ctrl(mc.START_TRAJ_MODE).result == mc.SUCCESS
            assert client.point(0, 0, 0.0, start[:R1], [0.0] * R1).result == mc.SUCCESS
            assert client.point(0, 1, 0.5, goal, [0.0] * R1).result == mc.SUCCESS
            assert wait_until(lambda: np.allclose(np.array(joints.last().position)[:R1], goal, atol=1e-4), 30)
            assert wait_until(lambda: status.last().lease_holder == "motoros:cell@127.0.0.1", 10), \
                status.last().lease_holder  # the lease is the certificate's role at its host
        finally:
            client.close()
    finally:
        for staller in stallers:
            staller.close()
    # foldcell's own client, as the operator over TLS; and one trusting another CA refuses the server
    motoros = ("--motoros", f"127.0.0.1:{port}")
    status_cli = subprocess.run(foldcell_argv("controller", "status", "--json", *motoros, "--security",
                                              str(trusted / "operator")),
                                capture_output=True, text=True, timeout=60)
    assert status_cli.returncode == 0, status_cli.stderr
    seen = json.loads(status_cli.stdout)["status"]
    assert seen["drives_powered"] == 1, seen
    assert np.allclose(list(seen["joints"].values())[:R1], goal, atol=1e-4), seen
    refused = subprocess.run(foldcell_argv("controller", "status", *motoros,
                                           "--security", str(other / "operator")),
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode != 0 and "CERTIFICATE_VERIFY_FAILED" in refused.stderr, refused.stderr


def test_the_secured_cell_drives_the_controller_over_tls(secured, spawn, tmp_path: Path) -> None:
    # the cell, connected over MotoROS, sees an e-stop the pendant (the controller's Zenoh side) engages
    # and releases; its reset then switches the servos on over MotoROS, as the certificate's role
    ep, port, trusted, _other, _controller, _joints, status = secured
    daemon = spawn(foldcell_argv("run", "--no-record", "--job", str(tmp_path / "job.json"), "--controller",
                                 f"motoros://127.0.0.1:{port}", *ep.args(),
                                 "--security", str(trusted / "cell")))
    operator = ep.settings().overridden(security_dir=trusted / "operator", role="operator")
    with Wire(operator, "cli-test-operator") as wire:
        # ready: connected over MotoROS and listening to its status (its token is up before that)
        assert wait_until(lambda: f"cell {CELL} ready" in daemon.stderr(), 60), daemon.stderr()[-2000:]
        pendant = ZenohController(wire)
        pendant.connect(timeout=30)
        try:
            pendant.command(Command.ESTOP)
            assert wait_until(lambda: status.last().e_stopped == 1, 20)
            # held a while, as a pendant's is: the cell hears it on the MotoROS state port, every 25 ms
            assert settled(status, 5)
            pendant.acquire_lease()
            pendant.command(Command.ESTOP_RESET)
            pendant.release_lease()
            assert wait_until(lambda: (status.last().e_stopped, status.last().drives_powered) == (0, 0), 20)
            start = status.count()
            reply = request_once_served(wire, "cell/command", messages.new(
                "foldcell_msgs/msg/CellCommand", command="reset", argument=""), timeout=20)
            assert reply.accepted and "servos on" in reply.text, reply.text
        finally:
            pendant.disconnect()
    # the controller names the lease after the certificate the cell showed (the cell's own samples of
    # `controller/status`, what MotoROS reports, name no holder)
    assert wait_until(lambda: any(m.lease_holder == "motoros:cell@127.0.0.1" and m.drives_powered == 1
                                  for m in since(status, start)), 20), status.last()


def test_plain_motoros_under_security_is_loopback_only_and_said_loudly(secured, tmp_path: Path) -> None:
    ep, _port, trusted, _other, _controller, _joints, _status = secured
    port = free_ports()
    # another cell id on the same router: this controller stays off the secured one's keys
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", "--motoros", f"0.0.0.0:{port}",
                              "--motoros-plain", *ep.args("mplain"), "--security",
                              str(trusted / "controller")),
                tmp_path / "plain.log")
    try:
        assert wait_until(lambda: "serving cell mplain" in proc.stderr(), 60), proc.stderr()
        assert listening_addresses(port) == {"127.0.0.1"}  # as the kernel says
        assert f"under --security (--motoros-plain): unauthenticated, whoever reaches 127.0.0.1:{port}" \
            in proc.stderr()
        assert "bound to 127.0.0.1 only (not 0.0.0.0)" in proc.stderr()
        client = mc.MotionClient(port)  # plain simple message, no certificate
        try:
            assert client.ctrl(mc.CHECK_MOTION_READY).msg_type == 2002
        finally:
            client.close()
    finally:
        proc.stop()


def listening_addresses(port: int) -> set[str]:
    """The IPv4 addresses a socket listens on at `port`, from /proc/net/tcp."""
    addresses = set()
    for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
        local, state = line.split()[1], line.split()[3]
        address, local_port = local.split(":")
        if state == "0A" and int(local_port, 16) == port:  # 0A: LISTEN
            addresses.add(socket.inet_ntoa(bytes.fromhex(address)[::-1]))
    return addresses
