"""`foldcell monitor` with real processes on loopback Zenoh."""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

from drivers.sessions.mcap.reader import iter_messages
from drivers.sessions.monitor.live import MonitorSession
from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.conftest import REPO, Endpoint, foldcell_argv, on_terminal, wait_until
from tests.nodes.fake_cell import STATES

BAD_SAMPLES_SENT = len(STATES) - STATES.index("matching")


def node_argv(ep: Endpoint, cell: str, *extra: str) -> list[str]:
    return [sys.executable, "-m", "tests.nodes.fake_cell", *ep.args(cell), *extra]


def test_a_cell_shows_as_gone_when_its_processes_die(spawn) -> None:
    ep = Endpoint()
    with MonitorSession(ep.settings("watcher"), "*", "monitor-test") as mon:
        nodes = [
            spawn(node_argv(ep, "doomed", "--forever", "--state-period", "0.1", "--joint-hz", "250"))
            for _ in range(2)
        ]
        cells = lambda: mon.snapshot()["cells"]  # noqa: E731

        def up() -> bool:
            c = cells().get("doomed")
            return bool(c and c["alive"] and c["topics"].get("controller/joint_states"))

        assert wait_until(up, 20)
        assert not cells()["doomed"]["gone"]
        # the stream keeps being followed (how fast, and how soon a death shows: `make bench`)
        joints = lambda: cells()["doomed"]["topics"]["controller/joint_states"]["count"]  # noqa: E731
        seen = joints()
        assert wait_until(lambda: joints() >= seen + 250, 30)
        for n in nodes:
            os.kill(n.popen.pid, signal.SIGKILL)
        assert wait_until(lambda: cells()["doomed"]["gone"], 30), "not shown as gone"
        cell = cells()["doomed"]
        assert not cell["alive"] and cell["processes"] == []
        assert [p["name"] for p in cell["processes_gone"]] == ["fake-cell"]


def test_malformed_samples_show_as_errors_and_the_monitor_keeps_going(spawn, tmp_path, monkeypatch) -> None:
    # room for every error the node sends (the default keeps the last 10)
    config = tmp_path / "config"
    shutil.copytree(REPO / "config", config)
    settings = config / "replay_monitor.yaml"
    settings.write_text(settings.read_text().replace("max_errors: 10 ", "max_errors: 100 "))
    monkeypatch.setenv("FOLDCELL_CONFIG_DIR", str(config))
    ep = Endpoint("bad")
    monitor = spawn(foldcell_argv("monitor", "--once", "--json", "--duration", "120", *ep.args()))
    bad_keys = ["cell/state", "controller/joint_states", "controller/status", "cell/log", "camera/image"]
    node = subprocess.run(
        node_argv(
            ep, "bad", "--state-period", "0.15", "--wait", "8", *[a for k in bad_keys for a in ("--bad", k)]
        ),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert node.returncode == 0, node.stderr
    os.kill(monitor.popen.pid, signal.SIGINT)  # print the snapshot now
    out, _ = monitor.popen.communicate(timeout=20)
    cell = json.loads(out)["cells"]["bad"]
    wire_errors = {e["where"]: e["text"] for e in cell["errors"] if e["source"] == "wire"}
    assert set(wire_errors) == {f"foldcell/bad/{k}" for k in bad_keys}
    assert all(wire_errors.values())
    for k in bad_keys:  # one per state from `matching` on; the monitor's drop lanes may lose some
        assert 1 <= cell["topics"][k]["bad"] <= BAD_SAMPLES_SENT
    # after the bad samples (sent on `matching`) the states went on to the end
    assert cell["states_seen"] == list(STATES)
    assert any(e["source"] == "log" and e["text"] == "state verifying" for e in cell["errors"])


def test_watching_every_cell_and_recording(spawn, tmp_path: Path) -> None:
    ep = Endpoint()
    path = tmp_path / "mon.mcap"
    monitor = spawn(
        foldcell_argv(
            "monitor", "--once", "--json", "--duration", "120", "--record", str(path), *ep.args("*")
        )
    )
    runs = [
        subprocess.Popen(
            node_argv(ep, cell, "--state-period", "0.1", "--wait", "8"),
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        for cell in ("one", "two")
    ]
    for r in runs:
        assert r.wait(60) == 0
    os.kill(monitor.popen.pid, signal.SIGINT)
    out, _ = monitor.popen.communicate(timeout=20)
    assert monitor.popen.returncode == 0
    snap = json.loads(out)
    assert snap["watching"] == "*"
    for cell in ("one", "two"):
        assert snap["cells"][cell]["states_seen"] == list(STATES)
        assert snap["cells"][cell]["gone"]  # both nodes have exited
    topics = {m.topic for m in iter_messages(path)}
    assert {"/foldcell/one/cell/state", "/foldcell/two/cell/state"} <= topics


def test_text_mode_once_and_bad_arguments() -> None:
    ep = Endpoint("quiet")
    r = subprocess.run(
        foldcell_argv("monitor", "--once", "--duration", "0.2", *ep.args()),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 1 and "foldcell monitor - watching quiet" in r.stdout   # nobody there
    r = subprocess.run(
        foldcell_argv("monitor", "--once", "--duration", "-1", *ep.args()),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 2 and r.stderr.startswith("foldcell: error: --duration")


def test_live_json_lines_until_duration(tmp_path: Path) -> None:
    ep = Endpoint("lines")
    r = subprocess.run(
        foldcell_argv("monitor", "--json", "--duration", "1.0", *ep.args()),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    docs = [json.loads(line) for line in r.stdout.splitlines() if line.strip()]
    assert len(docs) >= 3 and all(d["watching"] == "lines" for d in docs)


def test_terminal_dashboard_redraws_and_quits_on_q(spawn) -> None:
    ep = Endpoint("tty")
    spawn(node_argv(ep, "tty", "--forever", "--state-period", "0.1", "--wait", "0"))
    with on_terminal(foldcell_argv("monitor", *ep.args())) as (proc, master):
        screen = read_screen_until(master, b"controller/joint_states")
        assert b"\x1b[H\x1b[2J" in screen and b"cell tty" in screen
        os.write(master, b"q")
        assert proc.wait(15) == 0


def read_screen_until(master: int, needle: bytes, timeout: float = 20.0) -> bytes:
    """What the terminal shows from now until `needle` appears (it fails the test when it does not)."""
    screen = b""
    deadline = time.monotonic() + timeout
    while needle not in screen and time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if ready:
            screen += os.read(master, 65536)
    assert needle in screen, f"{needle!r} not shown; the terminal shows {screen[-2000:]!r}"
    return screen


def test_keys_pause_resume_and_abort_the_watched_cell_after_confirmation() -> None:
    ep = Endpoint("keys")
    received: list[str] = []

    def on_command(request, _info):
        received.append(request.command)
        if request.command == "abort":
            return messages.new("foldcell_msgs/msg/CellReply", accepted=False, text="abort: not in idle",
                                state="idle")
        return messages.new("foldcell_msgs/msg/CellReply", accepted=True, text="", state="paused")

    with on_terminal(foldcell_argv("monitor", *ep.args())) as (proc, master):
        with Wire(ep.settings("keys"), "cell") as cell:
            cell.serve("cell/command", on_command)
            read_screen_until(master, b"keys: p pause  r resume  a abort  q quit")
            os.write(master, b"a")
            read_screen_until(master, b"abort keys? [y/N]")
            os.write(master, b"q")  # an answer, not quitting: cancels
            read_screen_until(master, b"abort keys: cancelled")
            assert proc.poll() is None and received == []
            os.write(master, b"p")
            read_screen_until(master, b"pause keys? [y/N]")
            os.write(master, b"y")
            read_screen_until(master, b"pause keys: accepted, state paused")
            os.write(master, b"ay")
            read_screen_until(master, b"abort keys: REFUSED: abort: not in idle")
            assert received == ["pause", "abort"]
        # the cell has gone: a command that nobody takes says so
        os.write(master, b"ry")
        read_screen_until(master, b"resume keys: REFUSED: ")
        os.write(master, b"q")
        assert proc.wait(15) == 0


def test_keys_are_off_watching_every_cell_or_without_a_terminal() -> None:
    ep = Endpoint("nokeys")
    with on_terminal(foldcell_argv("monitor", *ep.args("*"))) as (proc, master):
        read_screen_until(master, b"keys off: watching every cell (--cell ID to command one)")
        os.write(master, b"a")
        read_screen_until(master, b"abort: not sent: watching every cell")
        os.write(master, b"q")
        assert proc.wait(15) == 0
    r = subprocess.run(foldcell_argv("monitor", "--duration", "0.5", *ep.args()), cwd=REPO,
                       stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "keys off: stdin is not a terminal" in r.stdout
