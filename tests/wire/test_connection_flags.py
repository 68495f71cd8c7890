"""The connection flags as Zenoh's own tools take them, on real sessions over loopback: `--listen` adds
to the process's own listener, `--connect` alone binds nothing shared, a busy `--listen` port is an
error naming it, and an endpoint nobody answers is a warning naming it (Zenoh keeps trying it)."""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh

from drivers.wire.settings import (
    ENV_CONNECT,
    ENV_LISTEN,
    EndpointError,
    WireSettings,
    check_endpoint,
    load_wire_settings,
    settings_from_environment,
    warn_open_to_network,
)
from drivers.wire.transport import Wire
from tests.conftest import REPO, foldcell_argv, free_port, wait_until

CELL = "flags"
OWN_PORT = "tcp/127.0.0.1:0"


def url(port: int) -> str:
    return f"tcp/127.0.0.1:{port}"


@pytest.fixture
def cell_config(tmp_path: Path) -> tuple[Path, int]:
    """A cell file whose shared meeting point is a free port of this test (not 7447)."""
    shared = free_port()
    path = tmp_path / "cell.yaml"
    path.write_text(f"cell_id: {CELL}\nzenoh:\n  listen: [{url(shared)}, {OWN_PORT}]\n"
                    f"  connect: [{url(shared)}]\n")
    return path, shared


@contextlib.contextmanager
def opened(settings: WireSettings, name: str) -> Iterator[Wire]:
    wire = Wire(settings, name)
    try:
        yield wire
    finally:
        wire.close()


def sees(wire: Wire, process: str) -> bool:
    """Whether `wire` sees `process`'s liveliness token (so a link carries declarations between them)."""
    replies = wire.session.liveliness().get(wire.key(f"alive/{process}"), timeout=1.0)
    return any(reply.ok is not None for reply in replies)


def linked_to(wire: Wire, endpoint: str) -> bool:
    return any(link.dst == endpoint for link in wire.session.info.links())


def test_listen_adds_to_the_own_port_and_the_meeting_point(cell_config) -> None:
    path, shared = cell_config
    given = free_port()
    settings = load_wire_settings(path).overridden(listen=[url(given)])
    assert settings.listen == (url(given), url(shared), OWN_PORT)
    assert settings.connect == (url(shared),)
    # started first, the process also takes the configured meeting point: the cell meets it there
    with opened(settings, "subject"):
        only_given = load_wire_settings(path).overridden(listen=[OWN_PORT], connect=[url(given)])
        through_shared = load_wire_settings(path).overridden(listen=[OWN_PORT], connect=[url(shared)])
        with opened(only_given, "stranger") as stranger, opened(through_shared, "member") as member:
            assert wait_until(lambda: sees(stranger, "subject"), 15), "not reached on the given endpoint"
            assert linked_to(stranger, url(given))
            assert wait_until(lambda: sees(member, "subject"), 15), "not reached on the meeting point"
            assert linked_to(member, url(shared))


def test_processes_given_one_endpoint_to_listen_on_and_connect_to_form_a_mesh(cell_config) -> None:
    """The demo's case: every process given `--listen X --connect X`. The first gets X, the others
    reach it there, and their own ports let gossip link them to each other (peers do not forward)."""
    path, _ = cell_config
    meeting = url(free_port())
    settings = load_wire_settings(path).overridden(listen=[meeting], connect=[meeting])
    assert settings.listen == (meeting, OWN_PORT)
    with opened(settings, "first"), opened(settings, "second") as second, opened(settings, "third") as third:
        assert wait_until(lambda: sees(second, "third") and sees(third, "second"), 15)


def test_connect_alone_binds_nothing_shared(cell_config) -> None:
    path, shared = cell_config
    other = free_port()
    settings = load_wire_settings(path).overridden(connect=[url(other)])
    assert settings.listen == (OWN_PORT,)
    peer_settings = load_wire_settings(path).overridden(listen=[url(other)], connect=[url(other)])
    with opened(peer_settings, "peer"), opened(settings, "subject") as subject:
        assert wait_until(lambda: sees(subject, "peer"), 15)
        assert linked_to(subject, url(other))
        with socket.socket() as sock:   # the configured meeting point is still free
            sock.bind(("127.0.0.1", shared))


def test_a_busy_listen_port_is_an_error_naming_it(cell_config) -> None:
    path, _ = cell_config
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        busy = url(sock.getsockname()[1])
        done = subprocess.run(foldcell_argv("monitor", "--once", "--json", "--duration", "0.5", "--config",
                                            str(path), "--listen", busy),
                              cwd=REPO, capture_output=True, text=True, timeout=60)
        assert done.returncode == 2, done
        assert done.stderr.strip() == f"foldcell: error: --listen {busy}: address already in use", done.stderr


def test_a_busy_or_foreign_address_in_the_environment_is_an_error_naming_it(cell_config, monkeypatch) -> None:
    path, _ = cell_config
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        sock.listen()
        busy = url(sock.getsockname()[1])
        monkeypatch.setenv(ENV_LISTEN, busy)
        with pytest.raises(EndpointError, match=f"^{ENV_LISTEN} {busy}: address already in use$"):
            Wire(settings_from_environment(load_wire_settings(path)), "subject")
    foreign = "tcp/192.0.2.1:7447"   # TEST-NET-1: no interface of this machine has it
    monkeypatch.setenv(ENV_LISTEN, foreign)
    with pytest.raises(EndpointError, match=f"^{ENV_LISTEN} {foreign}: cannot assign requested address$"):
        Wire(settings_from_environment(load_wire_settings(path)), "subject")


def test_a_client_without_its_router_is_an_error_naming_it(cell_config) -> None:
    path, _ = cell_config
    nobody = url(free_port())
    settings = load_wire_settings(path).overridden(connect=[nobody], mode="client")
    with pytest.raises(EndpointError, match=f"^--connect {nobody}: nobody answers"):
        Wire(settings, "subject")


def test_an_unanswered_connect_endpoint_is_a_warning_naming_it_and_is_retried(
        cell_config, monkeypatch, caplog: pytest.LogCaptureFixture) -> None:
    path, _ = cell_config
    answered, nobody = url(free_port()), url(free_port())
    monkeypatch.setenv(ENV_CONNECT, f"{answered},{nobody}")
    settings = settings_from_environment(load_wire_settings(path))
    peer_settings = load_wire_settings(path).overridden(listen=[answered], connect=[answered])
    caplog.set_level(logging.WARNING, logger="drivers.wire.settings")

    def warnings() -> list[str]:
        return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]

    with opened(peer_settings, "peer"), opened(settings, "subject") as subject:
        assert wait_until(lambda: warnings(), 15)
        assert len(warnings()) == 1 and warnings()[0].startswith(f"{ENV_CONNECT} {nobody}: nobody answers"), \
            warnings()
        # Zenoh keeps trying: a process that comes up there later is reached
        with opened(load_wire_settings(path).overridden(listen=[nobody], connect=[nobody]), "late"):
            assert wait_until(lambda: sees(subject, "late"), 20)
            assert linked_to(subject, nobody)


def test_zenoh_opens_what_the_settings_name(cell_config) -> None:
    """Required listeners carry Zenoh's own exit_on_failure; meeting points do not."""
    path, shared = cell_config
    given = url(free_port())
    conf = load_wire_settings(path).overridden(listen=[given]).zenoh_config()
    assert conf.get_json("listen/endpoints") == (
        f'["{given}#exit_on_failure=true","{url(shared)}","{OWN_PORT}"]')
    assert isinstance(conf, zenoh.Config)


def test_only_an_open_process_that_listens_beyond_loopback_warns(cell_config, caplog) -> None:
    """A warning per endpoint beyond loopback, naming it and how to secure the cell; none for loopback
    addresses and names, none for a secured process."""
    path, _ = cell_config
    base = load_wire_settings(path)
    caplog.set_level(logging.WARNING, logger="drivers.wire.settings")
    cases = [
        (base.overridden(listen=(wide := ["tcp/0.0.0.0:7000", "tcp/[::]:7001"])), wide),
        (base.overridden(listen=["tcp/127.0.0.2:7000", "tcp/[::1]:7001", "tcp/localhost:7002"]), []),
        (base.overridden(listen=["tcp/0.0.0.0:7000"], security_dir=path.parent, role="router"), []),
    ]
    for settings, open_to in cases:
        caplog.clear()
        warn_open_to_network(settings)
        warned = [r.getMessage() for r in caplog.records]
        assert [w.split(": this process", 1)[0] for w in warned] == [f"--listen {e}" for e in open_to], warned
        assert all("anyone who can reach it can command the robot" in w and "--security" in w for w in warned)


def test_an_open_process_listening_on_every_interface_says_so_at_start(cell_config) -> None:
    path, _ = cell_config
    wide = f"tcp/0.0.0.0:{free_port()}"
    argv = foldcell_argv("monitor", "--once", "--duration", "0.5", "--config", str(path), "--listen", wide)
    done = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert f"--listen {wide}: this process is open (no --security)" in done.stderr, done.stderr


@pytest.mark.parametrize(("endpoint", "reason"), [
    ("tcp/127.0.0.1:99999", "port '99999' is not a number from 0 to 65535"),
    ("tcp/127.0.0.1:port", "port 'port' is not a number"),
    ("tcp/127.0.0.1", "needs a host and a port"),
    ("tcp/:7448", "needs a host and a port"),
    ("127.0.0.1:7448", "is not a Zenoh endpoint"),
    ("tcp/nohost.invalid:7448", "host 'nohost.invalid' does not resolve"),
])
def test_a_bad_endpoint_is_refused_naming_the_flag_and_the_reason(endpoint: str, reason: str) -> None:
    argv = foldcell_argv("topic", "hz", "cell/state", "--duration", "0.1", "--connect", endpoint)
    result = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"foldcell: error: --connect: {endpoint!r} ") and reason in line, line


@pytest.mark.parametrize("endpoint", ["tcp/127.0.0.1:0", "tcp/[::1]:7448", "tcp/localhost:65535",
                                      "tcp/127.0.0.1:7448#iface=lo", "unixsock-stream//tmp/cell.sock"])
def test_good_endpoints_pass(endpoint: str) -> None:
    assert check_endpoint(endpoint, "--connect") == endpoint


@pytest.mark.parametrize("given_by", ["FOLDCELL_SECURITY", "--security"])
def test_a_bad_security_directory_is_blamed_on_what_gave_it(tmp_path: Path, given_by: str) -> None:
    argv = foldcell_argv("topic", "hz", "cell/state", "--duration", "0.1")
    env = dict(os.environ)
    env.pop("FOLDCELL_SECURITY", None)
    if given_by == "--security":
        argv += ["--security", str(tmp_path)]
    else:
        env["FOLDCELL_SECURITY"] = str(tmp_path)
    result = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60, env=env)
    assert result.returncode == 2, result
    (line,) = result.stderr.strip().splitlines()
    missing = tmp_path / "ca.pem"
    assert line == f"foldcell: error: {given_by}: {missing} is missing (the role 'observer' needs it)", line


def test_a_tool_that_hears_nobody_says_when_nobody_was_at_the_meeting_point(cell_config, spawn) -> None:
    path, shared = cell_config
    argv = foldcell_argv("topic", "echo", "cell/state", "--timeout", "1", "--config", str(path))
    alone = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert alone.returncode == 1, alone.stderr
    assert f"nobody was at {url(shared)}, the cell's meeting point" in alone.stderr, alone.stderr
    # a process of the cell holds the meeting point: the tool met it there, and the cell is just silent
    router = spawn(foldcell_argv("router", "--config", str(path)))
    assert wait_until(lambda: "router serving" in router.stderr(), 60), router.stderr()
    met = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert met.returncode == 1, met.stderr
    assert "no message on" in met.stderr and "nobody was at" not in met.stderr, met.stderr
