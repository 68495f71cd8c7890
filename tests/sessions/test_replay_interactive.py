"""`foldcell replay` in a terminal (keyboard pause, step, quit) and `--loop` seen by the monitor."""

from __future__ import annotations

import fcntl
import os
import select
import struct
import subprocess
import termios
import threading
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


class Terminal:
    """The pty a process runs on: what it writes there (its progress bar), read as it comes."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        # a terminal of 24 x 120 characters: on one of no size the progress bar draws nothing
        fcntl.ioctl(self.slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 120, 0, 0))
        self.text = ""
        self.lock = threading.Lock()
        self.done = threading.Event()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    def _read(self) -> None:
        while not self.done.is_set():
            if select.select([self.master], [], [], 0.05)[0]:
                try:
                    chunk = os.read(self.master, 4096).decode(errors="replace")
                except OSError:   # the process's side is closed
                    return
                with self.lock:
                    self.text += chunk

    def type(self, keys: bytes) -> int:
        """Type `keys`; returns where the output that follows them starts."""
        with self.lock:
            mark = len(self.text)
        os.write(self.master, keys)
        return mark

    def shows(self, word: str, since: int) -> bool:
        with self.lock:
            return word in self.text[since:]

    def close(self) -> None:
        self.done.set()
        self.reader.join(5)
        os.close(self.master)
        os.close(self.slave)


def test_keyboard_pauses_steps_and_quits(session: Path) -> None:
    # The keys reach the replayer, each seen take effect; that a held replayer publishes nothing and a
    # step exactly one sample is checked on the engine (test_replay_engine.py), where a hold is an event
    ep = Endpoint()
    received: list[RawSample] = []
    lock = threading.Lock()

    def on(raw: RawSample) -> None:
        with lock:
            received.append(raw)

    count = lambda: len(received)  # noqa: E731
    terminal = Terminal()
    with Wire(ep.settings("kb-observer"), "observer") as wire:
        wire.subscribe_raw("foldcell/kb/**", on)
        proc = subprocess.Popen(
            foldcell_argv("replay", str(session), "--loop", "--rate", "0.5", *ep.args("kb")),
            cwd=REPO,
            stdin=terminal.slave,
            stdout=subprocess.DEVNULL,
            stderr=terminal.slave,   # the progress bar, which names the replay's state
        )
        try:
            assert wait_until(lambda: count() > 5, 20)
            since = terminal.type(b" ")  # pause
            assert wait_until(lambda: terminal.shows("paused", since), 10), terminal.text[-800:]
            before = count()
            terminal.type(b"s")  # step: a sample more
            assert wait_until(lambda: count() > before, 5)
            since = terminal.type(b" ")  # resume
            assert wait_until(lambda: terminal.shows("replay", since), 10)
            assert wait_until(lambda: count() > before + 10, 10)
            terminal.type(b"q")  # quit
            assert proc.wait(15) == 0
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            terminal.close()


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
