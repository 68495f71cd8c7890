"""The chaos soak: the split cell (master, slave, camera, cell daemon and an independent recorder) folds
garments for `FOLDCELL_CHAOS_S` seconds (default 600) while faults are injected at random points of the
folds: e-stops, SIGKILLs of the master, the slave, the camera and the cell daemon, floods of malformed
requests, and (where network namespaces can be made, with the controllers on the far side of a veth
link) partitions. After each fault the operator's steps of the README's recovery table are followed.

Printed: garments folded, faults injected by kind with the time to the cell's safe state (paused or
fault, as an observer sees it), its reason and the time until the cell folds again; processes that died
unasked; reliable samples lost in the independent recording (gaps in each publisher's sequence
numbers); memory growth of the processes that ran the whole soak.

    FOLDCELL_CHAOS_S=120 .venv/bin/python -m tests.bench chaos
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import socket
import statistics
import threading
import time
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

from mcap.reader import make_reader

from drivers.common.garments import CATEGORIES
from drivers.controller import codec
from drivers.controller.codes import Command
from drivers.wire import messages
from drivers.wire.registry import spec_for
from drivers.wire.settings import load_wire_settings
from drivers.wire.transport import Wire
from tests.bench.targets import check
from tests.conftest import Proc, foldcell_argv, free_port, wait_until
from tests.netns import NetNamespace

SOAK_S = float(os.environ.get("FOLDCELL_CHAOS_S", "600"))
SEED = int(os.environ.get("FOLDCELL_CHAOS_SEED", "7"))
CELL = "chaos"
TIME_SCALE = 5.0
KINDS = ("none", "e-stop", "kill master", "kill slave", "kill camera", "kill cell", "flood", "partition")
RELIABLE = ("cell/state", "cell/log", "cell/fold_report", "perception/observation")
TERMINAL = {"done", "failed", "fault"}
SAFE = {"paused", "fault"}
START_TIMEOUT_S = 120.0
GARMENT_TIMEOUT_S = 300.0
FLOOD_REQUESTS = 2000
PARTITION_S = (1.0, 3.0)
RECOVERY_TARGET = 1.0        # share of faults after which the cell folds again
MEMORY_GROWTH_TARGET_MB = 100.0


@dataclass
class Injected:
    kind: str
    safe_s: float | None = None      # to the cell's paused/fault state, seen by an observer
    reason: str = ""
    recovered_s: float | None = None  # to the cell folding again (None: it did not)
    outcome: str = ""


@dataclass
class Soak:
    garments: Counter = field(default_factory=Counter)   # outcome -> count
    injected: list[Injected] = field(default_factory=list)
    unasked_deaths: list[str] = field(default_factory=list)


class Observer:
    """Every `cell/state` with its arrival time."""

    def __init__(self, wire: Wire):
        self.seen: list[tuple[float, Any]] = []
        self.changed = threading.Condition()
        wire.subscribe("cell/state", self._on)

    def _on(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.changed:
            self.seen.append((time.monotonic(), msg))
            self.changed.notify_all()

    def first(self, states: set[str], since: float, timeout: float) -> tuple[float, Any] | None:
        deadline = time.monotonic() + timeout
        with self.changed:
            while time.monotonic() < deadline:
                for at, msg in self.seen:
                    if at >= since and msg.state in states:
                        return at, msg
                self.changed.wait(0.1)
        return None

    def last(self) -> str:
        with self.changed:
            return self.seen[-1][1].state if self.seen else ""


class Cell:
    """The processes, started and restarted the way an operator would."""

    def __init__(self, logs: Path, namespace: NetNamespace | None):
        self.logs = logs
        self.namespace = namespace
        port = free_port()
        if namespace is None:
            self.shared = f"tcp/127.0.0.1:{port}"
            self.far = self.near = ["--cell", CELL, "--listen", "tcp/127.0.0.1:0", "--connect", self.shared]
        else:
            self.shared = f"tcp/{namespace.far}:{port}"
            self.far = ["--cell", CELL, "--listen", f"tcp/{namespace.far}:0", "--connect", self.shared]
            self.near = ["--cell", CELL, "--listen", f"tcp/{namespace.near}:0", "--connect", self.shared]
        self.procs: dict[str, Proc] = {}
        self.starts: Counter = Counter()
        self.camera_args: list[str] = []

    def shared_listening(self) -> bool:
        host, port = self.shared.removeprefix("tcp/").rsplit(":", 1)
        try:
            with socket.create_connection((host, int(port)), timeout=1.0):
                return True
        except OSError:
            return False

    def argv(self, name: str) -> list[str]:
        if name == "controller-master":   # it holds the shared endpoint, on the controllers' side
            args = ["--cell", CELL, "--listen", self.shared, "--connect", self.shared]
            return self._far(foldcell_argv("controller", "serve", "--role", "master", "--time-scale",
                                           str(TIME_SCALE), *args))
        if name == "controller-slave":
            return self._far(foldcell_argv("controller", "serve", "--role", "slave", "--time-scale",
                                           str(TIME_SCALE), *self.far))
        if name == "camera":
            return foldcell_argv("camera", "serve", *self.camera_args, *self.near)
        if name == "cell":
            return foldcell_argv("run", "--no-record", *self.near)
        if name == "recorder":
            return foldcell_argv("log", "record", "-o", str(self.logs / "session.mcap"), *self.near)
        raise ValueError(name)

    def _far(self, argv: list[str]) -> list[str]:
        return [*self.namespace.prefix(), *argv] if self.namespace else argv

    def start(self, name: str) -> None:
        self.starts[name] += 1
        self.procs[name] = Proc(self.argv(name), self.logs / f"{name}-{self.starts[name]}.log")

    def kill(self, name: str) -> None:
        self.procs[name].popen.send_signal(signal.SIGKILL)
        self.procs[name].popen.wait()

    def stop(self, name: str) -> None:
        if name in self.procs:
            self.procs[name].stop()

    def dead(self) -> list[str]:
        return [name for name, proc in self.procs.items() if proc.popen.poll() is not None]

    def rss_mb(self, name: str) -> float:
        status = Path(f"/proc/{self.procs[name].popen.pid}/status").read_text()
        line = next(text for text in status.splitlines() if text.startswith("VmRSS:"))
        return int(line.split()[1]) / 1024.0


class Operator:
    """The watcher's session: cell commands, the e-stop, and liveliness."""

    def __init__(self, cell: Cell):
        near = "127.0.0.1" if cell.namespace is None else cell.namespace.near
        self.wire = Wire(load_wire_settings().overridden(
            cell_id=CELL, listen=[f"tcp/{near}:0"], connect=[cell.shared]), "cli-chaos")
        self.states = Observer(self.wire)

    def command(self, what: str, argument: str = "") -> Any:
        request = messages.new("foldcell_msgs/msg/CellCommand", command=what, argument=argument,
                               client="chaos")
        try:
            return self.wire.request("cell/command", request, timeout=10)
        except Exception:   # the cell is gone or busy: the caller retries or counts it
            return None

    def alive(self) -> set[str]:
        return {key.rsplit("/", 1)[1] for key in self.wire.alive()}

    def estop(self) -> None:
        estop = codec.command_msg(Command.ESTOP, "alive/cli-chaos")
        self.wire.request("controller/command", estop, timeout=10)

    def flood(self) -> None:
        """Malformed and unauthorised requests, as fast as they go, at the controller and the cell."""
        rng = random.Random(SEED)
        for n in range(FLOOD_REQUESTS):
            spec = spec_for(("controller/command", "cell/command", "controller/trajectory")[n % 3])
            with contextlib.suppress(Exception):   # every one should be refused; a refusal is the point
                self.wire.request_raw(self.wire.key(spec.pattern), rng.randbytes(rng.randrange(0, 400)),
                                      spec.type_name, spec.reply_type, timeout=0.5)

    def close(self) -> None:
        self.wire.close()


REQUIRED = ("controller-master", "controller-slave", "camera", "cell")


def soak(logs: Path, namespace: NetNamespace | None) -> tuple[Soak, dict[str, tuple[float, float]], int]:
    rng = random.Random(SEED)
    kinds = [k for k in KINDS if k != "partition" or namespace is not None]
    cell = Cell(logs, namespace)
    result = Soak()
    memory: dict[str, tuple[float, float]] = {}
    operator = None
    try:
        cell.start("controller-master")
        if not wait_until(cell.shared_listening, START_TIMEOUT_S):
            raise RuntimeError(f"the master does not serve {cell.shared}")
        for name in ("controller-slave", "recorder"):
            cell.start(name)
        operator = Operator(cell)
        cell.camera_args = ["--garment", "towel", "--seed", "1", "--folding", "geometric"]
        cell.start("camera")
        cell.start("cell")
        if not wait_until(lambda: set(REQUIRED) <= operator.alive(), START_TIMEOUT_S):
            raise RuntimeError(f"the cell did not start: {sorted(set(REQUIRED) - operator.alive())}")
        first_rss = {name: cell.rss_mb(name) for name in ("recorder",)}
        started = time.monotonic()
        garment = 0
        while time.monotonic() - started < SOAK_S:
            category = CATEGORIES[garment % len(CATEGORIES)]
            garment += 1
            for name in cell.dead():   # every process killed on purpose was restarted by the recovery
                result.unasked_deaths.append(name)
                cell.start(name)
            cell.stop("camera")
            cell.camera_args = ["--garment", category, "--seed", str(rng.randrange(1000)), "--folding",
                                "geometric"]
            cell.start("camera")
            wait_until(lambda: "camera" in operator.alive(), START_TIMEOUT_S)
            kind = rng.choice(kinds)
            outcome = fold_with_fault(cell, operator, category, kind, rng.uniform(0.5, 12.0), result)
            result.garments[outcome] += 1
            print(f"  garment {garment} {category}: {kind} -> {outcome}", flush=True)
        for name, rss in first_rss.items():
            memory[name] = (rss, cell.rss_mb(name))
        lost = lost_samples(cell, operator)
        return result, memory, lost
    finally:
        if operator is not None:
            operator.close()
        for name in ("cell", "camera", "recorder", "controller-slave", "controller-master"):
            cell.stop(name)


def fold_with_fault(cell: Cell, operator: Operator, category: str, kind: str, delay: float,
                    result: Soak) -> str:
    """One garment: fold, the fault `delay` s into it, the operator's recovery; the garment's outcome."""
    reply = operator.command("fold", category)
    if reply is None or not reply.accepted:
        return "rejected"
    begun = time.monotonic()
    if kind == "none":
        return finish(operator, begun)
    ended = operator.states.first(TERMINAL, begun, delay)
    if ended is not None:   # it finished before the fault was due
        return ended[1].state
    fault = Injected(kind)
    result.injected.append(fault)
    injected = time.monotonic()
    if kind == "e-stop":
        operator.estop()
    elif kind.startswith("kill "):
        name = {"master": "controller-master", "slave": "controller-slave"}.get(kind[5:], kind[5:])
        cell.kill(name)
    elif kind == "flood":
        operator.flood()
    elif kind == "partition":
        assert cell.namespace is not None
        cell.namespace.cut()
    safe = operator.states.first(SAFE, injected, 30)
    if safe is not None:
        fault.safe_s, fault.reason = safe[0] - injected, safe[1].reason
    outcome = recover(cell, operator, kind, injected)
    fault.outcome = outcome
    if outcome in ("done", "recovered"):
        fault.recovered_s = time.monotonic() - injected
    return outcome


def recover(cell: Cell, operator: Operator, kind: str, injected: float) -> str:
    """The README's recovery steps for `kind`; the garment's outcome ("recovered": the cell is folding-
    ready again, the garment given up)."""
    if kind == "flood":
        return finish(operator, injected)
    if kind == "partition":
        time.sleep(random.Random(injected).uniform(*PARTITION_S))
        assert cell.namespace is not None
        cell.namespace.heal()
    for name in cell.dead():
        if name in REQUIRED:
            cell.start(name)
    if not wait_until(lambda: set(REQUIRED) <= operator.alive(), START_TIMEOUT_S):
        return "unrecovered"
    if kind == "e-stop":
        operator.states.first(SAFE, injected, 30)
        for step in ("reset", "resume"):
            if not wait_until(lambda s=step: (r := operator.command(s)) is not None and r.accepted, 30):
                return "unrecovered"
        return finish(operator, injected)
    # a lost process or link: the garment is given up, the cell reset to fold the next one
    operator.command("abort")

    def idle_after_reset() -> bool:
        reply = operator.command("reset")
        return (reply is not None and reply.accepted) or operator.states.last() == "idle"

    back = wait_until(idle_after_reset, 60, 1.0) and wait_until(lambda: operator.states.last() == "idle", 30)
    return "recovered" if back else "unrecovered"


def finish(operator: Operator, since: float) -> str:
    ended = operator.states.first(TERMINAL, since, GARMENT_TIMEOUT_S)
    if ended is None:
        operator.command("abort")
        operator.command("reset")
        return "timeout"
    if ended[1].state != "done":
        operator.command("abort")
        operator.command("reset")
    return ended[1].state


def lost_samples(cell: Cell, operator: Operator) -> int:
    """Gaps in the sequence numbers of each reliable key in the independent recording (a publisher that
    restarts starts again at 1, which is no gap)."""
    cell.stop("recorder")
    gaps = 0
    last: dict[str, int] = defaultdict(int)
    with open(cell.logs / "session.mcap", "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            key = channel.topic.split(f"/{CELL}/", 1)[-1]
            if key not in RELIABLE:
                continue
            previous = last[channel.topic]
            if message.sequence > previous + 1 and previous:
                gaps += message.sequence - previous - 1
            last[channel.topic] = message.sequence
    return gaps


def report(result: Soak, memory: dict[str, tuple[float, float]], lost: int) -> None:
    folded = result.garments["done"]
    print(f"chaos soak {SOAK_S:g} s (seed {SEED}): garments {sum(result.garments.values())}, "
          f"outcomes {dict(result.garments)}")
    by_kind: dict[str, list[Injected]] = defaultdict(list)
    for fault in result.injected:
        by_kind[fault.kind].append(fault)
    print(f"  {'fault':<13} {'n':>3} {'safe state s (median/max)':>26} "
          f"{'folding again s (median)':>25}  reason")
    for kind, faults in sorted(by_kind.items()):
        safe = [f.safe_s for f in faults if f.safe_s is not None]
        back = [f.recovered_s for f in faults if f.recovered_s is not None]
        reasons = Counter(f.reason.split(":")[0][:50] for f in faults if f.reason)
        safe_text = f"{statistics.median(safe):.3f}/{max(safe):.3f}" if safe else "-"
        back_text = f"{statistics.median(back):.1f}" if back else "-"
        print(f"  {kind:<13} {len(faults):>3} {safe_text:>26} {back_text:>25}  "
              f"{reasons.most_common(1)[0][0] if reasons else ''}")
    recovered = sum(1 for f in result.injected if f.recovered_s is not None)
    print(f"  faults {len(result.injected)}, recovered {recovered}; reliable samples lost {lost}; "
          f"processes that died unasked {result.unasked_deaths or 'none'}")
    for name, (before, after) in memory.items():
        print(f"  {name} memory {before:.0f} -> {after:.0f} MB")
    check("chaos", "garments folded", folded, ">", 0)
    if result.injected:
        check("chaos", "share of faults recovered", recovered / len(result.injected), ">=", RECOVERY_TARGET)
    check("chaos", "processes that died unasked", len(result.unasked_deaths), "<=", 0)
    check("chaos", "reliable samples lost", lost, "<=", 0)
    for name, (before, after) in memory.items():
        check("chaos", f"{name} memory growth", after - before, "<=", MEMORY_GROWTH_TARGET_MB, "MB")


def main() -> None:
    why = NetNamespace.unavailable()
    if why:
        print(f"partitions left out ({why})")
    with TemporaryDirectory() as tmp:
        logs = Path(os.environ.get("FOLDCELL_BENCH_LOGS", "") or tmp) / "chaos"
        logs.mkdir(parents=True, exist_ok=True)
        if why:
            result, memory, lost = soak(logs, None)
        else:
            with NetNamespace() as namespace:
                result, memory, lost = soak(logs, namespace)
    report(result, memory, lost)


if __name__ == "__main__":
    main()
