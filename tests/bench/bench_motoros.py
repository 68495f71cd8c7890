"""MotoROS server figures, at TCP clients in this process against `foldcell controller serve --motoros`
(another process), with the client of tests/motoros/client.py written from the protocol facts:

    .venv/bin/python -m tests.bench motoros

- the state stream: per message type (JOINT_FEEDBACK per group, MOTO_JOINT_FEEDBACK_EX, ROBOT_STATUS)
  the rate and the period's median, p95, max and jitter, at rest and while a trajectory streams
  (MotoROS: one burst every 25 ms plus processing time);
- trajectory streaming: one R1 point per interpolation period (one increment each), sent one by one
  and resent every 5 ms on BUSY (as the ROS client does): points per second accepted before the
  queue is full and after, BUSY replies, state bursts that found the robot starved (not in motion);
- from the last point accepted to the robot at rest (ROBOT_STATUS in_motion 0 on the state stream),
  against the time the queued increments take to run (CHECK_QUEUE_CNT right after the last point).
"""

from __future__ import annotations

import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from tempfile import TemporaryDirectory

import numpy as np

from drivers.controller.config import default_controller_config
from drivers.motoros.config import load_motoros_config
from tests.bench.targets import check
from tests.conftest import Endpoint, Proc, foldcell_argv
from tests.motoros import client as mc
from tests.motoros.test_process import free_ports

REST_WINDOW_S = 5.0
MOTION_S = 6.0  # robot seconds of the streamed trajectory
AMPLITUDE_RAD = 0.3  # of R1's joint S
STATE_PERIOD_SLACK_S = 0.003  # ROBOT_STATUS median period: MotoROS' 25 ms within this
STARTUP_S = 60.0
# from the last point to rest, beyond the queue's own run time: two state periods (when in_motion
# flips between bursts, and the burst's delivery) plus a margin for a shared machine
REST_EXCESS_LIMIT_S = 0.06
STEADY_FRACTION = 0.95  # of the trajectory's own points per robot second: the stream keeps up

# MotoROS truncates a point's time to whole ms (section 7): k * 4 ms as float32 may read as k * 4 - 1,
# and a 3 ms segment between points meant 4 ms apart accelerates past the limits (an alarm)
TIME_MARGIN_S = 1e-5
JOINT_FEEDBACK, ROBOT_STATUS, FEEDBACK_EX = 15, 13, 2017


@dataclass
class StateArrivals:
    """Every state frame's arrival (perf_counter s) by kind, and ROBOT_STATUS' in_motion."""

    port: int
    arrivals: dict[str, list[float]] = field(default_factory=dict)
    in_motion: list[tuple[float, int]] = field(default_factory=list)
    error: str = ""

    def __post_init__(self) -> None:
        self.sock = socket.create_connection(("127.0.0.1", self.port), timeout=mc.REPLY_TIMEOUT_S)
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        threading.Thread(target=self._run, daemon=True, name="bench-state").start()

    def _run(self) -> None:
        try:
            while True:
                msg_type, _, _, body = mc.read_frame(self.sock)
                now = time.perf_counter()
                if msg_type == JOINT_FEEDBACK:
                    kind = f"JOINT_FEEDBACK group {struct.unpack_from('<i', body)[0]}"
                elif msg_type == FEEDBACK_EX:
                    kind = "MOTO_JOINT_FEEDBACK_EX"
                elif msg_type == ROBOT_STATUS:
                    kind = "ROBOT_STATUS"
                else:
                    kind = f"type {msg_type}"
                with self.changed:
                    self.arrivals.setdefault(kind, []).append(now)
                    if msg_type == ROBOT_STATUS:
                        self.in_motion.append((now, struct.unpack_from("<7i", body)[4]))
                    self.changed.notify_all()
        except (OSError, ConnectionError) as exc:
            with self.changed:
                self.error = str(exc)
                self.changed.notify_all()

    def window(self, start: float, end: float) -> dict[str, np.ndarray]:
        with self.lock:
            return {kind: np.array([t for t in times if start <= t <= end])
                    for kind, times in sorted(self.arrivals.items())}

    def first_rest_after(self, after: float, timeout: float) -> float:
        """Arrival of the first ROBOT_STATUS with in_motion 0 after `after`."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                found = next((t for t, moving in self.in_motion if t > after and not moving), None)
                if found is not None:
                    return found
                left = deadline - time.monotonic()
                if left <= 0 or self.error:
                    raise RuntimeError(f"the robot never came to rest ({self.error or 'timeout'})")
                self.changed.wait(left)

    def starved(self, start: float, end: float) -> int:
        with self.lock:
            return sum(1 for t, moving in self.in_motion if start <= t <= end and not moving)

    def close(self) -> None:
        self.sock.close()


def _stream_figures(label: str, windows: dict[str, np.ndarray], period: float) -> float:
    """Print a table of each kind's rate and period; returns ROBOT_STATUS' median period (s)."""
    print(f"  state stream {label}:")
    print(f"    {'message':<26} {'count':>6} {'rate Hz':>8} {'median ms':>10} {'p95 ms':>8} {'max ms':>8} "
          f"{'jitter ms':>10}")
    median_status = float("nan")
    for kind, times in windows.items():
        if len(times) < 3:
            print(f"    {kind:<26} {len(times):>6}")
            continue
        dt = np.diff(times)
        rate = (len(times) - 1) / (times[-1] - times[0])
        jitter = np.percentile(np.abs(dt - period), 95)  # p95 of |period - MotoROS' 25 ms|
        print(f"    {kind:<26} {len(times):>6} {rate:>8.2f} {np.median(dt) * 1e3:>10.2f} "
              f"{np.percentile(dt, 95) * 1e3:>8.2f} {dt.max() * 1e3:>8.2f} {jitter * 1e3:>10.2f}")
        if kind == "ROBOT_STATUS":
            median_status = float(np.median(dt))
    print("    (jitter: p95 of |period - state_period|)")
    return median_status


def _wait_for_port(port: int, proc: Proc) -> None:
    deadline = time.monotonic() + STARTUP_S
    while time.monotonic() < deadline:
        if proc.popen.poll() is not None:
            raise RuntimeError(f"foldcell controller serve exited with {proc.popen.returncode}: "
                               f"{proc.stderr()[-2000:]}")
        try:
            socket.create_connection(("127.0.0.1", port), timeout=1.0).close()
            return
        except OSError:
            time.sleep(0.1)
    raise RuntimeError(f"no MotoROS state port on 127.0.0.1:{port} within {STARTUP_S:g} s")


def _points(period: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """R1 from home out and back on joint S, one point per interpolation period, rest to rest."""
    times = np.arange(0.0, MOTION_S + period / 2, period)
    phase = 2.0 * np.pi * times / MOTION_S
    positions = np.zeros((len(times), 6))
    velocities = np.zeros((len(times), 6))
    positions[:, 0] = AMPLITUDE_RAD * 0.5 * (1.0 - np.cos(phase))
    velocities[:, 0] = AMPLITUDE_RAD * 0.5 * np.sin(phase) * 2.0 * np.pi / MOTION_S
    velocities[-1] = 0.0
    return times, positions, velocities


def _stream(client: mc.MotionClient, times: np.ndarray, positions: np.ndarray,
            velocities: np.ndarray) -> tuple[list[float], int, float | None]:
    """Send every point (group 0), resending on BUSY every 5 ms; (acceptance times, BUSY count, time of
    the first BUSY)."""
    accepted: list[float] = []
    busy = 0
    first_busy = None
    for seq, (t, p, v) in enumerate(zip(times, positions, velocities, strict=True)):
        while True:
            reply = client.point(0, seq, float(t) + TIME_MARGIN_S, p, v)
            if reply.result != mc.BUSY:
                break
            busy += 1
            first_busy = first_busy or time.perf_counter()
            time.sleep(0.005)
        if reply.result != mc.SUCCESS:
            raise RuntimeError(f"point {seq}: result {reply.result} subcode {reply.subcode}")
        accepted.append(time.perf_counter())
    return accepted, busy, first_busy


def main() -> None:
    motoros = load_motoros_config()
    period = default_controller_config().interpolation_period
    ep = Endpoint("bench-motoros")
    port = free_ports()
    logs = TemporaryDirectory()
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", "--motoros", f"127.0.0.1:{port}",
                              *ep.args()), Path(logs.name) / "serve.log")
    state = client = None
    try:
        _wait_for_port(port + 1, proc)
        state = StateArrivals(port + 1)
        start = time.perf_counter()
        time.sleep(REST_WINDOW_S)  # a window of the stream at rest
        median_rest = _stream_figures(f"at rest ({REST_WINDOW_S:g} s)",
                                      state.window(start, time.perf_counter()), motoros.state_period)

        client = mc.MotionClient(port)
        if client.ctrl(mc.START_TRAJ_MODE).result != mc.SUCCESS:
            raise RuntimeError("START_TRAJ_MODE refused")
        times, positions, velocities = _points(period)
        sent = time.perf_counter()
        accepted, busy, first_busy = _stream(client, times, positions, velocities)
        last = accepted[-1]
        queued = client.ctrl(mc.CHECK_QUEUE_CNT).subcode
        queue_reply = time.perf_counter()
        rest = state.first_rest_after(last, MOTION_S + 10.0)

        median_motion = _stream_figures(f"while streaming ({last - sent:.1f} s)", state.window(sent, last),
                                        motoros.state_period)
        count = len(accepted) - 1  # the start point queues nothing
        burst = sum(1 for t in accepted[1:] if first_busy is None or t < first_busy)
        steady = [t for t in accepted[1:] if first_busy is not None and t >= first_busy]
        steady_rate = (len(steady) - 1) / (steady[-1] - steady[0]) if len(steady) > 1 else float("nan")
        burst_rate = burst / ((first_busy or last) - accepted[0])
        wanted = 1.0 / period
        elapsed = last - accepted[0]
        print(f"  trajectory streaming: {count} points (one per {period * 1e3:g} ms of robot time) in "
              f"{elapsed:.2f} s = {count / elapsed:.1f} points/s, {busy} BUSY replies")
        print(f"    until the queue was full: {burst} points at {burst_rate:.0f} points/s "
              "(the request round trip)")
        print(f"    then: {steady_rate:.1f} points/s (the robot's pace: {wanted:g} points/s); "
              f"{state.starved(accepted[1], last)} state bursts found the robot starved")
        drain = queued * period
        after_queue = rest - queue_reply
        print(f"  last point accepted -> at rest on the state stream: {(rest - last) * 1e3:.1f} ms "
              f"({queued} increments queued = {drain * 1e3:.0f} ms of motion; "
              f"{(after_queue - drain) * 1e3:+.1f} ms beyond it)")
        for label, median in (("at rest", median_rest), ("while streaming", median_motion)):
            check("motoros", f"ROBOT_STATUS median period {label}", round(median * 1e3, 2), ">=",
                  (motoros.state_period - STATE_PERIOD_SLACK_S) * 1e3, "ms")
            check("motoros", f"ROBOT_STATUS median period {label}", round(median * 1e3, 2), "<=",
                  (motoros.state_period + STATE_PERIOD_SLACK_S) * 1e3, "ms")
        check("motoros", "points/s accepted once the queue is full", round(steady_rate, 1), ">=",
              STEADY_FRACTION * wanted, "points/s")
        check("motoros", "last point to rest beyond the queued increments", round(after_queue - drain, 4),
              "<=", REST_EXCESS_LIMIT_S, "s")
    finally:
        for closable in (client, state):
            if closable is not None:
                closable.close()
        proc.stop()
        logs.cleanup()


if __name__ == "__main__":
    main()
