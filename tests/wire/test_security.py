"""The secured wire (`--security DIR`): a real router and real master and slave controller processes
with mutual TLS and access control, probed by Zenoh sessions this test configures by hand (the way
a stranger, or a tool that shares no code with foldcell, would), and by `foldcell monitor`."""

from __future__ import annotations

import json
import shutil
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import zenoh
from cryptography import x509
from cryptography.x509.oid import NameOID

from drivers.controller import codec
from drivers.controller.codes import Command
from drivers.robot.config import default_robot_config
from drivers.wire import messages
from tests.conftest import REPO, Endpoint, Proc, foldcell_argv, wait_until

ROLES = ("cell", "controller", "master", "slave", "camera", "operator", "observer", "player")
CELL = "sec"
RC = default_robot_config()


def init(directory: Path) -> None:
    subprocess.run(foldcell_argv("security", "init", str(directory)), cwd=REPO, check=True,
                   capture_output=True, timeout=60)


def raw_session(port: int, *, protocol: str = "tls", security: Path | None = None,
                role: str | None = None, mode: str = "client") -> zenoh.Session:
    """A plain Zenoh session (a client of the router; a stranger: a peer, which opens even when no
    link forms), configured here from Zenoh's documented keys only; with a certificate of the cell's
    CA, once it is linked to the router."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("connect/exit_on_failure", "false")
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([f"{protocol}/127.0.0.1:{port}"]))
    tls: dict = {}
    if security is not None:
        tls["root_ca_certificate"] = str(security / "ca.pem")
    if role is not None:
        assert security is not None
        tls.update(enable_mtls=True, connect_certificate=str(security / f"{role}.pem"),
                   connect_private_key=str(security / f"{role}.key"))
    if tls:
        conf.insert_json5("transport/link/tls", json.dumps(tls))
    session = zenoh.open(conf)
    if role is not None and security is not None and security.name == "trusted":
        assert wait_until(lambda: len(list(session.info.routers_zid())) == 1, 30), "not linked to the router"
    return session


class Stream:
    """Decoded samples of one key, as they arrive."""

    def __init__(self, session: zenoh.Session, key: str, type_name: str):
        self.lock = threading.Lock()
        self.items: list = []
        self.type_name = type_name
        self.subscriber = session.declare_subscriber(key, self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        msg = messages.decode(self.type_name, sample.payload.to_bytes(), str(sample.key_expr))
        with self.lock:
            self.items.append(msg)

    def count(self) -> int:
        with self.lock:
            return len(self.items)

    def last(self):
        with self.lock:
            return self.items[-1] if self.items else None


def command(session: zenoh.Session, code: int, client: str) -> str:
    """Send a controller command; 'ok', 'refused: ...' or 'no reply'."""
    payload = messages.encode(codec.COMMAND_TYPE, codec.command_msg(code, client), "command")
    for reply in session.get(f"foldcell/{CELL}/controller/command", payload=payload,
                             encoding=zenoh.Encoding.APPLICATION_CDR.with_schema(codec.COMMAND_TYPE),
                             timeout=3.0):
        if reply.ok is not None:
            return "ok"
        return f"refused: {reply.err.payload.to_string() if reply.err else ''}"
    return "no reply"


def alive_tokens(session: zenoh.Session) -> set[str]:
    replies = session.liveliness().get(f"foldcell/{CELL}/alive/*", timeout=2.0)
    return {str(reply.ok.key_expr) for reply in replies if reply.ok is not None}


def monitored_processes(ep: Endpoint, security: Path) -> list[str]:
    """The processes `foldcell monitor --security` sees alive in the cell."""
    monitor = subprocess.run(foldcell_argv("monitor", "--once", "--json", "--duration", "2", "--cell", CELL,
                                           "--connect", ep.url, "--security", str(security)),
                             cwd=REPO, capture_output=True, text=True, timeout=60)
    assert monitor.returncode == 0, monitor.stderr
    return json.loads(monitor.stdout)["cells"][CELL]["processes"]


@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    """A secured master and slave, the security directory, and a second CA nobody trusts."""
    root = tmp_path_factory.mktemp("security")
    trusted, other = root / "trusted", root / "other"
    init(trusted)
    init(other)
    ep = Endpoint(CELL)
    secured_args = (*ep.args(), "--security", str(trusted))
    procs = [Proc(foldcell_argv("router", *secured_args), root / "router.log")]
    assert wait_until(lambda: "router serving" in procs[0].stderr(), 60), procs[0].stderr()
    procs += [Proc(foldcell_argv("controller", "serve", "--time-scale", "4", *secured_args, "--role", role),
                   root / f"{role}.log") for role in ("master", "slave")]
    watcher = raw_session(ep.port, security=trusted, role="observer")
    try:
        assert wait_until(lambda: {f"foldcell/{CELL}/alive/controller-master",
                                   f"foldcell/{CELL}/alive/controller-slave"} <= alive_tokens(watcher), 60), \
            "\n".join(p.stderr() for p in procs)
        yield ep, trusted, other, watcher
    finally:
        watcher.close()
        for proc in reversed(procs):
            proc.stop()


def test_security_init_makes_a_ca_and_one_certificate_per_role(tmp_path: Path) -> None:
    init(tmp_path / "s")
    ca = x509.load_pem_x509_certificate((tmp_path / "s" / "ca.pem").read_bytes())
    for role in ROLES:
        certificate = x509.load_pem_x509_certificate((tmp_path / "s" / f"{role}.pem").read_bytes())
        certificate.verify_directly_issued_by(ca)
        assert certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        assert (tmp_path / "s" / f"{role}.key").stat().st_mode & 0o077 == 0, "a key readable by others"
        if shutil.which("openssl"):
            check = subprocess.run(["openssl", "verify", "-CAfile", str(tmp_path / "s" / "ca.pem"),
                                    str(tmp_path / "s" / f"{role}.pem")], capture_output=True, text=True)
            assert check.returncode == 0, check.stdout + check.stderr
    again = subprocess.run(foldcell_argv("security", "init", str(tmp_path / "s")), cwd=REPO,
                           capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and "already holds a CA" in again.stderr


def test_a_process_refuses_a_missing_or_foreign_certificate(tmp_path: Path) -> None:
    init(tmp_path / "a")
    init(tmp_path / "b")
    shutil.copy(tmp_path / "b" / "observer.pem", tmp_path / "a" / "observer.pem")
    cases = ((tmp_path / "a", "was not signed by"), (tmp_path / "none", "is not a directory"))
    for directory, words in cases:
        result = subprocess.run(foldcell_argv("monitor", "--once", "--duration", "0",
                                              "--connect", "tcp/127.0.0.1:9", "--security", str(directory)),
                                cwd=REPO, capture_output=True, text=True, timeout=60)
        assert result.returncode != 0 and words in result.stderr, result.stderr


def test_strangers_cannot_connect_while_the_cells_own_tools_can(secured) -> None:
    ep, trusted, other, watcher = secured
    kinds = {"plain tcp": {"protocol": "tcp"}, "tls without a certificate": {"security": trusted},
             "a certificate of another CA": {"security": other, "role": "operator"}}
    for name, kind in kinds.items():
        with pytest.raises(zenoh.ZError, match="Unable to connect"):
            raw_session(ep.port, **kind).close()
            pytest.fail(f"{name}: a client linked to the router")
    strangers = {name: raw_session(ep.port, mode="peer", **kind) for name, kind in kinds.items()}
    try:
        streams = {name: Stream(s, f"foldcell/{CELL}/controller/joint_states", "sensor_msgs/msg/JointState")
                   for name, s in strangers.items()}
        ours = Stream(watcher, f"foldcell/{CELL}/controller/joint_states", "sensor_msgs/msg/JointState")
        assert wait_until(lambda: ours.count() > 50, 20), "the trusted observer receives the joint stream"
        for name, session in strangers.items():
            assert alive_tokens(session) == set(), f"{name}: sees who is alive"
            assert streams[name].count() == 0, f"{name}: receives joint states"
            assert command(session, Command.ESTOP, "alive/cli-x") == "no reply", f"{name}: reaches a command"
        assert {"controller-master", "controller-slave"} <= set(monitored_processes(ep, trusted))
    finally:
        for session in strangers.values():
            session.close()


def test_a_read_only_identity_reads_but_every_command_is_refused(secured) -> None:
    ep, trusted, _other, watcher = secured
    status = Stream(watcher, f"foldcell/{CELL}/controller/status", "foldcell_msgs/msg/ControllerStatus")
    observer = raw_session(ep.port, security=trusted, role="observer")
    operator = raw_session(ep.port, security=trusted, role="operator")
    try:
        assert wait_until(lambda: status.last() is not None, 20)
        assert not status.last().e_stopped
        for role, session in (("observer", observer), ("player", None)):
            if session is None:
                session = raw_session(ep.port, security=trusted, role=role)
            assert command(session, Command.ESTOP, "alive/cli-x") == "no reply", role
            count = status.count()
            assert wait_until(lambda c=count: status.count() > c + 5, 20)
            assert not status.last().e_stopped, f"{role} e-stopped the robot"
        # the same command from the operator's identity goes through: the refusal above is the ACL's
        assert command(operator, Command.ESTOP, "alive/cli-x") == "ok"
        assert wait_until(lambda: status.last().e_stopped, 20)
    finally:
        observer.close()
        operator.close()


def test_forged_slave_joint_states_and_a_forged_token_are_dropped(secured) -> None:
    ep, trusted, _other, watcher = secured
    joints = Stream(watcher, f"foldcell/{CELL}/controller/joint_states", "sensor_msgs/msg/JointState")
    forger = raw_session(ep.port, security=trusted, role="operator")
    try:
        assert wait_until(lambda: joints.last() is not None, 20)
        before = joints.last()
        slave_names = [n for n in before.name if n.startswith(("r2_",))]
        assert slave_names
        forged = messages.new("sensor_msgs/msg/JointState", header=messages.header(time.time_ns()),
                              name=slave_names, position=np.full(len(slave_names), 0.7),
                              velocity=np.zeros(len(slave_names)), effort=np.zeros(0))
        payload = messages.encode("sensor_msgs/msg/JointState", forged, "forged")
        token = forger.liveliness().declare_token(f"foldcell/{CELL}/alive/cell")
        start = joints.count()
        for _ in range(100):
            forger.put(f"foldcell/{CELL}/controller/slave/joint_states", payload,
                       encoding=zenoh.Encoding.APPLICATION_CDR.with_schema("sensor_msgs/msg/JointState"))
            time.sleep(0.01)
        assert wait_until(lambda: joints.count() > start + 100, 20)
        with joints.lock:
            seen = joints.items[start:]
        index = [list(before.name).index(n) for n in slave_names]
        worst = max(float(np.max(np.abs(np.asarray(m.position)[index] - np.asarray(before.position)[index])))
                    for m in seen)
        assert worst < 0.01, f"the master published a forged R2 position ({worst:.3f} rad off)"
        assert "cell" not in monitored_processes(ep, trusted), "a forged token counts"
        token.undeclare()
    finally:
        forger.close()
