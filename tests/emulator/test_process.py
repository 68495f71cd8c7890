"""The emulator as a real process (`foldcell controller serve --role both`) on loopback Zenoh,
driven through `ZenohController`: acceptance, tracking, e-stop, lease, bad bytes."""

from __future__ import annotations

import contextlib
import itertools
import re
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import yaml

from drivers.controller import codec
from drivers.controller.codes import Command, Result, Subcode
from drivers.controller.config import default_controller_config
from drivers.controller.credential import Signer
from drivers.controller.errors import ControllerError, LeaseHeld, NotReady, TrajectoryRejected
from drivers.controller.interface import MotionStatus
from drivers.controller.trajectory import JointTrajectory
from drivers.controller.zenoh_client import ZenohController
from drivers.emulator.commands import EmulatorCommand
from drivers.emulator.motion import PreparedTrajectory
from drivers.robot.config import default_robot_config
from drivers.wire import messages
from drivers.wire.messages import ErrorReply, NoReply
from drivers.wire.registry import payload_limit
from drivers.wire.timebase import TimeBase, timebase_of
from drivers.wire.transport import Wire
from tests.bench.bench_flood import flood_then_estop
from tests.conftest import REPO, Endpoint, Proc, foldcell_argv, request_once_served, wait_until

K = 4.0  # robot time runs 4x faster than wall time
RC = default_robot_config()
CFG = default_controller_config()
NAMES = RC.joint_names
PERIOD = CFG.interpolation_period


class Recorder:
    """Every joint state received after the first status, as (tick, positions, velocities): the tick of
    its wall-clock stamp by the time base the status states."""

    def __init__(self, wire: Wire):
        self.lock = threading.Lock()
        self.samples: list[tuple[int, np.ndarray, np.ndarray]] = []
        self.timebase: TimeBase | None = None
        wire.subscribe("controller/status", self._on_status)
        wire.subscribe("controller/joint_states", self._on)

    def _on_status(self, key, msg, raw) -> None:
        self.timebase = timebase_of(msg)

    def _on(self, key, msg, raw) -> None:
        if self.timebase is None:
            return
        tick = round(self.timebase.robot(messages.stamp_to_ns(msg.header.stamp)) / (PERIOD * 1e9))
        with self.lock:
            self.samples.append((tick, np.array(msg.position), np.array(msg.velocity)))

    def since(self, tick: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        with self.lock:
            return [s for s in self.samples if s[0] >= tick]

    def clear(self) -> None:
        with self.lock:
            self.samples.clear()


@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    ep = Endpoint("ctlboth")
    log = tmp_path_factory.mktemp("ctl") / "serve.log"
    argv = foldcell_argv("controller", "serve", "--role", "both", "--time-scale", str(K), *ep.args())
    proc = Proc(argv, log)
    wire = Wire(ep.settings(), "tester")
    ctl = ZenohController(wire)
    try:
        ctl.connect(timeout=30)
        ctl.acquire_lease()
        rec = Recorder(wire)
        yield ep, proc, wire, ctl, rec
    finally:
        wire.close()
        proc.stop()


def make_ready(ctl: ZenohController) -> None:
    for code in (Command.ESTOP_RESET, Command.RESET_ALARM, EmulatorCommand.PENDANT_PLAY,
                 EmulatorCommand.PENDANT_REMOTE_ON, Command.RESUME if ctl.status().held else None,
                 Command.START_TRAJ_MODE):
        if code is None:
            continue
        with contextlib.suppress(NotReady):
            ctl.command(code)
    assert ctl.wait_status(lambda s: s.motion_possible and not s.in_motion and s.queue_count == 0, 10)


def states_over(rec: Recorder, robot_s: float, first_tick: int = 0,
                timeout: float = 20.0) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """The joint states from `first_tick` on, once they span `robot_s` of robot time; a stream that
    stops fails the test."""
    span = round(robot_s / PERIOD)

    def spanned() -> bool:
        ticks = [s[0] for s in rec.since(first_tick)]
        return bool(ticks) and max(ticks) - min(ticks) >= span

    assert wait_until(spanned, timeout), f"the joint-state stream stopped after {len(rec.since(first_tick))}"
    return rec.since(first_tick)


def still_for(rec: Recorder, q0: np.ndarray, robot_s: float = 1.2) -> None:
    """The robot does not move: every joint state over `robot_s` of robot time equals q0, at rest."""
    rec.clear()
    for _, q, v in states_over(rec, robot_s):
        np.testing.assert_array_equal(q, q0)
        assert not v.any()


def traj(q0: np.ndarray, targets: list[np.ndarray], times: list[float], vel=None) -> JointTrajectory:
    return JointTrajectory(NAMES, np.array(times, dtype=float), np.stack([q0, *targets]), vel)


def start_tick(reply) -> int:
    """The accepted trajectory's start tick, as the reply's field gives it (its text says the same)."""
    assert reply.start_tick > 0, reply
    assert f"start tick {reply.start_tick}" in reply.text, reply.text
    return reply.start_tick


def bad_trajectories(q0: np.ndarray) -> list[tuple[str, JointTrajectory, int, int, int, str]]:
    """(name, trajectory, result, subcode, point, joint)."""
    up = q0.copy()
    up[2] += 0.1
    swapped = list(NAMES)
    swapped[0], swapped[1] = swapped[1], swapped[0]
    far = q0.copy()
    far[4] = RC.upper[4] + 0.05
    fast = q0.copy()
    fast[0] += 1.0
    off = q0.copy()
    off[7] += 0.05
    return [
        ("names", JointTrajectory(tuple(swapped), np.array([0.0, 1.0]), np.stack([q0, up])),
         Result.INVALID, Subcode.INVALID_DATA, -1, None),
        ("one point", JointTrajectory(NAMES, np.array([0.0]), q0[None, :]),
         Result.INVALID, Subcode.INVALID_DATA_INSUFFICIENT, -1, None),
        ("time", traj(q0, [up, up], [0.0, 1.0, 1.0]), Result.INVALID, Subcode.INVALID_DATA_TIME, 2, None),
        ("start", traj(off, [up], [0.0, 1.0]), Result.INVALID, Subcode.INVALID_DATA_START_POS, 0, NAMES[7]),
        ("limit", traj(q0, [far, q0], [0.0, 5.0, 10.0]), Result.INVALID, Subcode.INVALID_DATA_POSITION, 1,
         NAMES[4]),
        ("speed", traj(q0, [fast], [0.0, 0.05]), Result.INVALID, Subcode.INVALID_DATA_SPEED, 1, NAMES[0]),
    ]


def test_every_acceptance_rule_rejects_and_the_robot_stays(cell):
    _, _, _, ctl, rec = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    for name, bad, result, subcode, point, joint in bad_trajectories(q0):
        reply = ctl.submit(bad)
        assert (reply.result, reply.subcode) == (result, subcode), (name, reply)
        if point >= 0:
            assert reply.point == point, (name, reply)
        if joint is not None:
            assert reply.joint == joint, (name, reply)
        with pytest.raises(TrajectoryRejected):
            ctl.execute(bad)
    # non-finite values are refused by the controller's wire layer with an error naming the value
    nan = q0.copy()
    nan[5] = np.nan
    with pytest.raises(TrajectoryRejected, match="finite"):
        ctl.execute(traj(q0, [nan], [0.0, 1.0]))
    still_for(rec, q0)


@pytest.mark.parametrize("code, off, subcode", [
    (Command.ESTOP, None, Subcode.NOT_READY_ESTOP),
    (Command.STOP_SERVOS, None, Subcode.NOT_READY_SERVO_OFF),
    (EmulatorCommand.FAULT_ALARM_ON, None, Subcode.NOT_READY_ALARM),
    (Command.HOLD, Command.RESUME, Subcode.NOT_READY_HOLD),
    (EmulatorCommand.PENDANT_REMOTE_OFF, EmulatorCommand.PENDANT_REMOTE_ON, Subcode.NOT_READY_NOT_REMOTE),
    (EmulatorCommand.PENDANT_TEACH, EmulatorCommand.PENDANT_PLAY, Subcode.NOT_READY_NOT_PLAY),
])
def test_not_ready_refuses_with_moto_ros_subcode(cell, code, off, subcode):
    _, _, _, ctl, rec = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    up = q0.copy()
    up[1] += 0.05
    ctl.command(code)
    with pytest.raises(NotReady) as err:
        ctl.execute(traj(q0, [up], [0.0, 1.0]))
    assert (err.value.result, err.value.subcode) == (Result.NOT_READY, subcode)
    still_for(rec, q0, 0.6)
    if off is not None:
        ctl.command(off)
    make_ready(ctl)


def test_queue_full_is_busy(cell):
    _, _, _, ctl, _ = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    try:
        for _ in range(CFG.queue_size):
            ctl.execute(traj(q0, [q0], [0.0, 20.0]))
        reply = ctl.submit(traj(q0, [q0], [0.0, 20.0]))
        assert reply.result == Result.BUSY
    finally:
        ctl.stop()
    assert ctl.wait_status(lambda s: s.queue_count == 0, 10)


def test_accepted_trajectory_is_tracked_at_every_published_state(cell):
    _, _, _, ctl, rec = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    rng = np.random.default_rng(7)
    mid = q0 + rng.uniform(-0.15, 0.15, 13)
    end = q0 + rng.uniform(-0.15, 0.15, 13)
    vel = np.zeros((3, 13))
    vel[1] = (end - q0) / 2.0
    t = traj(q0, [mid, end], [0.0, 1.5, 3.0], vel)
    rec.clear()
    handle = ctl.execute(t)
    assert handle.wait(30) == MotionStatus.SUCCEEDED
    start = start_tick(handle.reply)
    ref = PreparedTrajectory.build(t, start)
    samples = rec.since(start - 5)
    end_tick = start + round(3.0 / PERIOD)
    # the check below saw the robot on its way, not only at rest before and after
    on_the_way = [q for tick, q, _ in samples if start < tick < end_tick
                  and np.abs(q - q0).max() > 0.01 and np.abs(q - end).max() > 0.01]
    assert on_the_way, "no joint state published while the robot moved"
    for tick, q, _ in samples:
        expected, _, _ = ref.evaluate((tick - start) * PERIOD)
        err = np.abs(q - expected).max()
        assert err <= CFG.tracking_tolerance, (tick - start, err)
    np.testing.assert_allclose(ctl.joint_state().positions, end, atol=CFG.goal_tolerance)


def test_estop_stops_within_one_tick_and_refuses_until_reset(cell):
    _, _, _, ctl, rec = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    target = q0.copy()
    target[0] += 0.6
    target[12] -= 0.6
    handle = ctl.execute(traj(q0, [target], [0.0, 10.0]))  # 2.5 s wall: e-stopped on the way
    assert wait_until(lambda: np.abs(ctl.joint_state().velocities).max() > 0.05, 10)
    _, stamp_ns = ctl._send(Command.ESTOP)
    estop_tick = round(stamp_ns / (PERIOD * 1e9))
    assert handle.wait(20) == MotionStatus.ABORTED
    after = states_over(rec, 0.8, estop_tick + 1)
    q_stop = after[0][1]
    for _, q, v in after:
        np.testing.assert_array_equal(q, q_stop)
        assert not v.any()
    up = q_stop.copy()
    up[1] += 0.05
    with pytest.raises(NotReady) as err:
        ctl.execute(traj(q_stop, [up], [0.0, 1.0]))
    assert err.value.subcode == Subcode.NOT_READY_ESTOP
    ctl.command(Command.ESTOP_RESET)
    with pytest.raises(NotReady) as err:  # nothing moves until servos are switched on again
        ctl.execute(traj(q_stop, [up], [0.0, 1.0]))
    assert err.value.subcode == Subcode.NOT_READY_SERVO_OFF
    ctl.command(Command.START_TRAJ_MODE)
    assert ctl.execute(traj(q_stop, [up], [0.0, 1.0])).wait(10) == MotionStatus.SUCCEEDED


def test_a_second_client_cannot_command_while_the_lease_is_held(cell):
    ep, _, _, ctl, rec = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    up = q0.copy()
    up[3] += 0.05
    other_wire = Wire(ep.settings(), "intruder")
    try:
        other = ZenohController(other_wire)
        other.connect(timeout=10)
        with pytest.raises(LeaseHeld) as err:
            other.acquire_lease()
        assert err.value.subcode == Subcode.LEASE_HELD
        with pytest.raises(LeaseHeld):
            other.execute(traj(q0, [up], [0.0, 1.0]))
        with pytest.raises(LeaseHeld):
            other.command(Command.START_SERVOS)
        still_for(rec, q0, 0.6)
        assert ctl.status().lease_holder == "alive/tester"
    finally:
        other_wire.close()


HOLDER = """
import sys, time, numpy as np
from drivers.wire.settings import load_wire_settings
from drivers.wire.transport import Wire
from drivers.controller.zenoh_client import ZenohController
s = load_wire_settings().overridden(cell_id=sys.argv[1], listen=['tcp/127.0.0.1:0'], connect=[sys.argv[2]])
w = Wire(s, 'holder')
c = ZenohController(w)
c.connect(timeout=20)
c.acquire_lease()
from drivers.controller.trajectory import JointTrajectory
q0 = c.joint_state().positions.copy()
q = q0.copy()
q[0] += 0.8
c.execute(JointTrajectory(c.robot_config.joint_names, np.array([0.0, 12.0]), np.stack([q0, q])))
print('moving', flush=True)
time.sleep(60)
"""


def test_killing_the_lease_holder_stops_the_robot(cell):
    ep, _, _, ctl, rec = cell
    make_ready(ctl)
    ctl.release_lease()
    try:
        holder = subprocess.Popen([sys.executable, "-c", HOLDER, ep.cell, ep.url], cwd=REPO,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        try:
            line = holder.stdout.readline().strip()
            assert line == b"moving", holder.stderr.read().decode() if holder.poll() is not None else line
            assert ctl.wait_status(lambda s: s.in_motion and s.lease_holder == "alive/holder", 10)
            holder.send_signal(signal.SIGKILL)
            holder.wait(5)
            st = ctl.wait_status(lambda s: not s.in_motion and s.lease_holder == "", 10)
            assert st is not None, ctl.status()
        finally:
            if holder.poll() is None:
                holder.kill()
                holder.wait()
        # the joint stream and the status are separate keys: take a sample from after the stop
        assert wait_until(lambda: ctl.joint_state().stamp >= st.stamp, 20)
        q = ctl.joint_state().positions.copy()
        still_for(rec, q, 0.6)
    finally:
        ctl.acquire_lease()


def shipped_controller_yaml() -> dict:
    """config/controller.yaml as plain YAML: the timeouts as shipped, not as the loader reads them."""
    return yaml.safe_load((REPO / "config" / "controller.yaml").read_text())


class StampLog:
    """What the controller stamps on its own streams, as it stamps them (wall ns of its ticks): every
    status (stamp, lease holder, lease note, loop stalls) and every joint state's stamp."""

    def __init__(self, wire: Wire):
        self.lock = threading.Lock()
        self.statuses: list[tuple[int, str, str, int]] = []
        self.joint_stamps: list[int] = []
        wire.subscribe("controller/status", self._on_status)
        wire.subscribe("controller/joint_states", self._on_joint_state)

    def _on_status(self, key, msg, raw) -> None:
        with self.lock:
            self.statuses.append((messages.stamp_to_ns(msg.header.stamp), msg.lease_holder, msg.lease_note,
                                  int(msg.loop_stalls)))

    def _on_joint_state(self, key, msg, raw) -> None:
        with self.lock:
            self.joint_stamps.append(messages.stamp_to_ns(msg.header.stamp))

    def status_list(self) -> list[tuple[int, str, str, int]]:
        with self.lock:
            return sorted(self.statuses)

    def stalled_s(self, first_ns: int, last_ns: int, period: float, stall: float) -> float:
        """How long (s) the controller's loop could not run between two of its stamps, as the joint
        states (one per loop) show it: every stamp gap past a stall's threshold, less one period. A
        sample lost on the way only makes this larger (a looser bound, never a false failure)."""
        with self.lock:
            stamps = sorted(t for t in self.joint_stamps if first_ns <= t <= last_ns)
        gaps = np.diff(np.array(stamps, dtype=np.int64)) * 1e-9
        return float(np.sum(gaps[gaps > period + stall / 2] - period))


def test_the_lease_goes_to_live_sessions_only_and_a_silent_holder_loses_it(cell):
    """The lease follows a live session: a name with no liveliness token is refused it; a holder whose
    token stays but who sends nothing (a hung process) loses it after the silence timeout of
    config/controller.yaml (read here as plain YAML), the status saying why; the client's renewals
    keep a live holder's through two silence timeouts.

    Every bound is taken on the controller's own stamps, so a slow machine cannot fail it: the first
    status naming the hung holder (stamped on the loop after its acquire) and the first that names no
    holder (stamped on the loop that dropped it) lie the timeout apart, give or take one loop that is
    late by less than `server.stall` (the loop's own stall is not counted against the holder: the
    time its joint-state stamps show it could not run is allowed on top)."""
    ep, _, wire, ctl, _ = cell
    shipped = shipped_controller_yaml()
    silence = float(shipped["lease"]["silence_timeout"])
    period = 1.0 / float(shipped["feedback_rate"])
    stall = float(shipped["server"]["stall"])
    slack = period + stall + 0.01   # one loop late by less than a stall, and a tick's rounding
    watcher = Wire(ep.settings(), "watcher")
    hung = Wire(ep.settings(), "hung")   # a session with a token, that will not renew
    try:
        stamps = StampLog(watcher)
        assert wait_until(lambda: stamps.status_list(), 30), "no status reached the watcher"
        since = stamps.status_list()[-1][0]
        # renewing: the controller's statuses over two silence timeouts of its own stamps name the holder
        assert wait_until(lambda: stamps.status_list()[-1][0] >= since + 2 * silence * 1e9, 2 * silence + 60)
        renewing = [s for s in stamps.status_list() if s[0] >= since]
        assert {holder for _, holder, _, _ in renewing} == {"alive/tester"}, renewing
        ctl.release_lease()
        for name, where in (("alive/ghost", wire), ("alive/hung", hung)):
            reply = where.request("controller/command", codec.command_msg(Command.LEASE_ACQUIRE, name),
                                  timeout=5, sign=Signer(name).attachment)
            if name == "alive/ghost":
                assert reply.result == Result.FAILURE and reply.subcode == Subcode.NO_LEASE, reply.text
                assert "no liveliness token" in reply.text
                assert ctl.status().lease_holder == ""
            else:
                assert reply.result == 0, reply.text

        def held_then_dropped() -> tuple[tuple, tuple] | None:
            statuses = stamps.status_list()
            held = next((i for i, s in enumerate(statuses) if s[1] == "alive/hung"), None)
            if held is None:
                return None
            dropped = next((s for s in statuses[held:] if s[1] == ""), None)
            return None if dropped is None else (statuses[held], dropped)

        # a deadline only for a controller that never drops it: the bounds below are on its stamps
        assert wait_until(held_then_dropped, 2 * silence + 60), f"a silent holder kept it: {ctl.status()}"
        (held_ns, _, _, stalls_held), (dropped_ns, _, note, stalls_dropped) = held_then_dropped()
        lapse = (dropped_ns - held_ns) * 1e-9
        stalled = stamps.stalled_s(held_ns, dropped_ns, period, stall)
        evidence = (f"held at {held_ns}, dropped at {dropped_ns} (controller stamps): {lapse:.3f} s after; "
                    f"timeout {silence} s; loop stalled {stalled:.3f} s ({stalls_dropped - stalls_held} "
                    f"stalls counted); note {note!r}")
        assert lapse >= silence - slack, "the lease went before the silence timeout: " + evidence
        assert lapse <= silence + slack + stalled, "the lease went late: " + evidence
        stated = re.search(r"alive/hung sent nothing for ([0-9.]+) s", note)
        assert stated is not None and "hung process" in note, note
        assert silence <= float(stated[1]) <= silence + slack + 0.05, note   # + the note's rounding
    finally:
        hung.close()
        watcher.close()
        ctl.acquire_lease()


def hold_the_interpreter(seconds: float) -> float:
    """Keep this interpreter's GIL for at least `seconds` (one C call that never lets another Python
    thread run); returns how long no other thread ran (measured by a ticker thread)."""
    ticks: list[float] = []
    running = threading.Event()

    def ticker() -> None:
        while not running.is_set():
            ticks.append(time.monotonic())
            time.sleep(0.001)

    side = threading.Thread(target=ticker, daemon=True)
    side.start()
    time.sleep(0.05)
    n = 10_000_000
    started = time.perf_counter()
    sum(range(n))   # how fast this machine sums, now
    per_second = n / max(time.perf_counter() - started, 1e-6)
    margin = 2.0
    for _ in range(4):
        # a busy machine sums at another pace than it was timed at: hold again, longer, until long enough
        sum(range(int(per_second * seconds * margin)))
        time.sleep(0.05)
        if float(np.max(np.diff(ticks))) >= seconds:
            break
        margin *= 2
    running.set()
    side.join()
    return float(np.max(np.diff(ticks)))


def test_a_holder_whose_interpreter_is_busy_for_a_second_keeps_the_lease_and_its_motion(cell):
    """The lease's heartbeat is the holder's liveliness token, kept by Zenoh's own threads: an
    interpreter held for over a second (a perception or planning step that keeps the GIL) neither loses
    the lease nor stops the motion it started."""
    _, _, _, ctl, _ = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    target = q0.copy()
    target[0] += 0.4
    handle = ctl.move_to(target)
    assert ctl.wait_status(lambda s: s.in_motion, 10)
    before = ctl.status().stamp
    blocked = hold_the_interpreter(1.0)
    assert blocked >= 1.0, f"the test held the interpreter for {blocked:.2f} s only"
    # a status the controller published after the hold (robot time past it)
    status = ctl.wait_status(lambda s: s.stamp > before + K * blocked, 10)
    assert status is not None and status.lease_holder == "alive/tester" and not status.lease_note, status
    assert handle.wait(30) == MotionStatus.SUCCEEDED
    assert ctl.status().lease_holder == "alive/tester"
    ctl.move_to(q0).wait(30)


def test_naming_the_lease_holder_without_its_credential_moves_nothing(cell):
    """A stranger writes the holder's name (`alive/tester`) into its requests, with no credential, the name
    alone or a signature by a key of its own: every motion and the lease itself are refused, the robot stays
    still, the holder keeps the lease."""
    ep, _, _, ctl, rec = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    target = q0.copy()
    target[0] += 0.05
    stranger = Wire(ep.settings(), "stranger")
    try:
        for sign in (None, lambda _key, _payload: b"alive/tester", Signer("alive/tester").attachment):
            for msg in (codec.command_msg(Command.MOVE_TO, "alive/tester", values=target),
                        codec.command_msg(Command.JOG, "alive/tester", joint=NAMES[0], values=(0.05,)),
                        codec.command_msg(Command.LEASE_RELEASE, "alive/tester")):
                reply = request_once_served(stranger, "controller/command", msg, timeout=5, sign=sign)
                assert reply.result != Result.SUCCESS, (sign, reply.text)
            motion = traj(q0, [target], [0.0, 1.0])
            reply = request_once_served(stranger, "controller/trajectory", codec.trajectory_msg(motion),
                                        timeout=5, sign=sign)
            assert reply.result != Result.SUCCESS, (sign, reply.text)
        still_for(rec, q0, 0.8)
        assert ctl.status().lease_holder == "alive/tester"
        ctl.move_to(q0).wait(30)  # the real holder still commands
    finally:
        stranger.close()


@pytest.mark.parametrize("key, type_name, reply_type", [
    ("controller/trajectory", "trajectory_msgs/msg/JointTrajectory", "foldcell_msgs/msg/MotionReply"),
    ("controller/command", "foldcell_msgs/msg/ControllerCommand", "foldcell_msgs/msg/MotionReply"),
])
def test_random_bytes_get_an_error_reply_and_the_stream_goes_on(cell, key, type_name, reply_type):
    _, proc, wire, ctl, rec = cell
    rng = np.random.default_rng(11)
    for size in (0, 1, 7, 64, 999):
        with pytest.raises(ErrorReply):
            wire.request_raw(wire.key(key), rng.bytes(size), type_name, reply_type, timeout=5)
    rec.clear()
    states_over(rec, 0.8)
    assert proc.popen.poll() is None
    ctl.command(Command.CHECK_MOTION_READY) if ctl.status().motion_possible else None


def oversize_trajectory(points: int) -> bytes:
    """A well-formed trajectory of `points` points: without the size check it would decode (slowly)."""
    point = messages.new("trajectory_msgs/msg/JointTrajectoryPoint", positions=np.zeros(len(NAMES)),
                         velocities=np.zeros(len(NAMES)), accelerations=np.zeros(len(NAMES)))
    msg = messages.new("trajectory_msgs/msg/JointTrajectory", header=messages.header(),
                       joint_names=list(NAMES), points=[point] * points)
    return messages.encode("trajectory_msgs/msg/JointTrajectory", msg)


def test_an_oversize_trajectory_is_refused_undecoded_and_the_stream_goes_on(cell):
    _, proc, wire, _, rec = cell
    limit = payload_limit("trajectory_msgs/msg/JointTrajectory")
    payload = oversize_trajectory(20_000)  # 100 x the most points; 4.7 MB, under Zenoh's own limit
    assert len(payload) > 40 * limit
    rec.clear()
    started = time.monotonic()
    with pytest.raises(ErrorReply) as refused:
        wire.request_raw(wire.key("controller/trajectory"), payload, "trajectory_msgs/msg/JointTrajectory",
                         "foldcell_msgs/msg/MotionReply", timeout=30)
    assert f"payload of {len(payload)} bytes is over the limit of {limit} bytes" in refused.value.remote
    assert "not decoded" in refused.value.remote
    states_over(rec, 0.8)  # the stream kept coming through the refusal and after it
    elapsed = time.monotonic() - started
    assert len(rec.since(0)) >= 0.5 * CFG.feedback_rate * elapsed, (len(rec.since(0)), elapsed)
    assert proc.popen.poll() is None


def test_a_128_mb_payload_is_dropped_by_zenoh_and_the_stream_goes_on(cell):
    """Above Zenoh's own limit (config/zenoh/peer.json5) the message never reaches the controller: the
    asker hears nothing, the joint stream goes on, the next request is answered."""
    _, proc, wire, ctl, rec = cell
    payload = bytes(128 * 1024 * 1024)
    counted = threading.Event()
    during: list[int] = []

    def count_states() -> None:
        rec.clear()
        counted.wait(60)
        during.append(len(rec.since(0)))

    counter = threading.Thread(target=count_states)
    counter.start()
    started = time.monotonic()
    try:
        with pytest.raises(NoReply):
            wire.request_raw(wire.key("controller/trajectory"), payload,
                             "trajectory_msgs/msg/JointTrajectory", "foldcell_msgs/msg/MotionReply",
                             timeout=5)
    finally:
        elapsed = time.monotonic() - started
        counted.set()
        counter.join()
    assert during[0] >= 0.5 * CFG.feedback_rate * elapsed, (during, elapsed)
    assert ctl.status() is not None
    assert proc.popen.poll() is None


def test_an_estop_is_answered_ahead_of_a_flood_of_commands(cell):
    """Every command of the flood takes 20 ms (an injected reply latency): in one queue the e-stop would
    wait for all of them; it is answered while most are still waiting."""
    _, _, wire, ctl, _ = cell
    make_ready(ctl)
    flood = 100
    ctl.command(EmulatorCommand.FAULT_REPLY_LATENCY_ON, values=(0.02, 0.0))
    try:
        _latency, answered_before, answered = flood_then_estop(wire, flood)
    finally:
        ctl.command(EmulatorCommand.FAULT_REPLY_LATENCY_OFF)
    assert answered == flood
    assert answered_before < flood // 2, answered_before
    make_ready(ctl)


def test_cli_status_and_errors(cell):
    ep, _, _, _, _ = cell
    flags = ["--cell", ep.cell, "--listen", "tcp/127.0.0.1:0", "--connect", ep.url]
    out = subprocess.run(foldcell_argv("controller", "status", "--json", *flags), cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert '"lease_holder": "alive/tester"' in out.stdout
    out = subprocess.run(foldcell_argv("controller", "servo", "off", *flags), cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 1 and "foldcell: error:" in out.stderr and "lease" in out.stderr
    out = subprocess.run(foldcell_argv("controller", "fault", "slow-loop", "on", *flags), cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2 and "takes 1 value" in out.stderr


def test_gripper_state_carries_the_tcp_pose_in_world(cell):
    from scipy.spatial.transform import Rotation

    from drivers.robot.kinematics import CellKinematics

    _, _, wire, ctl, _ = cell
    make_ready(ctl)
    got: dict[str, object] = {}
    wire.subscribe("controller/gripper/*", lambda key, msg, raw: got.__setitem__(msg.arm, msg))
    for arm in ("r1", "r2"):
        ctl.grip(arm, True)
    assert wait_until(lambda: all(a in got and got[a].closed for a in ("r1", "r2")), 10)
    kin = CellKinematics(RC)
    q = ctl.joint_state().positions
    for arm in ("r1", "r2"):
        msg = got[arm]
        pose = kin.tcp_pose(q, arm)
        p = msg.tcp_pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], pose[:3, 3], atol=1e-6)
        o = msg.tcp_pose.orientation
        rot = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
        np.testing.assert_allclose(rot, pose[:3, :3], atol=1e-6)
        assert msg.header.frame_id == "world" and msg.opening == 0.0
    ctl.grip("r1", False)
    assert wait_until(lambda: not got["r1"].closed and got["r1"].opening > 0, 10)
    with pytest.raises(ControllerError, match="arm"):
        ctl.grip("r9", True)


def test_a_gripper_change_is_posed_where_the_arm_stood_though_the_loop_runs_late(cell):
    """A grip followed at once by a motion, the loop 100 ms late: the change is told where the arm stood
    when the gripper acted (forward kinematics of the rest pose) and stamped before the motion began,
    not where the motion had taken the arm by the loop's next turn."""
    from drivers.robot.kinematics import CellKinematics

    _, _, wire, ctl, rec = cell
    make_ready(ctl)
    ctl.grip("r1", False)
    heard: list = []
    wire.subscribe("controller/gripper/r1", lambda key, msg, raw: heard.append(msg))
    q0 = ctl.joint_state().positions.copy()
    q1 = q0.copy()
    q1[RC.joint_names.index("r1_joint_s")] += 0.3
    rest = CellKinematics(RC).tcp_pose(q0, "r1")[:3, 3]
    ctl.command(EmulatorCommand.FAULT_SLOW_LOOP_ON, values=(25.0,))
    try:
        assert ctl.wait_status(lambda s: "slow_loop" in s.faults, 20)
        ctl.grip("r1", True)
        motion = ctl.execute(traj(q0, [q1], [0.0, 1.0]))
        assert motion.wait(30) == MotionStatus.SUCCEEDED
    finally:
        ctl.command(EmulatorCommand.FAULT_SLOW_LOOP_OFF)
    closing = next(msg for msg in heard if msg.closed)
    p = closing.tcp_pose.position
    np.testing.assert_allclose([p.x, p.y, p.z], rest, atol=1e-6)
    assert rec.timebase is not None
    tick = round(rec.timebase.robot(messages.stamp_to_ns(closing.header.stamp)) / (PERIOD * 1e9))
    assert tick <= start_tick(motion.reply)
    ctl.grip("r1", False)
    assert ctl.move_to(q0).wait(30) == MotionStatus.SUCCEEDED


def test_cli_drives_the_robot(cell, tmp_path):
    ep, _, _, ctl, _ = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    q1 = q0.copy()
    q1[2] += 0.05
    path = tmp_path / "t.yaml"
    path.write_text("points:\n"
                    f"  - {{time: 0.0, positions: {q0.tolist()}}}\n"
                    f"  - {{time: 1.0, positions: {q1.tolist()}}}\n")
    flags = ["--cell", ep.cell, "--listen", "tcp/127.0.0.1:0", "--connect", ep.url]
    ctl.release_lease()
    try:
        out = subprocess.run(foldcell_argv("controller", "send", str(path), "--json", *flags), cwd=REPO,
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 0, out.stderr
        assert '"motion": "succeeded"' in out.stdout
        np.testing.assert_allclose(ctl.joint_state().positions, q1, atol=CFG.goal_tolerance)
        out = subprocess.run(foldcell_argv("controller", "jog", "r1_joint_x", "0.1", *flags), cwd=REPO,
                             capture_output=True, text=True, timeout=60)
        # an unknown joint is bad input (exit 2), told before connecting
        assert out.returncode == 2 and "foldcell: error: joint: must be one of" in out.stderr
        path.write_text("points: []\n")
        out = subprocess.run(foldcell_argv("controller", "send", str(path), *flags), cwd=REPO,
                             capture_output=True, text=True, timeout=60)
        assert out.returncode == 2 and "points" in out.stderr and "Traceback" not in out.stderr
    finally:
        ctl.acquire_lease()


def test_fault_injection_commands(cell):
    _, _, _, ctl, rec = cell
    make_ready(ctl)
    ctl.command(EmulatorCommand.FAULT_FREEZE_FEEDBACK_ON)
    try:
        assert ctl.wait_status(lambda s: "freeze_feedback" in s.faults, 20)
        # states stamped before the freeze may still be on their way: wait for the repeats
        def repeating() -> bool:
            last = rec.since(0)[-6:]
            return len(last) == 6 and len({s[0] for s in last}) == 1

        assert wait_until(repeating, 10), "the stream does not repeat one state"
        rec.clear()
        assert wait_until(lambda: len(rec.since(0)) > 5, 10), "the frozen stream stopped"
        frozen = rec.since(0)
        assert len({s[0] for s in frozen}) == 1  # the same sample repeated
    finally:
        ctl.command(EmulatorCommand.FAULT_FREEZE_FEEDBACK_OFF)
    ctl.command(EmulatorCommand.FAULT_REPLY_LATENCY_ON, values=(0.3, 0.05))
    try:
        t = time.monotonic()
        ctl.command(Command.CHECK_MOTION_READY)
        assert time.monotonic() - t >= 0.3
    finally:
        ctl.command(EmulatorCommand.FAULT_REPLY_LATENCY_OFF)
    with pytest.raises(ControllerError, match="factor"):
        ctl.command(EmulatorCommand.FAULT_SLOW_LOOP_ON, values=(0.5,))
    ctl.command(EmulatorCommand.FAULT_SLOW_LOOP_ON, values=(2.0,))
    try:
        assert ctl.wait_status(lambda s: "slow_loop" in s.faults, 20)
        rec.clear()
        ticks = [s[0] for s in states_over(rec, 0.4)]
        # robot time still advances
        assert all(b > a for a, b in itertools.pairwise(ticks))
    finally:
        ctl.command(EmulatorCommand.FAULT_SLOW_LOOP_OFF)
    assert not ctl.wait_status(lambda s: not s.faults, 20).faults


def test_two_queued_trajectories_both_succeed(cell):
    _, _, _, ctl, _ = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    q1, q2 = q0.copy(), q0.copy()
    q1[0] += 0.05
    q2[0] += 0.1
    first = ctl.execute(traj(q0, [q1], [0.0, 1.0]))
    second = ctl.execute(traj(q1, [q2], [0.0, 2.0]))
    # queued: the second starts once the first has run its 1 s
    assert start_tick(second.reply) >= start_tick(first.reply) + round(1.0 / PERIOD)
    assert first.wait(20) == MotionStatus.SUCCEEDED
    assert second.wait(20) == MotionStatus.SUCCEEDED
    np.testing.assert_allclose(ctl.joint_state().positions, q2, atol=CFG.goal_tolerance)


def test_move_to_and_jog_plan_jerk_limited_motions(cell):
    _, _, _, ctl, rec = cell
    make_ready(ctl)
    q0 = ctl.joint_state().positions.copy()
    target = q0.copy()
    target[[1, 7, 12]] += (0.1, -0.1, 0.05)
    rec.clear()
    assert ctl.move_to(target).wait(20) == MotionStatus.SUCCEEDED
    np.testing.assert_allclose(ctl.joint_state().positions, target, atol=CFG.goal_tolerance)
    v = np.array([s[2] for s in rec.since(0)])
    assert (np.abs(v) <= RC.max_velocity * (1 + 1e-6)).all() and np.abs(v).max() > 0
    assert ctl.jog("r2_joint_t", -0.05).wait(20) == MotionStatus.SUCCEEDED
    assert ctl.joint_state().positions[11] == pytest.approx(target[11] - 0.05, abs=CFG.goal_tolerance)
    with pytest.raises(TrajectoryRejected) as err:
        ctl.move_to(np.full(13, 100.0))
    assert err.value.subcode == Subcode.INVALID_DATA_POSITION
