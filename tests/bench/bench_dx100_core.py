"""Bench of the pure DX100 emulator core: interpolation ticks per second and acceptance time.

Run: .venv/bin/python -m tests.bench.bench_dx100_core
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from drivers.controller.acceptance import check_trajectory
from drivers.controller.codes import OK, Command
from drivers.controller.config import default_controller_config
from drivers.controller.motion import move_trajectory
from drivers.controller.trajectory import JointTrajectory
from drivers.emulator.core import ControllerCore
from drivers.robot.config import default_robot_config

REPEATS = 7
TICKS = 5000

RC = default_robot_config()
CFG = default_controller_config()
N = len(RC.joint_names)


def _core() -> ControllerCore:
    core = ControllerCore(RC, CFG, "both")
    core.command(Command.LEASE_ACQUIRE, "bench")
    core.command(Command.START_TRAJ_MODE, "bench")
    return core


def _long_trajectory(points: int) -> JointTrajectory:
    """`points` points, slow sine waves on every axis, zero velocity at both ends."""
    t = np.linspace(0.0, 60.0, points)
    phase = np.linspace(0, np.pi, N)
    shape = np.sin(2 * np.pi * t[:, None] / 60.0 * 3 + phase) - np.sin(phase)
    window = np.sin(np.pi * t / 60.0)[:, None] ** 2
    p = 0.3 * shape * window
    v = np.gradient(p, t, axis=0)
    v[0] = v[-1] = 0.0
    return JointTrajectory(RC.joint_names, t, p, v)


def ticks_per_second(mode: str) -> float:
    core = _core()
    if mode != "idle":
        reply = core.submit(_long_trajectory(200), "bench")
        assert reply.ok, reply
        core.run_until(1.0)
    start = time.perf_counter()
    for i in range(TICKS):
        # "hold": alternate hold and resume every 200 ticks, so most ticks change the speed factor
        if mode == "hold" and i % 200 == 0:
            core.command(Command.HOLD if (i // 200) % 2 == 0 else Command.RESUME, "bench")
        core.step()
    return TICKS / (time.perf_counter() - start)


def acceptance_seconds(points: int) -> float:
    trajectory = _long_trajectory(points)
    cur = np.zeros(N)
    assert check_trajectory(trajectory, cur, RC, CFG).ok
    start = time.perf_counter()
    loops = 50
    for _ in range(loops):
        check_trajectory(trajectory, cur, RC, CFG)
    return (time.perf_counter() - start) / loops


def move_to_plan_seconds() -> float:
    rng = np.random.default_rng(0)
    targets = rng.uniform(RC.lower * 0.8, RC.upper * 0.8, size=(20, N))
    core = _core()
    start = time.perf_counter()
    for q in targets:
        planned = move_trajectory(Command.MOVE_TO, core.axes, core.queue_end_position(), q, "", OK, CFG)
        assert isinstance(planned, JointTrajectory), planned
    return (time.perf_counter() - start) / len(targets)


def median(fn, *args) -> float:
    return statistics.median(fn(*args) for _ in range(REPEATS))


def main() -> None:
    rate = 1.0 / CFG.interpolation_period
    print(f"DX100 core bench, 13 axes, medians of {REPEATS} runs of {TICKS} ticks")
    for mode in ("idle", "motion", "hold"):
        tps = median(ticks_per_second, mode)
        print(f"  ticks/s {mode:7s}: {tps:10.0f}  ({tps / rate:6.1f} x real time at {rate:.0f} Hz, "
              f"{1e6 / tps:6.1f} us/tick)")
    for points in (2, 200):
        s = median(acceptance_seconds, points)
        print(f"  check_trajectory, {points:3d} points: {s * 1e3:7.3f} ms")
    print(f"  move_to ruckig plan + sampling: {median(move_to_plan_seconds) * 1e3:7.3f} ms")


if __name__ == "__main__":
    main()
