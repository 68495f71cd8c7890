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
from collections import Counter, defaultdict, deque
from dataclasses import dataclass, field
from pathlib import Path
from tempfile import TemporaryDirectory
from typing import Any

from mcap.reader import make_reader

from drivers.common.garments import CATEGORIES
from drivers.controller import codec
from drivers.controller.codes import Command
from drivers.sessions.mcap.bag import find_session
from drivers.wire import messages
from drivers.wire.registry import spec_for
from drivers.wire.settings import load_wire_settings
from drivers.wire.transport import Wire
from tests.bench.targets import check
from tests.cell.cell_states import CellStates
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
CUE_DELAY_S = 0.5            # after `folding` is seen: the arms are on their way with the cloth
RECOVERY_TARGET = 1.0        # share of faults after which the cell folds again
MEMORY_GROWTH_TARGET_MB = 100.0


@dataclass
class Injected:
    kind: str
    safe_s: float | None = None      # to the cell's paused/fault state, seen by an observer
    still_s: float | None = None     # to the robot at rest (the slave's stream when the master died)
    reason: str = ""
    recovered_s: float | None = None  # to the garment finished after the recovery, or given up and the
    #                                   cell idle (None: neither)
    outcome: str = ""


@dataclass
class Soak:
    garments: Counter = field(default_factory=Counter)   # outcome -> count
    injected: list[Injected] = field(default_factory=list)
    unasked_deaths: list[str] = field(default_factory=list)


class Motion:
    """Arrival time and largest joint speed of every joint state, the master's and the slave's."""

    HOLD_S = 0.3   # still this long counts as at rest

    def __init__(self, wire: Wire):
        self.lock = threading.Lock()
        self.samples: deque[tuple[float, float]] = deque(maxlen=50_000)
        for key in ("controller/joint_states", "controller/slave/joint_states"):
            wire.subscribe(key, self._on)

    def _on(self, _key: str, msg: Any, _raw: Any) -> None:
        speed = max((abs(v) for v in msg.velocity), default=0.0)
        with self.lock:
            self.samples.append((time.monotonic(), speed))

    def still_after(self, since: float, timeout: float = 15.0) -> float | None:
        """Seconds from `since` to the first joint state from which every joint stays at rest."""
        def first_still() -> float | None:
            with self.lock:
                after = [(t, v) for t, v in self.samples if t >= since]
            for i, (t, v) in enumerate(after):
                window = [w for u, w in after[i:] if u <= t + self.HOLD_S]
                if v == 0.0 and after[-1][0] >= t + self.HOLD_S and not any(window):
                    return t - since
            return None

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = first_still()
            if found is not None:
                return found
            time.sleep(0.05)
        return None


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
            return foldcell_argv("run", "--no-record", "--job", str(self.logs / "cell.job.json"), *self.near)
        if name == "recorder":
            return foldcell_argv("log", "record", "-v", "-o", str(self.logs / "session"), *self.near)
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
        self.states = CellStates(self.wire)
        self.motion = Motion(self.wire)

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


Memory = dict[str, tuple[float, float]]   # process -> RSS MB at the start and the end


def soak(logs: Path, namespace: NetNamespace | None) -> tuple[Soak, Soak, Memory, int]:
    """Each fault once on cue (the fault table), then random faults at random times until `SOAK_S` has
    passed since the start; (table, soak, memory before/after, reliable samples lost)."""
    rng = random.Random(SEED)
    kinds = [k for k in KINDS if k != "partition" or namespace is not None]
    cell = Cell(logs, namespace)
    table, chaos = Soak(), Soak()
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
        schedule = [(kind, None, table) for kind in kinds if kind != "none"]
        garment = 0
        while schedule or time.monotonic() - started < SOAK_S:
            kind, delay, into = (schedule.pop(0) if schedule
                                 else (rng.choice(kinds), rng.uniform(0.5, 12.0), chaos))
            category = CATEGORIES[garment % len(CATEGORIES)]
            garment += 1
            for name in cell.dead():   # every process killed on purpose was restarted by the recovery
                into.unasked_deaths.append(name)
                cell.start(name)
            cell.stop("camera")
            cell.camera_args = ["--garment", category, "--seed", str(rng.randrange(1000)), "--folding",
                                "geometric"]
            cell.start("camera")
            wait_until(lambda: "camera" in operator.alive(), START_TIMEOUT_S)
            outcome = fold_with_fault(cell, operator, category, kind, delay, into)
            into.garments[outcome] += 1
            when = "on cue" if delay is None else f"at {delay:.1f} s"
            print(f"  garment {garment} {category}: {kind} {when} -> {outcome}", flush=True)
        memory = {name: (rss, cell.rss_mb(name)) for name, rss in first_rss.items()}
        return table, chaos, memory, lost_samples(cell)
    finally:
        if operator is not None:
            operator.close()
        for name in ("cell", "camera", "recorder", "controller-slave", "controller-master"):
            cell.stop(name)


def fold_with_fault(cell: Cell, operator: Operator, category: str, kind: str, delay: float | None,
                    result: Soak) -> str:
    """One garment: fold, the fault `delay` s into it (None: once the arms carry the cloth, the cell
    `folding`), the operator's recovery; the garment's outcome."""
    reply = operator.command("fold", category)
    if reply is None or not reply.accepted:
        print(f"  fold refused: {reply.text if reply is not None else 'no answer'} "
              f"(cell {operator.states.last()})", flush=True)
        return "rejected"
    begun = time.monotonic()
    if kind == "none":
        return finish(operator, begun)
    if delay is None:
        cue = operator.states.first(TERMINAL | {"folding"}, begun, GARMENT_TIMEOUT_S)
        if cue is None or cue[1].state != "folding":
            return cue[1].state if cue else "timeout"
        time.sleep(CUE_DELAY_S)
    else:
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
    # a killed cell says nothing until it is started again (in the recovery)
    safe = None if kind == "kill cell" else operator.states.first(SAFE, injected, 30)
    if safe is not None:
        fault.safe_s, fault.reason = safe[0] - injected, safe[1].reason
    if kind != "flood":   # a flood must not stop the robot at all
        fault.still_s = operator.motion.still_after(injected)
    outcome = recover(cell, operator, kind, injected)
    fault.outcome = outcome
    if outcome in ("done", "failed", "recovered"):   # the cell back to work (a garment may still fail)
        fault.recovered_s = time.monotonic() - injected
    return outcome


def recover(cell: Cell, operator: Operator, kind: str, injected: float) -> str:
    """The README's recovery steps for `kind`; the garment's outcome. A lost process is started again
    and the cell resumes the garment (a restarted cell comes up paused with its job, so reset first);
    only when resume is refused is the garment given up ("recovered": the cell idle, ready to fold)."""
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
    if operator.states.first(SAFE, injected, 30) is None:   # a restarted cell's first state: paused
        return "unrecovered"
    steps = ("reset", "resume") if kind in ("e-stop", "kill cell") else ("resume",)
    for step in steps:
        if not wait_until(lambda s=step: (r := operator.command(s)) is not None and r.accepted, 60, 1.0):
            return give_up(operator)
    return finish(operator, time.monotonic())   # the fault itself is not the garment's end


def give_up(operator: Operator) -> str:
    """The garment abandoned: abort, reset, until the cell is idle."""
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


def lost_samples(cell: Cell) -> int:
    """Gaps in the sequence numbers of each reliable key in the independent recording (a publisher that
    restarts starts again at 1, which is no gap)."""
    cell.stop("recorder")
    gaps = 0
    last: dict[str, int] = defaultdict(int)
    for path in find_session(cell.logs / "session").files:   # the bag's split files, in order
        with open(path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
                key = channel.topic.split(f"/{CELL}/", 1)[-1]
                if key not in RELIABLE:
                    continue
                previous = last[channel.topic]
                if message.sequence > previous + 1 and previous:
                    gaps += message.sequence - previous - 1
                last[channel.topic] = message.sequence
    return gaps


def print_faults(result: Soak) -> None:
    by_kind: dict[str, list[Injected]] = defaultdict(list)
    for fault in result.injected:
        by_kind[fault.kind].append(fault)
    print(f"  {'fault':<12} {'n':>3} {'cell safe s':>12} {'robot still s':>14} {'recovered s':>16}  "
          "reason (cell)")

    def span(values: list[float], digits: int) -> str:
        if not values:
            return "-"
        if len(values) == 1:
            return f"{values[0]:.{digits}f}"
        return f"{statistics.median(values):.{digits}f}/{max(values):.{digits}f}"

    for kind, faults in sorted(by_kind.items()):
        reasons = Counter(f.reason.split(":")[0][:48] for f in faults if f.reason)
        safe = span([f.safe_s for f in faults if f.safe_s is not None], 3)
        still = span([f.still_s for f in faults if f.still_s is not None], 3)
        back = span([f.recovered_s for f in faults if f.recovered_s is not None], 1)
        print(f"  {kind:<12} {len(faults):>3} {safe:>12} {still:>14} {back:>16}  "
              f"{reasons.most_common(1)[0][0] if reasons else '-'}")


def report(table: Soak, chaos: Soak, memory: Memory, lost: int) -> None:
    print("fault table: each fault once, 0.5 s after the cell reports folding (several: median/max); "
          "recovered: from the fault to the garment finished after the README's steps")
    print_faults(table)
    print(f"chaos soak {SOAK_S:g} s (seed {SEED}): garments {sum(chaos.garments.values())}, "
          f"outcomes {dict(chaos.garments)}")
    print_faults(chaos)
    injected = table.injected + chaos.injected
    recovered = sum(1 for f in injected if f.recovered_s is not None)
    unasked = table.unasked_deaths + chaos.unasked_deaths
    print(f"  faults {len(injected)}, recovered {recovered}; reliable samples lost {lost}; "
          f"processes that died unasked {unasked or 'none'}")
    for name, (before, after) in memory.items():
        print(f"  {name} memory {before:.0f} -> {after:.0f} MB")
    check("chaos", "garments folded", table.garments["done"] + chaos.garments["done"], ">", 0)
    if injected:
        check("chaos", "share of faults recovered", recovered / len(injected), ">=", RECOVERY_TARGET)
    check("chaos", "processes that died unasked", len(unasked), "<=", 0)
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
            figures = soak(logs, None)
        else:
            with NetNamespace() as namespace:
                figures = soak(logs, namespace)
    report(*figures)


if __name__ == "__main__":
    main()
