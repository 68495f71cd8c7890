"""The secured wire (`--security DIR/<role>`): a real router and real master and slave controller
processes with mutual TLS and access control, probed by Zenoh sessions this test configures by hand
(the way a stranger, or a tool that shares no code with foldcell, would), and by `foldcell monitor`
and `foldcell replay`."""

from __future__ import annotations

import json
import os
import pty
import re
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
from drivers.sessions.mcap.writer import SessionWriter
from drivers.wire import messages
from drivers.wire.registry import KEYS
from drivers.wire.security import REPLAY_SUFFIX, SecurityError, identity, load_security_config
from tests.conftest import REPO, Endpoint, Proc, foldcell_argv, wait_until

SECURITY = load_security_config()
CELL = "sec"
STATUS = "foldcell_msgs/msg/ControllerStatus"
RC = default_robot_config()


def init(directory: Path) -> subprocess.CompletedProcess:
    return subprocess.run(foldcell_argv("security", "init", str(directory)), cwd=REPO, check=True,
                          capture_output=True, text=True, timeout=60)


def raw_session(port: int, *, protocol: str = "tls", security: Path | None = None,
                role: str | None = None, mode: str = "client") -> zenoh.Session:
    """A plain Zenoh session (a client of the router; a stranger: a peer, which opens even when no
    link forms), configured here from Zenoh's documented keys only; with `security`, a role's
    directory, the CA it trusts and (with `role`) its certificate; with the cell's CA, once it is
    linked to the router."""
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
    if role is not None and security is not None and security.parent.name == "trusted":
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


def monitored_processes(ep: Endpoint, trusted: Path) -> list[str]:
    """The processes `foldcell monitor --security DIR/observer` sees alive in the cell."""
    monitor = subprocess.run(foldcell_argv("monitor", "--once", "--json", "--duration", "2", "--cell", CELL,
                                           "--connect", ep.url, "--security", str(trusted / "observer")),
                             cwd=REPO, capture_output=True, text=True, timeout=60)
    assert monitor.returncode == 0, monitor.stderr
    return json.loads(monitor.stdout)["cells"][CELL]["processes"]


@pytest.fixture(scope="module")
def security_dirs(tmp_path_factory) -> tuple[Path, Path]:
    """The cell's security directory (`security init`), and a second CA nobody trusts."""
    root = tmp_path_factory.mktemp("security")
    trusted, other = root / "trusted", root / "other"
    init(trusted)
    init(other)
    return trusted, other


def client(ep: Endpoint, trusted: Path, role: str) -> zenoh.Session:
    """A client of the router with `role`'s certificate, from its own directory."""
    return raw_session(ep.port, security=trusted / role, role=role)


def start_router(ep: Endpoint, trusted: Path, log: Path) -> Proc:
    router = Proc(foldcell_argv("router", *ep.args(), "--security", str(trusted / "router")), log)
    assert wait_until(lambda: "router serving" in router.stderr(), 60), router.stderr()
    return router


@pytest.fixture(scope="module")
def secured(security_dirs, tmp_path_factory):
    """A secured master and slave, the security directory, and a second CA nobody trusts."""
    trusted, other = security_dirs
    logs = tmp_path_factory.mktemp("secured")
    ep = Endpoint(CELL)
    procs = [start_router(ep, trusted, logs / "router.log")]
    procs += [Proc(foldcell_argv("controller", "serve", "--time-scale", "4", *ep.args(),
                                 "--security", str(trusted / role), "--role", role), logs / f"{role}.log")
              for role in ("master", "slave")]
    watcher = client(ep, trusted, "observer")
    try:
        assert wait_until(lambda: {f"foldcell/{CELL}/alive/controller-master",
                                   f"foldcell/{CELL}/alive/controller-slave"} <= alive_tokens(watcher), 60), \
            "\n".join(p.stderr() for p in procs)
        yield ep, trusted, other, watcher
    finally:
        watcher.close()
        for proc in reversed(procs):
            proc.stop()


def test_hosts_given_to_security_init_are_added_to_loopback_s(tmp_path: Path) -> None:
    """The README's `security init DIR --host cell-pc --host 10.0.0.5`: the certificates name those
    and still name loopback, which every process on the cell's own machine dials."""
    subprocess.run(foldcell_argv("security", "init", str(tmp_path / "s"), "--host", "cell-pc", "--host",
                                 "10.0.0.5"), cwd=REPO, check=True, capture_output=True, timeout=60)
    certificate = x509.load_pem_x509_certificate((tmp_path / "s" / "cell" / "cell.pem").read_bytes())
    names = certificate.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    dns = set(names.get_values_for_type(x509.DNSName))
    addresses = {str(a) for a in names.get_values_for_type(x509.IPAddress)}
    assert {"localhost", "cell-pc"} <= dns, dns
    assert {"127.0.0.1", "10.0.0.5"} <= addresses, addresses


@pytest.mark.parametrize("host", ["/srv/cell", "cell pc", "cell-", "cell..pc", ""])
def test_security_init_refuses_a_host_no_certificate_can_name_and_writes_nothing(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], host: str) -> None:
    from tools.cli import main
    assert main(["security", "init", str(tmp_path / "s"), "--host", "cell-pc", "--host", host]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"foldcell: error: host {host!r}: not an IP address or a host name"), line
    assert not (tmp_path / "s").exists()


def test_security_init_makes_one_directory_per_role_and_keeps_the_ca_key_apart(tmp_path: Path) -> None:
    made = init(tmp_path / "s")
    top = tmp_path / "s"
    assert f"{top / 'ca-private' / 'ca.key'}" in made.stderr and "move it off" in made.stderr
    assert {p.name for p in top.iterdir()} == {"ca-private", *SECURITY.roles}
    ca = x509.load_pem_x509_certificate((top / "ca-private" / "ca.pem").read_bytes())
    for role in SECURITY.roles:
        own = top / role
        assert own.stat().st_mode & 0o777 == 0o700, f"{own}: not the owner's only"
        assert {p.name for p in own.iterdir()} == {"ca.pem", f"{role}.pem", f"{role}.key"}
        assert (own / f"{role}.key").stat().st_mode & 0o777 == 0o600
        assert (own / "ca.pem").read_bytes() == (top / "ca-private" / "ca.pem").read_bytes()
        certificate = x509.load_pem_x509_certificate((own / f"{role}.pem").read_bytes())
        certificate.verify_directly_issued_by(ca)
        assert certificate.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        if shutil.which("openssl"):
            check = subprocess.run(["openssl", "verify", "-CAfile", str(own / "ca.pem"),
                                    str(own / f"{role}.pem")], capture_output=True, text=True)
            assert check.returncode == 0, check.stdout + check.stderr
    assert (top / "ca-private").stat().st_mode & 0o777 == 0o700
    assert (top / "ca-private" / "ca.key").stat().st_mode & 0o777 == 0o600
    # what an observer's machine gets: nothing under its directory leads to another key
    reachable = [Path(d) / f for d, _, files in os.walk(top / "observer", followlinks=True) for f in files]
    assert sorted(p.name for p in reachable) == ["ca.pem", "observer.key", "observer.pem"]
    assert not any(p.is_symlink() for p in reachable)
    shown = subprocess.run(foldcell_argv("security", "show", str(top), "--json"), cwd=REPO,
                           capture_output=True, text=True, timeout=60)
    assert shown.returncode == 0, shown.stderr
    assert [row["role"] for row in json.loads(shown.stdout)] == list(SECURITY.roles)
    again = subprocess.run(foldcell_argv("security", "init", str(top)), cwd=REPO,
                           capture_output=True, text=True, timeout=60)
    assert again.returncode == 2 and "already holds a CA" in again.stderr


def test_a_process_runs_only_with_its_own_roles_directory(security_dirs, tmp_path: Path) -> None:
    trusted, other = security_dirs
    foreign = tmp_path / "foreign"
    shutil.copytree(trusted / "observer", foreign)
    shutil.copy(other / "observer" / "observer.pem", foreign / "observer.pem")
    flat = tmp_path / "flat"   # every key in one directory, as `security init` made it before
    shutil.copytree(trusted / "observer", flat)
    shutil.copy(trusted / "cell" / "cell.key", flat / "cell.key")
    result = subprocess.run(foldcell_argv("monitor", "--once", "--duration", "0",
                                          "--connect", "tcp/127.0.0.1:9", "--security", str(trusted)),
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result
    assert f"give this process its own, {trusted / 'observer'}" in result.stderr
    cases = ((foreign, "was not signed by"), (tmp_path / "none", "is not a directory"),
             (trusted / "cell", "is not the directory of role 'observer'"),
             (flat, "holds other keys than observer.key (cell.key)"))
    for directory, words in cases:
        with pytest.raises(SecurityError, match=re.escape(words)):
            identity(directory, "observer")
    assert identity(trusted / "observer", "observer").key == trusted / "observer" / "observer.key"


def test_strangers_cannot_connect_while_the_cells_own_tools_can(secured) -> None:
    ep, trusted, other, watcher = secured
    kinds = {"plain tcp": {"protocol": "tcp"},
             "tls without a certificate": {"security": trusted / "observer"},
             "a certificate of another CA": {"security": other / "operator", "role": "operator"}}
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
    observer = client(ep, trusted, "observer")
    operator = client(ep, trusted, "operator")
    try:
        assert wait_until(lambda: status.last() is not None, 20)
        assert not status.last().e_stopped
        for role, session in (("observer", observer), ("player", None)):
            if session is None:
                session = client(ep, trusted, role)
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
    forger = client(ep, trusted, "operator")
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


def test_a_monitor_in_a_terminal_given_an_observers_directory_watches(secured) -> None:
    ep, trusted, _other, _watcher = secured
    controller, terminal = pty.openpty()   # a person's terminal: the monitor would take command keys
    try:
        argv = foldcell_argv("monitor", "--duration", "3", "--cell", CELL, "--connect", ep.url,
                             "--security", str(trusted / "observer"))
        result = subprocess.run(argv, stdin=terminal, cwd=REPO, capture_output=True, text=True, timeout=60)
    finally:
        os.close(controller)
        os.close(terminal)
    assert result.returncode == 0, result.stderr
    assert "controller-master" in result.stdout


RECORDED_S = 1_000_000_000   # 2001: the stamps of a recorded session, told from a live sample's


def recorded_estop(path: Path, samples: int) -> Path:
    """A session recorded in this cell while its controller reported an e-stop."""
    with SessionWriter(path, cell=CELL) as writer:
        for i in range(samples):
            stamp = (RECORDED_S + i) * 1_000_000_000
            msg = messages.new(STATUS, header=messages.header(stamp), e_stopped=1)
            writer.write(f"/foldcell/{CELL}/controller/status", STATUS, messages.msgdef(STATUS),
                         messages.encode(STATUS, msg), stamp, stamp)
    return path


def test_a_replay_goes_to_a_cell_of_its_own_never_into_the_live_one(secured, tmp_path: Path) -> None:
    ep, trusted, _other, watcher = secured
    session = recorded_estop(tmp_path / "estop.mcap", 10)
    live = Stream(watcher, f"foldcell/{CELL}/controller/status", STATUS)
    replayed = Stream(watcher, f"foldcell/{CELL}{REPLAY_SUFFIX}/controller/status", STATUS)
    player = ("--connect", ep.url, "--security", str(trusted / "player"))

    def replay(*args: str) -> subprocess.CompletedProcess:
        argv = foldcell_argv("replay", str(session), "--rate", "max", "--json", *player, *args)
        return subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)

    refused = replay("--cell", CELL)
    assert refused.returncode == 2 and "ending in '-replay'" in refused.stderr, refused.stderr
    result = replay()
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)["published"] == 10
    assert wait_until(lambda: replayed.count() == 10, 20), replayed.count()
    with replayed.lock:
        assert all(m.e_stopped and m.header.stamp.sec >= RECORDED_S for m in replayed.items)
    count = live.count()
    assert wait_until(lambda: live.count() > count + 5, 20), "the live status goes on"
    with live.lock:
        assert not [m for m in live.items if m.header.stamp.sec < RECORDED_S + 100], "replayed live"


# ------------------------------------------------------------------ every role held to its rights
ACL_CELL = "acl"
# The layout (drivers/wire/registry.py): every published key (a wildcard chunk filled), every served
# key, and the liveliness token of every process of the design and of a CLI tool.
LAYOUT_PUBLISHED = tuple(spec.pattern.replace("*", "r1") for spec in KEYS if spec.kind == "pub")
LAYOUT_SERVED = tuple(spec.pattern for spec in KEYS if spec.kind == "queryable")
LAYOUT_TOKENS = tuple(f"alive/{name}" for name in
                      ("cell", "camera", "controller", "controller-master", "controller-slave", "cli-probe"))


def granted(role: str, kind: str, relative: str) -> bool:
    """Whether config/security.yaml gives `role` the right `kind` (publishes, serves, calls, alive)
    over `relative` in the live cell."""
    rights = SECURITY.roles[role]
    key = zenoh.KeyExpr(f"c/{relative}")
    return rights.cells == "live" and any(zenoh.KeyExpr(f"c/{pattern}").intersects(key)
                                          for pattern in getattr(rights, kind))


class Marked:
    """The samples marked `forged:<role>` or `canary:<role>` a session receives, on every cell."""

    def __init__(self, session: zenoh.Session):
        self.lock = threading.Lock()
        self.samples: list[tuple[str, bytes]] = []
        self.subscriber = session.declare_subscriber("foldcell/**", self._on)

    def _on(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        if payload.startswith((b"forged:", b"canary:")):
            with self.lock:
                self.samples.append((str(sample.key_expr), payload))

    def keys(self, mark: str) -> set[str]:
        with self.lock:
            return {key for key, payload in self.samples if payload.startswith(mark.encode())}


def test_every_role_sends_only_what_its_rights_allow(security_dirs, tmp_path: Path) -> None:
    """For every role, with its own certificate: a put on every published key of the layout, a
    queryable on every served key, a call of every served key and a token of every process it has no
    right to reach nobody (readers of two other roles, the callers allowed); its own get through. The
    player's rights hold in a replay cell only."""
    trusted, _other = security_dirs
    ep = Endpoint(ACL_CELL)
    router = start_router(ep, trusted, tmp_path / "router.log")
    sessions: list[zenoh.Session] = []
    declared: list = []   # kept referenced: queryables and tokens live as long as they are

    def open_client(role: str) -> zenoh.Session:
        sessions.append(client(ep, trusted, role))
        return sessions[-1]

    def live(relative: str) -> str:
        return f"foldcell/{ACL_CELL}/{relative}"

    try:
        readers = {role: Marked(open_client(role)) for role in ("observer", "operator")}
        forgers = {role: open_client(role) for role in SECURITY.roles}
        # a query is answered inside its own session when that session serves the key: callers and
        # servers are sessions of their own
        callers = {role: open_client(role) for role in SECURITY.roles if SECURITY.roles[role].calls}
        servers = {role: open_client(role) for role in SECURITY.roles if SECURITY.roles[role].serves}
        # the readers' subscriptions reach the router before anything is forged
        def readers_subscribed() -> bool:
            forgers["cell"].put(live("cell/state"), b"canary:cell")
            return all(live("cell/state") in r.keys("canary:") for r in readers.values())
        assert wait_until(readers_subscribed, 20)

        forged_calls: list[str] = []   # forbidden calls the allowed servers received
        for role, session in forgers.items():
            mark = f"forged:{role}".encode()
            for relative in LAYOUT_PUBLISHED:
                if not granted(role, "publishes", relative):
                    session.put(live(relative), mark)
            session.put(f"foldcell/{ACL_CELL}2/cell/state", mark)   # another cell: nobody's
            if SECURITY.roles[role].cells == "live":
                session.put(f"foldcell/{ACL_CELL}-replay/cell/state", mark)
            for relative in LAYOUT_SERVED:
                if not granted(role, "serves", relative):
                    declared.append(session.declare_queryable(live(relative),
                                                              lambda q, m=mark: q.reply(q.key_expr, m)))
            declared += [session.liveliness().declare_token(live(token))
                         for token in LAYOUT_TOKENS if not granted(role, "alive", token)]

        # what each role may do, declared after the forgeries: once it is through, they would be too
        canary_puts, canary_tokens = set(), set()
        for role, session in forgers.items():
            mark = f"canary:{role}".encode()
            cell = ACL_CELL if SECURITY.roles[role].cells == "live" else f"{ACL_CELL}-replay"
            own = [r for r in LAYOUT_PUBLISHED if granted(role, "publishes", r)]
            if SECURITY.roles[role].cells == "replay":
                own = ["cell/state"]
            if own:
                session.put(f"foldcell/{cell}/{own[0]}", mark)
                canary_puts.add(f"foldcell/{cell}/{own[0]}")
            if granted(role, "alive", "alive/cli-x") or SECURITY.roles[role].cells == "replay":
                token = f"foldcell/{cell}/alive/cli-canary-{role}"
                declared.append(session.liveliness().declare_token(token))
                canary_tokens.add(token)
            for relative in LAYOUT_SERVED:
                if granted(role, "serves", relative):
                    def serve(query: zenoh.Query, m: bytes = mark) -> None:
                        payload = query.payload.to_bytes() if query.payload is not None else b""
                        if payload.startswith(b"forged:"):
                            forged_calls.append(f"{payload.decode()} -> {query.key_expr}")
                        query.reply(query.key_expr, m)
                    declared.append(servers[role].declare_queryable(live(relative), serve))

        for name, reader in readers.items():
            assert wait_until(lambda r=reader: canary_puts <= r.keys("canary:"), 20), \
                f"{name}: allowed samples missing: {canary_puts - reader.keys('canary:')}"
            assert reader.keys("forged:") == set(), f"{name} received forged samples"
        watcher = sessions[0]
        assert wait_until(lambda: canary_tokens <= alive_everywhere(watcher), 20)
        assert alive_everywhere(watcher) == canary_tokens, "forged tokens are alive"

        for relative in LAYOUT_SERVED:
            role = next(r for r in callers if granted(r, "calls", relative))
            replies: list[bytes] = []

            def answered(key: str = live(relative), caller: str = role, out: list[bytes] = replies) -> bool:
                # every reply (not consolidated: a forged one would replace the canary on the same key)
                answers = callers[caller].get(key, target=zenoh.QueryTarget.ALL,
                                              consolidation=zenoh.ConsolidationMode.NONE, timeout=2.0)
                out[:] = [reply.ok.payload.to_bytes() for reply in answers if reply.ok is not None]
                return any(p.startswith(b"canary:") for p in out)
            assert wait_until(answered, 20), f"{relative}: its server does not answer {role}"
            assert not [p for p in replies if p.startswith(b"forged:")], f"{relative}: forged servers replied"
        pending = [forgers[role].get(live(relative), payload=f"forged:{role}".encode(),
                                     target=zenoh.QueryTarget.ALL, timeout=2.0)
                   for role in forgers for relative in LAYOUT_SERVED if not granted(role, "calls", relative)]
        for replies_of_one in pending:
            list(replies_of_one)
        assert forged_calls == [], "forbidden calls reached a server"

        # each process's own token
        own_tokens = {live(t) for role in forgers for t in LAYOUT_TOKENS[:-1] if granted(role, "alive", t)}
        declared += [forgers[role].liveliness().declare_token(live(t))
                     for role in forgers for t in LAYOUT_TOKENS[:-1] if granted(role, "alive", t)]
        assert wait_until(lambda: own_tokens <= alive_everywhere(watcher), 20)
    finally:
        for entity in declared:
            entity.undeclare()
        for session in sessions:
            session.close()
        router.stop()


def alive_everywhere(session: zenoh.Session) -> set[str]:
    return {str(reply.ok.key_expr) for reply in session.liveliness().get("foldcell/*/alive/*", timeout=2.0)
            if reply.ok is not None}


def test_only_the_controllers_and_the_cell_publish_controller_keys_and_the_player_no_live_key() -> None:
    """config/security.yaml against the least-privilege rules the cell's trust rests on (the wire test
    above holds the router to whatever the file grants)."""
    controllers = {"controller", "master", "slave"}
    for role in SECURITY.roles:
        published = {r for r in LAYOUT_PUBLISHED if granted(role, "publishes", r)}
        if role not in controllers | {"cell"}:   # the cell: what a MotoROS controller's state port reports
            assert not {r for r in published if r.startswith("controller/")}, role
        if role != "slave":
            assert not {r for r in published if r.startswith("controller/slave/")}, role
        if role != "cell":
            assert not {r for r in published if r.startswith("cell/")}, role
    player = SECURITY.roles["player"]
    assert player.cells == "replay" and not player.serves and not player.calls


def test_a_router_whose_certificate_does_not_name_the_host_dialled_is_named_as_the_cause(tmp_path):
    """Certificates made for other hosts only: the router listens, and a client dialling 127.0.0.1 is
    told that its certificate names other hosts (which), not that nobody answers."""
    from drivers.wire.security import create_security

    create_security(tmp_path / "sec", ["cell-pc", "10.0.0.5"])
    ep = Endpoint(CELL)
    router = start_router(ep, tmp_path / "sec", tmp_path / "router.log")
    try:
        done = subprocess.run(foldcell_argv("topic", "hz", "cell/state", "--duration", "0.1", *ep.args(),
                                            "--security", str(tmp_path / "sec" / "observer")),
                              cwd=REPO, capture_output=True, text=True, timeout=60)
    finally:
        router.stop()
    assert done.returncode == 2, done
    assert (f"--connect {ep.url}: answers, but its certificate does not name 127.0.0.1 (it names cell-pc, "
            "10.0.0.5): make the certificates again with `foldcell security init DIR --host 127.0.0.1`"
            in done.stderr), done.stderr
    assert "Traceback" not in done.stderr and "nobody answers" not in done.stderr, done.stderr
