"""Issue 25's figures: the CPU a cell costs, and the scheduling delays of its safety path.

1. CPU budget (per process, from /proc/<pid>/stat: all its threads): a hand-started cell (controller
   master and slave streaming at 250 Hz, the simulated camera, the cell daemon recording its session) at
   rest, then while it folds a towel. Targets (of one core): the whole idle cell <= 0.25, each arm
   controller <= 0.08, an idle camera <= 0.02.
2. Scheduling delays, measured inside the processes (drivers/common/scheduling.py) during
   `foldcell demo --garment all`, alone and beside two busy loops (`python3 -c 'while True: pass'` x 2):
   how late the controllers' 250 Hz loops woke, how late the cell's lease renewals went out, the gaps
   the master saw in the lease holder's requests, and the kernel's run-queue wait of Zenoh's own
   threads (the links' keep-alives). Targets: the lease holder's longest silence
   leaves the controller's silence timeout a margin of 2; no lease or link lost; every garment done.

    .venv/bin/python -m tests.bench.bench_budget [--idle-s 20] [--skip-demo]
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from drivers.common.scheduling import ENV_TIMING_DIR, merge
from drivers.controller.config import default_controller_config
from drivers.wire import messages
from drivers.wire.transport import Wire, process_of
from tests.bench.targets import check
from tests.conftest import REPO, Endpoint, wait_until

BENCH = "bench_budget"
CELL_PROCESSES = ("controller-master", "controller-slave", "camera", "cell")
TARGET_WHOLE = 0.25
TARGET_ARM = 0.08
TARGET_CAMERA = 0.02
SILENCE_MARGIN = 2.0
SETTLE_S = 15.0
HOG = "while True: pass"
TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float:
    """User + system CPU (s) of a process, all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


class HandStartedCell:
    """The cell's processes as an operator starts them, each on its own, on a private endpoint."""

    def __init__(self, folder: Path):
        self.endpoint = Endpoint("budget")
        wire = self.endpoint.args()
        argv = {
            "controller-master": ["controller", "serve", "--role", "master", "--time-scale", "10"],
            "controller-slave": ["controller", "serve", "--role", "slave", "--time-scale", "10"],
            "camera": ["camera", "serve", "--source", "sim", "--garment", "towel", "--seed", "3"],
            "cell": ["run", "--record", str(folder / "session")],
        }
        self.procs: dict[str, subprocess.Popen] = {}
        for name, args in argv.items():
            with open(folder / f"{name}.log", "wb") as log:
                self.procs[name] = subprocess.Popen([sys.executable, "-m", "tools.cli", *args, *wire],
                                                    stdout=log, stderr=log, cwd=REPO)
        self.wire = Wire(self.endpoint.settings(), "bench-budget")

    def wait_alive(self) -> None:
        alive = lambda: {process_of(k) for k in self.wire.alive()}  # noqa: E731
        if not wait_until(lambda: set(CELL_PROCESSES) <= alive(), 90):
            raise RuntimeError(f"the cell did not start: {sorted(set(CELL_PROCESSES) - alive())} missing")

    def cpu(self) -> dict[str, float]:
        return {name: cpu_seconds(p.pid) for name, p in self.procs.items()}

    def command(self, command: str, argument: str = "") -> object:
        return self.wire.request("cell/command", messages.new(
            "foldcell_msgs/msg/CellCommand", command=command, argument=argument, client="bench"), timeout=10)

    def wait_state(self, states: set[str], timeout: float) -> str:
        last = {"state": ""}

        def on_state(_k: str, msg: object, _r: object) -> None:
            last["state"] = msg.state  # type: ignore[attr-defined]

        self.wire.subscribe("cell/state", on_state)
        wait_until(lambda: last["state"] in states, timeout, 0.1)
        return last["state"]

    def close(self) -> None:
        self.wire.close()
        for proc in self.procs.values():
            proc.send_signal(2)
        for proc in self.procs.values():
            try:
                proc.wait(20)
            except subprocess.TimeoutExpired:
                proc.kill()


def cpu_share(cell: HandStartedCell, until: Callable[[], object]) -> tuple[dict, float]:
    """Per process, the share of one core used until `until()` returns, and how long that took."""
    before, started = cell.cpu(), time.monotonic()
    until()
    after, elapsed = cell.cpu(), time.monotonic() - started
    return {name: (after[name] - before[name]) / elapsed for name in before}, elapsed


def print_table(title: str, shares: dict[str, float], elapsed: float) -> None:
    print(f"{title} ({elapsed:.0f} s): " + ", ".join(f"{n} {v:.3f}" for n, v in shares.items())
          + f"; whole cell {sum(shares.values()):.3f} of one core", flush=True)


def budget(idle_s: float) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        cell = HandStartedCell(Path(tmp))
        try:
            cell.wait_alive()
            time.sleep(SETTLE_S)   # past start-up (first links, models loaded on first use)
            idle, elapsed = cpu_share(cell, lambda: time.sleep(idle_s))
            print_table("CPU, idle cell", idle, elapsed)
            check(BENCH, "whole idle cell", sum(idle.values()), "<=", TARGET_WHOLE, "cores")
            for arm in ("controller-master", "controller-slave"):
                check(BENCH, f"{arm} streaming at 250 Hz", idle[arm], "<=", TARGET_ARM, "cores")
            check(BENCH, "idle camera", idle["camera"], "<=", TARGET_CAMERA, "cores")
            reply = cell.command("fold", "towel")
            if not reply.accepted:  # type: ignore[attr-defined]
                raise RuntimeError(f"fold refused: {reply.text}")  # type: ignore[attr-defined]
            folding, elapsed = cpu_share(cell, lambda: cell.wait_state({"done", "failed", "fault"}, 300))
            print_table("CPU, folding a towel (the camera simulates the cloth)", folding, elapsed)
        finally:
            cell.close()


@contextlib.contextmanager
def hogs(count: int) -> Iterator[None]:
    procs = [subprocess.Popen([sys.executable, "-c", HOG]) for _ in range(count)]
    try:
        yield
    finally:
        for proc in procs:
            proc.kill()
            proc.wait()


def demo_delays(label: str, hog_count: int) -> dict:
    """One `foldcell demo --garment all` with FOLDCELL_TIMING_DIR set: its summary and its processes'
    timing reports."""
    with tempfile.TemporaryDirectory() as tmp, hogs(hog_count):
        timing = Path(tmp) / "timing"
        env = dict(os.environ, **{ENV_TIMING_DIR: str(timing)})
        argv = [sys.executable, "-m", "tools.cli", "demo", "--garment", "all", "--json", "-o",
                str(Path(tmp) / "demo")]
        run = subprocess.run(argv, cwd=REPO, env=env, capture_output=True, text=True)
        try:
            summary = json.loads(run.stdout)
        except json.JSONDecodeError:
            raise RuntimeError(f"{label}: the demo printed no summary: {run.stderr[-2000:]}") from None
        logs = "\n".join(p.read_text(errors="replace") for p in (Path(tmp) / "demo" / "logs").glob("*.log"))
        reports = [json.loads(p.read_text()) for p in timing.glob("*.json")]
    return {"summary": summary, "reports": reports, "logs": logs, "returncode": run.returncode}


def histograms(reports: list[dict], name_ends: str) -> dict | None:
    found = [h for r in reports for n, h in r["histograms"].items() if n.endswith(name_ends)]
    return merge(found) if found else None


def zenoh_wait(reports: list[dict]) -> tuple[float, float]:
    """Mean and worst per-process mean run-queue wait (ms) of Zenoh's transmit threads (keep-alives)."""
    means = [t["wait_s"] / t["slices"] * 1e3 for r in reports for t in r["threads"]
             if t["name"].startswith("tx-") and t["slices"]]
    return (sum(means) / len(means), max(means)) if means else (0.0, 0.0)


def print_delays(label: str, run: dict) -> None:
    print(f"scheduling delays, {label}:", flush=True)
    rows = [("controller tick", " tick", "how late the 250 Hz loops woke (master and slave)"),
            ("lease renewal", "lease renewal", "how late the cell's renewals went out"),
            ("lease holder silence", "lease holder silence", "the master's view of the holder")]
    for title, suffix, what in rows:
        h = histograms(run["reports"], suffix)
        if h is None or not h["samples"]:
            print(f"  {title:22} no samples", flush=True)
            continue
        print(f"  {title:22} p50 {h['p50_s'] * 1e3:7.2f} ms  p99 {h['p99_s'] * 1e3:7.2f} ms  "
              f"max {h['max_s'] * 1e3:7.1f} ms  ({h['samples']} samples; {what})", flush=True)
    mean, worst = zenoh_wait(run["reports"])
    print(f"  {'zenoh keep-alive':22} run-queue wait per wake-up: mean {mean:.2f} ms, worst process "
          f"{worst:.2f} ms (the kernel's schedstat of Zenoh's tx threads)", flush=True)


def check_run(label: str, run: dict) -> None:
    garments = run["summary"]["garments"]
    done = sum(g["outcome"] == "done" for g in garments)
    check(BENCH, f"garments done, {label}", done, ">=", 4, "of 4")
    lease_losses = run["logs"].count("lease dropped, stopping")
    check(BENCH, f"lease losses, {label}", lease_losses, "<=", 0, "")
    silence = histograms(run["reports"], "lease holder silence")
    if silence is not None and silence["samples"]:
        timeout = default_controller_config().lease_silence_timeout
        check(BENCH, f"longest lease holder silence x {SILENCE_MARGIN:g}, {label}",
              silence["max_s"] * SILENCE_MARGIN, "<=", timeout, "s")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="bench_budget")
    parser.add_argument("--idle-s", type=float, default=20.0, help="idle measurement (s)")
    parser.add_argument("--skip-demo", action="store_true", help="only the CPU budget")
    args = parser.parse_args(argv or [])
    budget(args.idle_s)
    if args.skip_demo:
        return
    for label, hog_count in (("demo alone", 0), ("demo beside two busy loops", 2)):
        run = demo_delays(label, hog_count)
        print_delays(label, run)
        check_run(label, run)


if __name__ == "__main__":
    main(sys.argv[1:])
