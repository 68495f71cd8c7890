"""`foldcell replay` in a terminal (keyboard pause, step, quit) and `--loop` seen by the monitor."""

from __future__ import annotations

import os
import subprocess
import threading
import time
from pathlib import Path

import pytest

from drivers.sessions.monitor.live import MonitorSession
from drivers.wire.transport import RawSample, Wire
from tests.bench.bench_replay_monitor import write_session
from tests.conftest import REPO, Endpoint, foldcell_argv, wait_until


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("interactive") / "s.mcap"
    write_session(path, 2.0)
    return path


def test_keyboard_pauses_steps_and_quits(session: Path) -> None:
    ep = Endpoint()
    received: list[RawSample] = []
    lock = threading.Lock()

    def on(raw: RawSample) -> None:
        with lock:
            received.append(raw)

    count = lambda: len(received)  # noqa: E731
    master, slave = os.openpty()
    with Wire(ep.settings("kb-observer"), "observer") as wire:
        wire.subscribe_raw("foldcell/kb/**", on)
        proc = subprocess.Popen(
            foldcell_argv("replay", str(session), "--loop", "--rate", "0.5", *ep.args("kb")),
            cwd=REPO,
            stdin=slave,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        try:
            assert wait_until(lambda: count() > 5, 20)
            os.write(master, b" ")  # pause
            time.sleep(0.5)
            paused_at = count()
            time.sleep(0.6)
            assert count() == paused_at  # nothing while paused
            os.write(master, b"s")  # step: exactly one sample
            assert wait_until(lambda: count() == paused_at + 1, 5)
            time.sleep(0.5)
            assert count() == paused_at + 1
            os.write(master, b" ")  # resume
            assert wait_until(lambda: count() > paused_at + 10, 10)
            os.write(master, b"q")  # quit
            assert proc.wait(15) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            os.close(master)
            os.close(slave)


def test_a_looping_replay_shows_as_replay_and_then_as_gone(session: Path) -> None:
    ep = Endpoint()
    with MonitorSession(ep.settings("lp-watch"), "lp", "monitor-test") as mon:
        proc = subprocess.Popen(
            foldcell_argv("replay", str(session), "--loop", "--rate", "4", *ep.args("lp")),
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            cell = lambda: mon.snapshot()["cells"].get("lp", {})  # noqa: E731
            joints = lambda: cell().get("topics", {}).get("controller/joint_states", {}).get("count", 0)  # noqa: E731
            assert wait_until(lambda: cell().get("replay") and cell().get("alive") and joints() > 0, 30)
            # looping: the 2 s session runs out, yet samples keep coming (more than one pass holds)
            passes = joints()
            assert wait_until(lambda: joints() > passes + 600, 60)
            proc.send_signal(2)
            assert proc.wait(15) == 0
            assert wait_until(lambda: cell()["gone"], 30)
            assert not cell()["replay"]
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
