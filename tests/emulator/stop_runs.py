"""Stops of a two-arm motion on the split master/slave processes, measured against the commanded path.

Shared by `tests/emulator/test_stops.py` (which asserts) and `tests/bench/bench_stops.py` (which prints
the figures). The reference is the trajectory's own points interpolated by scipy's cubic Hermite spline,
not the emulator's interpolation or output.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from drivers.controller.codes import Command
from drivers.controller.config import default_controller_config
from drivers.controller.errors import NotReady
from drivers.controller.interface import MotionStatus
from drivers.controller.motion import plan_point_to_point
from drivers.controller.trajectory import JointTrajectory
from drivers.controller.zenoh_client import ZenohController
from drivers.robot.config import default_robot_config
from drivers.wire.transport import Wire
from tests.conftest import REPO, Endpoint, Proc, foldcell_argv, wait_until
from tests.emulator.test_process import Recorder

RC = default_robot_config()
CFG = default_controller_config()
PERIOD = CFG.interpolation_period
KINDS = ("hold", "stop", "lease loss", "e-stop")
ARMS = {"R1": [RC.index(j) for j in (*RC.group("R1").joints, *RC.group("B1").joints)],  # the master's
        "R2": [RC.index(j) for j in RC.group("R2").joints]}  # the slave's
# both arms and the turn-table move all the way, fast enough that a stop takes several ticks
DELTA = np.array([0.5, -0.4, 0.4, 0.6, -0.5, 0.6, -0.5, 0.4, -0.4, -0.6, 0.5, -0.6, 0.3])
PLAN_FRACTION = 0.7  # of every joint's velocity/acceleration/jerk limit
STOP_AT = 0.4  # share of the motion's duration after which the stop is asked for

HOLDER = """
import sys, time, numpy as np
from drivers.wire.settings import load_wire_settings
from drivers.wire.transport import Wire
from drivers.controller.zenoh_client import ZenohController
from drivers.controller.trajectory import JointTrajectory
s = load_wire_settings().overridden(cell_id=sys.argv[1], listen=['tcp/127.0.0.1:0'], connect=[sys.argv[2]])
c = ZenohController(Wire(s, 'holder'))
c.connect(timeout=20)
c.acquire_lease()
arrays = np.load(sys.argv[3])
h = c.execute(JointTrajectory(c.robot_config.joint_names, arrays['t'], arrays['p'], arrays['v']))
print(h.reply.start_tick, flush=True)
time.sleep(60)
"""


Running = tuple[Endpoint, ZenohController, Recorder, list[Proc]]


@contextlib.contextmanager
def master_and_slave(tmp: Path, time_scale: float = 1.0) -> Iterator[Running]:
    """`foldcell controller serve` as master and slave, a client holding the lease, a joint-state
    recorder."""
    ep = Endpoint("stops")
    serve = ("controller", "serve", "--time-scale", str(time_scale), *ep.args())
    procs = [Proc(foldcell_argv(*serve, "--role", role), tmp / f"{role}.log") for role in ("master", "slave")]
    wire = Wire(ep.settings(), "tester")
    ctl = ZenohController(wire)
    try:
        ctl.connect(timeout=30)
        linked = wait_until(lambda: all(g.link_ok for g in ctl.status_message().groups), 30)
        assert linked, ctl.status_message()
        ctl.acquire_lease()
        make_ready(ctl)
        yield ep, ctl, Recorder(wire), procs
    finally:
        wire.close()
        for proc in reversed(procs):
            proc.stop()


def make_ready(ctl: ZenohController) -> None:
    for code in (Command.ESTOP_RESET, Command.RESET_ALARM, Command.RESUME, Command.START_TRAJ_MODE):
        with contextlib.suppress(NotReady):
            ctl.command(code)
    assert ctl.wait_status(lambda s: s.motion_possible and not s.in_motion and s.queue_count == 0, 20), \
        ctl.status()


def two_arm_trajectory(start: np.ndarray, target: np.ndarray | None = None) -> JointTrajectory:
    """A jerk-limited motion of every joint from `start` to `target` (default `start + DELTA`)."""
    f = PLAN_FRACTION
    goal = start + DELTA if target is None else target
    times, positions, velocities = plan_point_to_point(
        start, goal, RC.max_velocity * f, RC.max_acceleration * f, RC.max_jerk * f, CFG.max_points)
    return JointTrajectory(RC.joint_names, times, positions, velocities, "stop-run")


class CommandedPath:
    """The commanded path, interpolated independently of the emulator, on a dense grid of its time."""

    def __init__(self, trajectory: JointTrajectory, step: float = 1e-4):
        self.spline = CubicHermiteSpline(trajectory.times, trajectory.positions, trajectory.point_velocities)
        self.grid_t = np.arange(0.0, trajectory.duration + step, step)
        self.grid = self.spline(np.minimum(self.grid_t, trajectory.duration))

    def deviation(self, q: np.ndarray) -> float:
        """min over the path parameter s of max over joints |q - path(s)|, rad."""
        return float(np.abs(self.grid - q).max(axis=1).min())

    def at(self, t: float) -> np.ndarray:
        return np.asarray(self.spline(min(max(t, 0.0), float(self.grid_t[-1]))))


@dataclass
class StopRun:
    """One stop: the joint states (tick, q, v; one per tick, sorted) from the start to rest."""

    kind: str
    trajectory: JointTrajectory
    start_tick: int
    samples: list[tuple[int, np.ndarray, np.ndarray]]

    def deviation(self) -> float:
        """The largest distance (rad) of a recorded configuration from the coordinated path."""
        path = CommandedPath(self.trajectory)
        return max(path.deviation(q) for _, q, _ in self.samples)

    def worst_sample(self) -> str:
        """Where the largest deviation was: its tick from the start, and the path time each arm alone
        fits best (arms apart on the path, or both off it), for a failure's message."""
        path = CommandedPath(self.trajectory)
        tick, q, _ = max(self.samples, key=lambda sample: path.deviation(sample[1]))
        fits = {arm: float(path.grid_t[np.abs(path.grid[:, cols] - q[cols]).max(axis=1).argmin()])
                for arm, cols in ARMS.items()}
        return (f"tick {tick - self.start_tick} from the start (brake tick "
                f"{self.brake_tick() - self.start_tick}); path time fitted per arm: "
                + ", ".join(f"{arm} {t:.4f} s" for arm, t in fits.items()))

    def stop_tick(self, arm: str) -> int:
        """The first tick from which `arm` is at rest for good."""
        cols = ARMS[arm]
        moving = [tick for tick, _, v in self.samples if v[cols].any()]
        assert moving, f"{arm} never moved"
        return min(tick for tick, _, v in self.samples if tick > moving[-1])

    def brake_tick(self) -> int:
        """The first tick whose configuration is off the nominal timing (the stop began)."""
        path = CommandedPath(self.trajectory)
        return next(tick for tick, q, _ in self.samples
                    if np.abs(q - path.at((tick - self.start_tick) * PERIOD)).max() > 1e-7)

    def worst_acceleration(self) -> float:
        """The largest |dv/dt| between consecutive ticks as a share of the joint's limit."""
        worst = 0.0
        for (t0, _, v0), (t1, _, v1) in zip(self.samples, self.samples[1:], strict=False):
            ratio = np.abs(v1 - v0) / ((t1 - t0) * PERIOD) / RC.max_acceleration
            worst = max(worst, float(ratio.max()))
        return worst

    def worst_velocity(self) -> float:
        return max(float((np.abs(v) / RC.max_velocity).max()) for _, _, v in self.samples)


Sample = tuple[int, np.ndarray, np.ndarray]


def one_per_tick(samples: list[Sample]) -> list[Sample]:
    by_tick = {tick: (tick, q, v) for tick, q, v in samples}
    return [by_tick[t] for t in sorted(by_tick)]


REST_TICKS = round(0.2 / PERIOD)  # still this long (robot time) counts as at rest


def at_rest(rec: Recorder, since: int, timeout: float = 30.0) -> int:
    """Wait until every joint has been still for 0.2 s of robot time; the tick it came to rest."""
    def resting() -> bool:
        samples = one_per_tick(rec.since(since))
        moving = [tick for tick, _, v in samples if v.any()]
        return bool(moving) and samples[-1][0] - moving[-1] >= REST_TICKS

    assert wait_until(resting, timeout), "the robot did not come to rest"
    return max(tick for tick, _, v in one_per_tick(rec.since(since)) if v.any()) + 1


def run_stop(kind: str, ep: Endpoint, ctl: ZenohController, rec: Recorder) -> StopRun:
    """Move both arms home, start the two-arm motion, stop it `kind`'s way mid-motion, wait for rest,
    and recover (resume, reset, re-take the lease)."""
    home = np.asarray(RC.home, dtype=float)
    if np.abs(ctl.joint_state().positions - home).max() > CFG.goal_tolerance:
        assert ctl.move_to(home).wait(60) == MotionStatus.SUCCEEDED
    trajectory = two_arm_trajectory(ctl.joint_state().positions.copy())
    rec.clear()
    holder = None
    if kind == "lease loss":
        ctl.release_lease()
        holder, start = _holder_executes(ep, trajectory)
    else:
        handle = ctl.execute(trajectory)
        start = handle.reply.start_tick
    try:
        stop_tick = start + round(STOP_AT * trajectory.duration / PERIOD)
        assert wait_until(lambda: any(tick >= stop_tick for tick, _, _ in rec.since(start)), 60), \
            "the motion did not reach the stop point"
        if kind == "hold":
            ctl.command(Command.HOLD)
        elif kind == "stop":
            ctl.command(Command.STOP_MOTION)
        elif kind == "e-stop":
            ctl.command(Command.ESTOP)
        else:
            assert holder is not None
            holder.send_signal(signal.SIGKILL)
            holder.wait(10)
        rest = at_rest(rec, start)
    finally:
        if holder is not None and holder.poll() is None:
            holder.kill()
            holder.wait()
    # the resting ticks are kept: the joint stream may drop a sample, the one at `rest` included
    samples = [s for s in one_per_tick(rec.since(start - 1)) if s[0] <= rest + REST_TICKS]
    if kind == "lease loss":
        assert ctl.wait_status(lambda s: s.lease_holder == "", 20)
        ctl.acquire_lease()
    make_ready(ctl)
    if kind == "hold":
        assert handle.wait(60) == MotionStatus.SUCCEEDED  # resumed by make_ready
    return StopRun(kind, trajectory, start, samples)


def _holder_executes(ep: Endpoint, trajectory: JointTrajectory) -> tuple[subprocess.Popen, int]:
    """A client process that takes the lease and starts `trajectory` (killed to lose the lease)."""
    with tempfile.NamedTemporaryFile(suffix=".npz", delete=False) as f:
        np.savez(f, t=trajectory.times, p=trajectory.positions, v=trajectory.point_velocities)
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, ep.cell, ep.url, f.name], cwd=REPO,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    line = holder.stdout.readline().strip() if holder.stdout else b""
    os.unlink(f.name)
    if not line.isdigit():
        holder.kill()
        err = holder.stderr.read().decode() if holder.stderr else ""
        raise AssertionError(f"the lease holder did not start the motion: {line!r} {err}")
    return holder, int(line)

