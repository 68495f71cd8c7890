"""Issue 25's soak: the README's first command, again and again, on this 2-core machine.

`foldcell demo --garment all` 10 times (seeds 1..10), then 10 times beside two busy loops
(`python3 -c 'while True: pass'` x 2), then `foldcell demo --camera wrist --garment all` 5 times: every
garment must end done, with no lease and no controller link lost while the garments were folded, and
no controller alarm at all (a loop stall is counted, never an alarm). Prints one line per run and the totals.

    .venv/bin/python -m tests.bench.bench_soak [--runs 10] [--hog-runs 10] [--wrist-runs 5]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from tests.bench.bench_budget import hogs
from tests.bench.targets import check
from tests.conftest import REPO

BENCH = "bench_soak"
LOG_LINE = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d),(\d{3}) (\w+) (\S+): (.*)$")
LEASE_LOST = "lease dropped, stopping"
LINK_LOST = ("slave link lost", "link to the master controller lost")
STALL = "the loop could not run for"
ALARM = re.compile(r"^alarm \d+: ")


@dataclass
class Tally:
    runs: int = 0
    garments: int = 0
    done: int = 0
    lease_losses: int = 0
    link_losses: int = 0
    stalls: int = 0
    alarms: int = 0
    failures: list[str] = field(default_factory=list)


def logged_before(logs: Path, stopped_at: dt.datetime) -> list[tuple[str, str]]:
    """(process, message) of every line the demo's processes logged before it stopped them."""
    lines = []
    for path in sorted(logs.glob("*.log")):
        for text in path.read_text(errors="replace").splitlines():
            m = LOG_LINE.match(text)
            if not m:
                continue
            when = dt.datetime.strptime(f"{m.group(1)}.{m.group(2)}", "%Y-%m-%d %H:%M:%S.%f")
            if when < stopped_at:
                lines.append((path.stem, m.group(5)))
    return lines


def run_demo(tally: Tally, label: str, seed: int, camera: str) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "demo"
        started = time.monotonic()
        argv = [sys.executable, "-m", "tools.cli", "demo", "--garment", "all", "--seed", str(seed),
                "--camera", camera, "--json", "-o", str(out)]
        run = subprocess.run(argv, cwd=REPO, capture_output=True, text=True)
        wall = time.monotonic() - started
        tally.runs += 1
        try:
            summary = json.loads(run.stdout)
        except json.JSONDecodeError:
            tally.failures.append(f"{label} seed {seed}: no summary (exit {run.returncode}): "
                                  f"{run.stderr.strip().splitlines()[-1:]}")
            return
        stopped_at = dt.datetime.fromisoformat(summary["processes_stopped_at"])
        lines = logged_before(out / "logs", stopped_at)
    garments = summary["garments"]
    done = [g for g in garments if g["outcome"] == "done"]
    lease = sum(LEASE_LOST in message for _, message in lines)
    link = sum(any(words in message for words in LINK_LOST) for _, message in lines)
    stalls = sum(STALL in message for _, message in lines)
    alarms = sum(bool(ALARM.match(message)) for _, message in lines)
    tally.garments += 4
    tally.done += len(done)
    tally.lease_losses += lease
    tally.link_losses += link
    tally.stalls += stalls
    tally.alarms += alarms
    for g in garments:
        if g["outcome"] != "done":
            tally.failures.append(f"{label} seed {seed}: {g['garment']} {g['outcome']}: {g['reason']}")
    missing = 4 - len(garments)
    if missing:
        tally.failures.append(f"{label} seed {seed}: {missing} garment(s) never folded "
                              f"(exit {run.returncode})")
    print(f"  {label:28} seed {seed:2d}: {len(done)}/4 done, {lease} lease and {link} link losses, "
          f"{alarms} alarms, {stalls} loop stalls, {wall:5.0f} s", flush=True)


def report(tally: Tally, label: str) -> None:
    print(f"{label}: {tally.done}/{tally.garments} garments done in {tally.runs} demos; "
          f"{tally.lease_losses} lease losses, {tally.link_losses} link losses, {tally.alarms} controller "
          f"alarms, {tally.stalls} loop stalls (counted)", flush=True)
    for failure in tally.failures:
        print(f"  not done: {failure}", flush=True)
    check(BENCH, f"garments done, {label}", tally.done, ">=", tally.garments, f"of {tally.garments}")
    check(BENCH, f"lease losses, {label}", tally.lease_losses, "<=", 0, "")
    check(BENCH, f"link losses, {label}", tally.link_losses, "<=", 0, "")
    check(BENCH, f"controller alarms, {label}", tally.alarms, "<=", 0, "")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="bench_soak")
    parser.add_argument("--runs", type=int, default=10, help="demos alone (default 10)")
    parser.add_argument("--hog-runs", type=int, default=10, help="demos beside two busy loops (default 10)")
    parser.add_argument("--wrist-runs", type=int, default=5, help="wrist-camera demos (default 5)")
    args = parser.parse_args(argv or [])
    for label, runs, hog_count, camera in (("demo alone", args.runs, 0, "fixed"),
                                           ("demo beside two busy loops", args.hog_runs, 2, "fixed"),
                                           ("wrist-camera demo", args.wrist_runs, 0, "wrist")):
        tally = Tally()
        with hogs(hog_count):
            for seed in range(1, runs + 1):
                run_demo(tally, label, seed, camera)
        if runs:
            report(tally, label)


if __name__ == "__main__":
    main(sys.argv[1:])
