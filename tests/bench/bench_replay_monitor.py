"""Replay and monitor figures: replay timing error at 1x, the rate replay sustains, and the monitor's
opening time and CPU share while watching a 250 Hz joint stream. Real processes, loopback Zenoh.

Run: .venv/bin/python -m tests.bench.bench_replay_monitor
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from drivers.robot.config import default_robot_config
from drivers.sessions.mcap.writer import SessionWriter
from drivers.wire import messages
from drivers.wire.transport import RawSample, Wire
from tests.bench.targets import check
from tests.conftest import REPO, Endpoint, foldcell_argv, wait_until
from tests.nodes.fake_cell import STATES, cell_state

RUNS = 3
SESSION_S = 4.0
JOINT_HZ = 250.0
CLK_TCK = os.sysconf("SC_CLK_TCK")


def write_session(path: Path, seconds: float, cell: str = "rec") -> int:
    """A synthetic session with exact timing: 250 Hz joints, 10 Hz status, 2 Hz state, a log per state."""
    names = list(default_robot_config().joint_names)
    t0 = time.time_ns()
    events: list[tuple[int, str, str, object]] = []
    for i in range(int(seconds * JOINT_HZ)):
        t = t0 + round(i * 1e9 / JOINT_HZ)
        events.append(
            (
                t,
                "controller/joint_states",
                "sensor_msgs/msg/JointState",
                messages.new(
                    "sensor_msgs/msg/JointState",
                    header=messages.header(t),
                    name=names,
                    position=np.full(len(names), i * 1e-3),
                ),
            )
        )
    for i in range(int(seconds * 10)):
        t = t0 + i * 100_000_000 + 1
        events.append(
            (
                t,
                "controller/status",
                "foldcell_msgs/msg/ControllerStatus",
                messages.new(
                    "foldcell_msgs/msg/ControllerStatus", header=messages.header(t), drives_powered=1
                ),
            )
        )
    for i in range(int(seconds * 2)):
        t = t0 + i * 500_000_000 + 2
        seq = list(STATES[: 1 + i % len(STATES)])
        events.append((t, "cell/state", "foldcell_msgs/msg/CellState", cell_state(cell, seq, t)))
        events.append(
            (
                t + 1,
                "cell/log",
                "rcl_interfaces/msg/Log",
                messages.new(
                    "rcl_interfaces/msg/Log", stamp=messages.stamp_from_ns(t), level=20, msg=seq[-1]
                ),
            )
        )
    events.sort(key=lambda e: e[0])
    with SessionWriter(path) as w:
        for t, rel, type_name, msg in events:
            w.write(
                f"/foldcell/{cell}/{rel}",
                type_name,
                messages.msgdef(type_name),
                messages.encode(type_name, msg),
                t,
                t,
            )
    return len(events)


class Receiver:
    def __init__(self, ep: Endpoint, cell: str):
        self.wire = Wire(ep.settings("benchrx"), "bench-rx")
        self.samples: list[tuple[int, int]] = []  # (receive_ns, sender stamp)
        self.lock = threading.Lock()
        self.wire.subscribe_raw(f"foldcell/{cell}/**", self._on)

    def _on(self, raw: RawSample) -> None:
        with self.lock:
            self.samples.append((raw.receive_ns, raw.stamp_ns or 0))

    def close(self) -> None:
        self.wire.close()


def replay_once(path: Path, total: int, rate: str) -> tuple[np.ndarray, float, int]:
    """Lateness of each received sample (ns, relative to the first), wall time of the stream, count."""
    ep = Endpoint()
    rx = Receiver(ep, "bench")
    try:
        proc = subprocess.run(
            foldcell_argv("replay", str(path), "--rate", rate, *ep.args("bench")),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=300,
        )
        if proc.returncode != 0:
            raise RuntimeError(proc.stderr)
        wait_until(lambda: len(rx.samples) >= total, 5)
    finally:
        rx.close()
    s = np.array(rx.samples, dtype=np.int64)
    recv, stamp = s[:, 0], s[:, 1]
    scale = 1.0 if rate == "max" else float(rate)
    offset = (recv - recv[0]) - ((stamp - stamp[0]) / scale).astype(np.int64)
    # no sample arrives before its due time, so the earliest one fixes the schedule's origin
    lateness = offset - offset.min()
    return lateness, (recv[-1] - recv[0]) / 1e9, len(s)


def replay_figures() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "session.mcap"
        total = write_session(path, SESSION_S)
        print(f"session: {total} samples over {SESSION_S:.0f} s (250 Hz joints, status, state, log)")
        p50s, p99s, maxes, lost = [], [], [], []
        for _ in range(RUNS):
            late, _, n = replay_once(path, total, "1")
            late_ms = late / 1e6
            p50s.append(np.median(late_ms))
            p99s.append(np.percentile(late_ms, 99))
            maxes.append(late_ms.max())
            lost.append(total - n)
        print(
            f"replay at 1x, lateness of each sample at the receiver vs the recording "
            f"(median of {RUNS} runs): p50 {np.median(p50s):.3f} ms, p99 {np.median(p99s):.3f} ms, "
            f"max {np.median(maxes):.3f} ms; samples lost {int(np.median(lost))}"
        )
        check("replay", "samples lost at 1x, worst run", max(lost), "<=", 0)
        rates, speedups, lost = [], [], []
        for _ in range(RUNS):
            _, wall, n = replay_once(path, total, "max")
            rates.append(n / wall)
            speedups.append(SESSION_S / wall)
            lost.append(total - n)
        print(
            f"replay --rate max (median of {RUNS}): {np.median(rates):.0f} samples/s received, "
            f"{np.median(speedups):.1f}x real time, samples lost {int(np.median(lost))}"
        )


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def monitor_figures() -> None:
    opens, shares, rates = [], [], []
    for _ in range(RUNS):
        ep = Endpoint("mon")
        node = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tests.nodes.fake_cell",
                *ep.args(),
                "--forever",
                "--state-period",
                "0.5",
                "--joint-hz",
                str(JOINT_HZ),
                "--wait",
                "0",
            ],
            cwd=REPO,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            time.sleep(1.5)
            start = time.monotonic()
            mon = subprocess.Popen(
                foldcell_argv("monitor", "--json", "--duration", "9", *ep.args()),
                cwd=REPO,
                stdout=subprocess.PIPE,
                stderr=subprocess.DEVNULL,
                text=True,
            )
            while True:  # opened = the first snapshot that shows the cell's joint stream
                first = mon.stdout.readline()
                if not first or "controller/joint_states" in first:
                    break
            opened = time.monotonic() - start
            lines: list[str] = []
            reader = threading.Thread(target=lines.extend, args=(mon.stdout,), daemon=True)
            reader.start()
            time.sleep(1.5)
            c0, t0 = cpu_seconds(mon.pid), time.monotonic()
            time.sleep(5.0)
            c1, t1 = cpu_seconds(mon.pid), time.monotonic()
            mon.wait(30)
            reader.join(5)
            last = json.loads(lines[-1]) if lines else json.loads(first)
            rates.append(last["cells"]["mon"]["topics"]["controller/joint_states"]["rate_hz"])
            opens.append(opened)
            shares.append((c1 - c0) / (t1 - t0) * 100)
        finally:
            node.send_signal(2)
            node.wait(10)
    imports = []
    for _ in range(RUNS):
        t = time.monotonic()
        subprocess.run(
            [sys.executable, "-c", "import tools.cli; tools.cli.build_parser()"], cwd=REPO, check=True
        )
        imports.append(time.monotonic() - t)
    startup_ms = np.median(imports) * 1000
    print(f"`foldcell` start-up alone (python, import tools.cli, build the parser): {startup_ms:.0f} ms")
    print(
        f"monitor: first snapshot showing the joint stream {np.median(opens) * 1000:.0f} ms after start "
        f"(median of {RUNS}; includes the start-up above); CPU share watching a 250 Hz joint stream "
        f"{np.median(shares):.1f} % of one core (min {min(shares):.1f}, max {max(shares):.1f}); "
        f"joint rate it shows {np.median(rates):.1f} Hz"
    )
    check("monitor", "first snapshot with the joint stream after start, median", np.median(opens), "<",
          1.0, "s")
    check("monitor", "joint rate shown for a 250 Hz stream, median", np.median(rates), ">=", 245.0, "Hz")


def main() -> None:
    replay_figures()
    monitor_figures()


if __name__ == "__main__":
    main()
