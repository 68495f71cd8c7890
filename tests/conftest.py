"""Shared test fixtures: loopback Zenoh endpoints, `foldcell` subprocesses stopped by signal, perception
fitted on the simulated world."""

from __future__ import annotations

import contextlib
import fcntl
import os
import pty
import signal
import socket
import struct
import subprocess
import sys
import termios
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from drivers.wire.messages import NobodyServes
from drivers.wire.settings import WireSettings, load_wire_settings

REPO = Path(__file__).resolve().parents[1]
# a `foldcell demo` run by a test is killed (its children die with it) before pytest gives up on the
# test: such tests carry @pytest.mark.timeout(DEMO_TIMEOUT_S + 60)
DEMO_TIMEOUT_S = 540


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Endpoint:
    """One shared loopback endpoint for a test: every process listens on and connects to it."""

    def __init__(self, cell: str = "test"):
        self.port = free_port()
        self.cell = cell

    @property
    def url(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def args(self, cell: str | None = None) -> list[str]:
        return ["--cell", cell or self.cell, "--listen", self.url, "--listen", "tcp/127.0.0.1:0",
                "--connect", self.url]

    def settings(self, cell: str | None = None) -> WireSettings:
        return load_wire_settings().overridden(cell_id=cell or self.cell,
                                               listen=[self.url, "tcp/127.0.0.1:0"], connect=[self.url])


@pytest.fixture
def endpoint() -> Endpoint:
    return Endpoint()


class Proc:
    """A `foldcell` (or python -m) subprocess; stopped with SIGINT, killed if it hangs."""

    def __init__(self, argv: list[str], log_path: Path):
        self.argv = argv
        self.log_path = log_path
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        # the child writes its stderr to its own copy of the descriptor; ours closes once it has started
        with open(log_path, "wb") as log:
            self.popen = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=log, cwd=REPO, env=env)

    def stop(self, sig: int = signal.SIGINT, timeout: float = 15.0) -> int:
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
            try:
                self.popen.wait(timeout)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()
        return self.popen.returncode

    def stderr(self) -> str:
        return self.log_path.read_text(errors="replace")


def foldcell_argv(*args: str) -> list[str]:
    return [sys.executable, "-m", "tools.cli", *args]


@pytest.fixture
def spawn(tmp_path: Path) -> Iterator:
    procs: list[Proc] = []

    def start(argv: list[str]) -> Proc:
        proc = Proc(argv, tmp_path / f"proc{len(procs)}.log")
        procs.append(proc)
        return proc

    yield start
    for proc in reversed(procs):  # dependents (started later) stop first
        proc.stop()


TERMINAL_ROWS, TERMINAL_COLUMNS = 60, 160


@contextlib.contextmanager
def on_terminal(argv: list[str]) -> Iterator[tuple[subprocess.Popen, int]]:
    """A process with a pseudo-terminal for stdin and stdout: (the process, the terminal's master end).
    Killed if still running at the end."""
    master, slave = pty.openpty()
    # a terminal tall enough for a whole cell's screen (a 24-row one cuts the topic table's tail)
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", TERMINAL_ROWS, TERMINAL_COLUMNS, 0, 0))
    # LINES/COLUMNS, if the test runner's environment has them, would override the terminal's own size
    env = {**os.environ, "LINES": str(TERMINAL_ROWS), "COLUMNS": str(TERMINAL_COLUMNS)}
    proc = subprocess.Popen(argv, cwd=REPO, stdin=slave, stdout=slave, stderr=subprocess.DEVNULL, env=env)
    os.close(slave)
    try:
        yield proc, master
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        os.close(master)


def accepts(port: int) -> bool:
    """Whether something listens on 127.0.0.1:`port`."""
    with contextlib.suppress(OSError), socket.create_connection(("127.0.0.1", port), timeout=1.0):
        return True
    return False


def wait_until(predicate, timeout: float = 10.0, interval: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(interval)
    return bool(predicate())


def request_once_served(wire, relative_key: str, msg, within: float = 30.0, **options):
    """`wire.request`, asked again (for up to `within` s) while a session just opened has no route to the
    queryable yet."""
    deadline = time.monotonic() + within
    while True:
        try:
            return wire.request(relative_key, msg, **options)
        except NobodyServes:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@pytest.fixture(scope="session")
def fitted_perception():
    """Perception config, a table model and garment models fitted here on the simulated world (empty
    tables, landmarks of random garments), so a test holds whatever the shipped files were fitted on."""
    from cell.perception import fit_table_model, learn_model, load_perception_config
    from drivers.common.garments import CATEGORIES, LANDMARKS
    from tests.perception.scenes import empty_table, landmark_polygons
    cfg = load_perception_config()
    table = fit_table_model([empty_table(seed) for seed in (1001, 1002, 1003)], None, cfg)
    floors = {"angle": cfg.angle_var_floor, "length": cfg.length_var_floor}
    rng = np.random.default_rng(1)
    models = {category: learn_model(category, landmark_polygons(category, 80, rng), LANDMARKS[category],
                                    vertices, floors)
              for category, vertices in zip(CATEGORIES, (10, 14, 18, 18), strict=True)}
    return cfg, table, models
