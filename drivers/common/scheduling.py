"""How the processes of a cell share two cores: priorities (`priorities:` in config/cell.yaml) and the
scheduling delay of the threads on the safety path, measured where they run.

Linux sets niceness per thread, and a thread inherits its creator's: a process that lowers its nice
before Zenoh starts its threads has them all at that nice, and a worker thread that raises its own
leaves the rest of its process where it was. A nice below 0 needs CAP_SYS_NICE; without it the
thread stays at 0 and says so once (the order holds: perception and the simulation go above 0).

`Lateness` is a histogram of how late a periodic thread woke (or how long a peer was silent), cheap
enough to record at 250 Hz. With `FOLDCELL_TIMING_DIR` set, a process writes its histograms and the
kernel's scheduling counters of every thread (/proc/self/task/*/schedstat) to
`<dir>/<process>-<pid>.json` when it ends: `make bench` reads them (tests/bench/bench_budget.py).
"""

from __future__ import annotations

import atexit
import json
import logging
import math
import os
import threading
from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import config_dir, load_yaml_over

log = logging.getLogger(__name__)

ENV_TIMING_DIR = "FOLDCELL_TIMING_DIR"
PRIORITY_ROLES = ("controller", "router", "cell", "perception", "camera", "simulation")
FIFO_MAX = 99
# histogram bins: 20 per decade from 10 µs to 100 s (a percentile is read within 12 %)
_BINS_PER_DECADE = 20
_LOWEST_S = 1e-5
_BIN_COUNT = 7 * _BINS_PER_DECADE


@dataclass(frozen=True)
class Priorities:
    """Nice values per role (lower runs first)."""

    controller: int = -10
    router: int = -10
    cell: int = 0
    perception: int = 5
    camera: int = 0
    simulation: int = 10
    controller_loop_fifo: int = 0   # SCHED_FIFO priority of a controller's loop thread (0: none)

    def of(self, role: str) -> int:
        if role not in PRIORITY_ROLES:
            raise ValueError(f"priority role must be one of {', '.join(PRIORITY_ROLES)}, got {role!r}")
        return int(getattr(self, role))


def load_priorities(path: str | Path | None = None) -> Priorities:
    f = load_yaml_over(path, config_dir() / "cell.yaml").sub("priorities")
    f.reject_unknown({*PRIORITY_ROLES, "controller_loop_fifo"})
    return Priorities(**{role: f.int(role, min=-20, max=19) for role in PRIORITY_ROLES},
                      controller_loop_fifo=f.int("controller_loop_fifo", min=0, max=FIFO_MAX))


def set_thread_nice(nice: int, what: str) -> int:
    """Run the calling thread (and the threads it starts from now on) at `nice`; returns the nice it
    got. `what` names the thread in the one log line said when the OS refuses."""
    tid = threading.get_native_id()
    try:
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except PermissionError:   # lowering the nice needs CAP_SYS_NICE: the thread keeps its own
        log.info("%s runs at nice %d, not %d: a nice below the current one needs CAP_SYS_NICE "
                 "(root); perception and the simulation still run below it", what,
                 os.getpriority(os.PRIO_PROCESS, tid), nice)
    except (AttributeError, OSError) as exc:   # not Linux
        log.debug("%s keeps its priority: %s", what, exc)
    try:
        return os.getpriority(os.PRIO_PROCESS, tid)
    except (AttributeError, OSError):
        return 0


def set_thread_fifo(priority: int, what: str) -> bool:
    """Run the calling thread SCHED_FIFO at `priority` (threads it starts later go back to the normal
    policy); False, and one log line, where the OS does not allow it. `priority` 0: nothing asked."""
    if priority <= 0:
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO | os.SCHED_RESET_ON_FORK, os.sched_param(priority))
    except PermissionError:
        log.info("%s runs without SCHED_FIFO: it needs CAP_SYS_NICE (root) or an RLIMIT_RTPRIO; its nice "
                 "still puts it above perception and the simulation", what)
        return False
    except (AttributeError, OSError) as exc:   # not Linux
        log.debug("%s keeps its scheduling policy: %s", what, exc)
        return False
    return True


class Lateness:
    """Histogram of delays (s): how late a periodic thread woke, or how long a peer was silent."""

    def __init__(self, name: str, what: str = "wake-up delay"):
        self.name = name
        self.what = what
        self.counts = [0] * (_BIN_COUNT + 1)   # the last bin: at or above its lower edge
        self.total = 0
        self.max = 0.0
        self.lock = threading.Lock()

    def record(self, seconds: float) -> None:
        seconds = max(0.0, float(seconds))
        if seconds < _LOWEST_S:
            index = 0
        else:
            index = min(_BIN_COUNT, 1 + int(math.log10(seconds / _LOWEST_S) * _BINS_PER_DECADE))
        with self.lock:
            self.counts[index] += 1
            self.total += 1
            if seconds > self.max:
                self.max = seconds

    def percentile(self, q: float) -> float:
        """The upper edge of the bin holding the q-th percentile (s); 0 with no samples."""
        with self.lock:
            counts, total, top = list(self.counts), self.total, self.max
        if total == 0:
            return 0.0
        rank = q / 100.0 * total
        seen = 0
        for index, count in enumerate(counts):
            seen += count
            if seen >= rank and count:
                return min(top, upper_edge(index))
        return top

    def summary(self) -> dict:
        return {"name": self.name, "what": self.what, "samples": self.total,
                "p50_s": self.percentile(50), "p99_s": self.percentile(99), "p999_s": self.percentile(99.9),
                "max_s": self.max, "counts": list(self.counts)}


def upper_edge(index: int) -> float:
    """The upper edge (s) of histogram bin `index`."""
    return _LOWEST_S * 10 ** (index / _BINS_PER_DECADE)


def merge(summaries: list[dict]) -> dict:
    """Several `Lateness.summary()`s of one kind as one (percentiles from the merged counts)."""
    merged = Lateness(summaries[0]["name"] if summaries else "", summaries[0]["what"] if summaries else "")
    for s in summaries:
        for index, count in enumerate(s["counts"]):
            merged.counts[index] += count
        merged.total += s["samples"]
        merged.max = max(merged.max, s["max_s"])
    return merged.summary()


class TimingReport:
    """This process's histograms, written on exit when FOLDCELL_TIMING_DIR is set."""

    def __init__(self) -> None:
        self.process = ""
        self.histograms: dict[str, Lateness] = {}
        self.lock = threading.Lock()
        self.registered = False

    def histogram(self, name: str, what: str = "wake-up delay") -> Lateness:
        with self.lock:
            if name not in self.histograms:
                self.histograms[name] = Lateness(name, what)
            self._register()
            return self.histograms[name]

    def _register(self) -> None:
        if not self.registered and os.environ.get(ENV_TIMING_DIR):
            atexit.register(self.write)
            self.registered = True

    def write(self) -> Path | None:
        folder = os.environ.get(ENV_TIMING_DIR)
        if not folder:
            return None
        path = Path(folder) / f"{self.process or 'process'}-{os.getpid()}.json"
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with self.lock:
                histograms = {name: h.summary() for name, h in self.histograms.items()}
            path.write_text(json.dumps({"process": self.process, "pid": os.getpid(),
                                        "histograms": histograms, "threads": thread_schedstats()}))
        except OSError as exc:
            log.warning("timing report not written to %s: %s", path, exc)
            return None
        return path


def thread_schedstats() -> list[dict]:
    """Per thread of this process: name (Python's, else the kernel's), nice, CPU time, time spent
    waiting for a CPU while runnable and the number of times it ran (/proc/<pid>/task/<tid>/schedstat)."""
    out: list[dict] = []
    task_dir = Path("/proc/self/task")
    if not task_dir.is_dir():
        return out
    python_names = {t.native_id: t.name for t in threading.enumerate()}
    for task in task_dir.iterdir():
        try:
            run_ns, wait_ns, slices = (int(v) for v in (task / "schedstat").read_text().split()[:3])
            stat = (task / "stat").read_text()
            name = stat[stat.index("(") + 1:stat.rindex(")")]
            nice = int(stat[stat.rindex(")") + 2:].split()[16])
        except (OSError, ValueError, IndexError):
            continue
        name = python_names.get(int(task.name), name)   # Zenoh's threads name themselves (rx-0...)
        out.append({"tid": int(task.name), "name": name, "nice": nice, "cpu_s": run_ns * 1e-9,
                    "wait_s": wait_ns * 1e-9, "slices": slices})
    return out


REPORT = TimingReport()


def histogram(name: str, what: str = "wake-up delay") -> Lateness:
    """This process's histogram `name` (made on first use)."""
    return REPORT.histogram(name, what)


def name_process(process: str) -> None:
    """The name this process's timing report is written under (and it is written, when asked for)."""
    REPORT.process = process
    with REPORT.lock:
        REPORT._register()
