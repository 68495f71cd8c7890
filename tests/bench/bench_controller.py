"""Controller emulator figures: joint-state rate and inter-arrival jitter at a subscriber in another
process (at rest and in motion, >= 10 s each, 250 Hz), trajectory-submit round trip, and the
emulator's CPU share at rest and in motion.

Run: `.venv/bin/python -m tests.bench.bench_controller` (about 40 s).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from drivers.controller.codes import Command
from drivers.controller.config import default_controller_config
from drivers.controller.trajectory import JointTrajectory
from drivers.controller.zenoh_client import ZenohController
from drivers.robot.config import default_robot_config
from drivers.wire.transport import Wire
from tests.bench.targets import check
from tests.conftest import REPO, Endpoint

WINDOW_S = 10.0
SUBMITS = 60
MIN_JOINT_STATE_RATE_HZ = 245.0  # of the configured 250 Hz, at a subscriber in another process


def _cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class Arrivals:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.times: list[int] = []

    def __call__(self, raw) -> None:
        with self.lock:
            self.times.append(raw.receive_ns)

    def take(self) -> np.ndarray:
        with self.lock:
            out = np.array(self.times, dtype=np.int64)
            self.times.clear()
        return out


def _window(label: str, arrivals: Arrivals, pid: int, rate: float) -> None:
    arrivals.take()
    cpu0, t0 = _cpu_seconds(pid), time.monotonic()
    time.sleep(WINDOW_S)
    cpu1, t1 = _cpu_seconds(pid), time.monotonic()
    stamps = arrivals.take()
    dt = np.diff(stamps) * 1e-6  # ms
    jitter = np.abs(dt - 1000.0 / rate)
    received_hz = len(stamps) / (t1 - t0)
    print(f"{label}: {len(stamps)} joint states in {t1 - t0:.1f} s = {received_hz:.1f} Hz "
          f"(configured {rate:g} Hz)")
    print(f"  inter-arrival ms p50 {np.percentile(dt, 50):.3f}  p99 {np.percentile(dt, 99):.3f}  "
          f"max {dt.max():.3f}")
    print(f"  jitter |dt - {1000.0 / rate:g} ms| p50 {np.percentile(jitter, 50):.3f}  "
          f"p99 {np.percentile(jitter, 99):.3f}  max {jitter.max():.3f} ms")
    print(f"  emulator CPU share {100.0 * (cpu1 - cpu0) / (t1 - t0):.1f} % of one core")
    check("controller", f"joint-state rate {label}", received_hz, ">=", MIN_JOINT_STATE_RATE_HZ, "Hz")


def main() -> None:
    rc, cfg = default_robot_config(), default_controller_config()
    ep = Endpoint("bench")
    proc = subprocess.Popen([sys.executable, "-m", "tools.cli", "controller", "serve", "--role", "both",
                             *ep.args()], cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wire = Wire(ep.settings(), "bench")
    try:
        ctl = ZenohController(wire)
        ctl.connect(timeout=30)
        arrivals = Arrivals()
        wire.subscribe_raw(wire.key("controller/joint_states"), arrivals)
        time.sleep(1.0)
        _window("at rest", arrivals, proc.pid, cfg.feedback_rate)

        ctl.acquire_lease()
        ctl.command(Command.START_TRAJ_MODE)
        q0 = ctl.joint_state().positions.copy()
        rtts = []
        for _ in range(SUBMITS):
            traj = JointTrajectory(rc.joint_names, np.array([0.0, 0.05]), np.stack([q0, q0]))
            t = time.perf_counter()
            ctl.execute(traj)
            rtts.append(time.perf_counter() - t)
            time.sleep(0.1)
        ms = np.array(rtts) * 1e3
        print(f"trajectory submit round trip ({SUBMITS} accepted 2-point trajectories): "
              f"median {np.median(ms):.2f} ms  p99 {np.percentile(ms, 99):.2f} ms  max {ms.max():.2f} ms")

        time.sleep(0.2)
        amp = np.where(np.arange(13) < 12, 0.3, 0.2)
        k = 9
        times = np.linspace(0.0, WINDOW_S + 4.0, k)
        pos = np.stack([q0 + amp * (i % 2) for i in range(k)])
        handle = ctl.execute(JointTrajectory(rc.joint_names, times, pos))
        time.sleep(1.0)
        _window("in motion", arrivals, proc.pid, cfg.feedback_rate)
        assert ctl.status().in_motion, "the robot should still be moving"
        ctl.stop()
        handle.wait(5)
        ctl.release_lease()
    finally:
        wire.close()
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


if __name__ == "__main__":
    main()
