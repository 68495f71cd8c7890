"""How soon a lost process is noticed: the cell faulting when the controller dies mid-fold (the design's
0.5 s), both sides of a partition between the cell and its controller (the cell faulting, the
controller dropping the lease and stopping: 0.5 s; skipped where network namespaces cannot be made),
and the monitor showing a dead cell as gone (the README's second). The tests check that it happens;
these are the figures.

    .venv/bin/python -m tests.bench faults
"""

from __future__ import annotations

import os
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path
from tempfile import TemporaryDirectory

from drivers.sessions.monitor.live import MonitorSession
from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.bench.targets import check
from tests.cell.cell_states import CellStates
from tests.cell.partition_run import run_partition
from tests.conftest import REPO, Endpoint, foldcell_argv, wait_until
from tests.netns import NetNamespace

RUNS = 3
CELL_FAULT_TARGET_S = 0.5
MONITOR_GONE_TARGET_S = 1.0
PARTITION_TARGET_S = 0.5


def cell_fault_after_controller_kill(tmp: Path) -> float:
    ep = Endpoint("faults")
    procs = [
        subprocess.Popen(foldcell_argv(*args, *ep.args()), cwd=REPO, stdout=subprocess.DEVNULL,
                         stderr=subprocess.DEVNULL)
        for args in (("controller", "serve", "--role", "both", "--time-scale", "5"),
                     ("camera", "serve", "--garment", "towel", "--seed", "2"),
                     ("run", "--record", str(tmp / "s.mcap")))
    ]
    try:
        with Wire(ep.settings(), "bench") as wire:
            states = CellStates(wire)
            names = lambda: {k.rsplit("/", 1)[1] for k in wire.alive()}  # noqa: E731
            if not wait_until(lambda: {"controller", "camera", "cell"} <= names(), 60):
                raise RuntimeError("the cell's processes did not start")
            wire.request("cell/command", messages.new("foldcell_msgs/msg/CellCommand", command="fold",
                                                      argument="towel", client="bench"), timeout=10)
            if states.first({"folding"}, 0.0, 120) is None:
                raise RuntimeError("the cell never started folding")
            killed = time.monotonic()
            os.kill(procs[0].pid, signal.SIGKILL)
            fault = states.first({"fault"}, killed, 30)
            if fault is None:
                raise RuntimeError("the cell did not fault")
            return fault[0] - killed
    finally:
        for proc in reversed(procs):
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
                try:
                    proc.wait(15)
                except subprocess.TimeoutExpired:
                    proc.kill()


def monitor_gone_after_kill() -> float:
    ep = Endpoint()
    with MonitorSession(ep.settings("watcher"), "*", "monitor-bench") as mon:
        node = subprocess.Popen(
            [sys.executable, "-m", "tests.nodes.fake_cell", *ep.args("doomed"), "--forever"],
            cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            cell = lambda: mon.snapshot()["cells"].get("doomed", {})  # noqa: E731
            if not wait_until(lambda: bool(cell().get("alive")), 30):
                raise RuntimeError("the monitor never saw the cell")
            killed = time.monotonic()
            node.kill()
            if not wait_until(lambda: bool(cell().get("gone")), 30, 0.005):
                raise RuntimeError("the monitor never showed the cell as gone")
            return time.monotonic() - killed
        finally:
            node.kill()
            node.wait()


def main() -> None:
    with TemporaryDirectory() as tmp:
        faults = [cell_fault_after_controller_kill(Path(tmp)) for _ in range(RUNS)]
    print(f"cell fault after the controller is killed mid-fold: {', '.join(f'{s:.3f}' for s in faults)} s")
    check("faults", "cell fault after a controller kill, worst of runs", max(faults), "<=",
          CELL_FAULT_TARGET_S, "s")
    why = NetNamespace.unavailable()
    if why:
        print(f"partition: skipped ({why})")
    else:
        runs = []
        kept_logs = os.environ.get("FOLDCELL_BENCH_LOGS")
        logs_root = Path(kept_logs) if kept_logs else None
        with TemporaryDirectory() as tmp:
            for run in range(RUNS):
                logs = (logs_root or Path(tmp)) / f"partition-{run}"
                logs.mkdir(parents=True, exist_ok=True)
                with NetNamespace() as ns:
                    runs.append(run_partition(ns, logs, recover=False))
        print("partition mid-fold: cell fault after "
              f"{', '.join(f'{r.cell_fault_s:.3f}' for r in runs)} s ({runs[0].fault_reason}); controller "
              f"stopped after {', '.join(f'{r.controller_stop_s:.3f}' for r in runs)} s")
        check("faults", "cell fault after a partition, worst of runs",
              max(r.cell_fault_s for r in runs), "<=", PARTITION_TARGET_S, "s")
        check("faults", "controller stop after a partition, worst of runs",
              max(r.controller_stop_s for r in runs), "<=", PARTITION_TARGET_S, "s")
    gone = [monitor_gone_after_kill() for _ in range(RUNS)]
    print(f"monitor shows a killed cell as gone after: {', '.join(f'{s:.3f}' for s in gone)} s "
          f"(median {statistics.median(gone):.3f})")
    check("faults", "monitor gone after a kill, worst of runs", max(gone), "<=", MONITOR_GONE_TARGET_S, "s")


if __name__ == "__main__":
    main()
