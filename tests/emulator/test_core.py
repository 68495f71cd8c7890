"""The emulator core: following, limits, e-stop, stop, hold/resume, alarms, move_to, lease, faults."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from drivers.controller.codes import Alarm, Command, Mode, Result, Subcode
from drivers.controller.config import default_controller_config
from drivers.controller.motion import plan_point_to_point
from drivers.controller.trajectory import JointTrajectory, sample
from drivers.emulator.commands import EmulatorCommand
from drivers.emulator.core import ControllerCore
from drivers.emulator.motion import PreparedTrajectory
from drivers.robot.config import default_robot_config

RC = default_robot_config()
CFG = default_controller_config()
N = len(RC.joint_names)
DT = CFG.interpolation_period
ME = "session-a"


def ready_core(role: str = "both", cfg=CFG, q0=None) -> ControllerCore:
    core = ControllerCore(RC, cfg, role, initial_position=q0)
    assert core.command(Command.LEASE_ACQUIRE, ME).ok
    assert core.command(Command.START_TRAJ_MODE, ME).ok
    return core


def planned(start, target, fraction=0.8):
    return plan_point_to_point(start, target, RC.max_velocity * fraction, RC.max_acceleration * fraction,
                               RC.max_jerk * fraction, CFG.max_points)


def trajectory(times, positions, velocities) -> JointTrajectory:
    """Over every joint, project order."""
    return JointTrajectory(RC.joint_names, np.asarray(times, dtype=float), np.asarray(positions, dtype=float),
                           velocities)


def run(core: ControllerCore, ticks: int):
    return [core.step() for _ in range(ticks)]


def random_trajectory(rng, core):
    """Random via points and velocities, slowed down in 15 % steps until accepted (so near the limits)."""
    k = int(rng.integers(2, 7))
    pos = np.empty((k, N))
    pos[0] = core.q
    span = RC.upper - RC.lower
    for i in range(1, k):
        pos[i] = np.clip(pos[i - 1] + rng.normal(scale=0.15, size=N) * span / 4, RC.lower + 0.05,
                         RC.upper - 0.05)
    vel = np.zeros((k, N))
    vel[1:-1] = rng.uniform(-0.5, 0.5, size=(k - 2, N)) * RC.max_velocity
    times = np.r_[0.0, np.cumsum(rng.uniform(0.05, 0.3, size=k - 1))]
    for _ in range(60):
        if core.check(trajectory(times, pos, vel), ME).ok:
            return times, pos, vel
        times, vel = times * 1.15, vel / 1.15
    return None


def test_accepted_trajectory_is_followed():
    core = ready_core()
    t, p, v = planned(core.q, np.linspace(-0.5, 0.7, N))
    assert core.submit(trajectory(t, p, v), ME).ok
    start = core.tick + 1
    ticks = int(np.ceil(t[-1] / DT)) + 2
    worst = 0.0
    for fb in run(core, ticks):
        ref, _, _ = sample(t, p, v, (round(fb.stamp / DT) - start) * DT)
        worst = max(worst, float(np.abs(fb.positions - ref).max()))
    assert worst <= CFG.tracking_tolerance
    assert np.allclose(core.q, p[-1]) and not core.status().in_motion
    assert np.all(core.v == 0)


def test_zero_velocity_trajectory_stops_at_each_point():
    core = ready_core()
    t = np.array([0.0, 1.0, 2.0])
    p = np.zeros((3, N))
    p[1] = 0.2
    p[2] = 0.1
    assert core.submit(trajectory(t, p, None), ME).ok
    fbs = run(core, int(2.0 / DT) + 3)
    at_1s = fbs[round(1.0 / DT)]  # tick start+250 is the stamp of point 1
    assert np.allclose(at_1s.positions, 0.2, atol=1e-9) and np.allclose(at_1s.velocities, 0, atol=1e-9)


def test_rejected_trajectory_never_moves():
    core = ready_core()
    t = np.array([0.0, 0.1])
    p = np.zeros((2, N))
    p[1, 0] = 3.0  # too fast and outside the limits
    reply = core.submit(trajectory(t, p, None), ME)
    assert not reply.ok
    q0 = core.q.copy()
    run(core, 100)
    assert np.array_equal(core.q, q0) and core.queue_count == 0 and not core.status().in_motion


def check_limits(fbs, tol=1e-6, fd_tol=0.02):
    """Reported and finite-difference velocity/acceleration stay inside the limits."""
    q = np.array([fb.positions for fb in fbs])
    v = np.array([fb.velocities for fb in fbs])
    a = np.array([fb.accelerations for fb in fbs])
    assert (q >= RC.lower - 1e-9).all() and (q <= RC.upper + 1e-9).all()
    assert (np.abs(v) <= RC.max_velocity * (1 + tol)).all()
    assert (np.abs(a) <= RC.max_acceleration * (1 + tol)).all()
    if len(q) > 2:
        assert (np.abs(np.diff(q, axis=0)) / DT <= RC.max_velocity * (1 + fd_tol)).all()
        assert (np.abs(np.diff(v, axis=0)) / DT <= RC.max_acceleration * (1 + fd_tol)).all()


def test_limits_never_exceeded_random_trajectories_with_interruptions():
    rng = np.random.default_rng(7)
    accepted = 0
    for trial in range(40):
        core = ready_core()
        traj = random_trajectory(rng, core)
        if traj is None:
            continue
        t, p, v = traj
        assert core.submit(trajectory(t, p, v), ME).ok
        accepted += 1
        ticks = int(t[-1] / DT) + 3
        event_tick = int(rng.integers(1, ticks))
        action = trial % 3  # 0 run through, 1 hold + resume, 2 stop
        fbs = run(core, event_tick)
        if action == 1:
            core.command(Command.HOLD, ME)
            fbs += run(core, 200)
            core.command(Command.RESUME, ME)
        elif action == 2:
            core.command(Command.STOP_MOTION, ME)
        fbs += run(core, ticks + 400)
        check_limits(fbs)
        assert core.alarm_code == 0, core.alarm_text
        assert not core.status().in_motion
        if action != 2:
            assert np.allclose(core.q, p[-1])
    assert accepted >= 30


def test_estop_stops_within_one_tick_and_refuses_motion_until_reset_and_servo_on():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.6))
    assert core.submit(trajectory(t, p, v), ME).ok
    run(core, 60)
    assert np.abs(core.v).max() > 0.1
    q_at = core.q.copy()
    assert core.command(Command.ESTOP, "anyone").ok  # e-stop needs no lease
    fb = core.step()
    assert np.array_equal(fb.positions, q_at) and np.all(fb.velocities == 0)
    run(core, 50)
    assert np.array_equal(core.q, q_at)
    st = core.status()
    assert st.e_stopped and not st.drives_powered and not st.motion_possible and not st.in_motion
    t2, p2, v2 = planned(core.q, np.zeros(N))
    r = core.submit(trajectory(t2, p2, v2), ME)
    assert r.result == Result.NOT_READY and r.subcode == Subcode.NOT_READY_ESTOP
    assert core.command(Command.START_TRAJ_MODE, ME).subcode == Subcode.NOT_READY_ESTOP
    assert core.command(Command.ESTOP_RESET, ME).ok
    r = core.submit(trajectory(t2, p2, v2), ME)  # no automatic servo on (the old driver's bug)
    assert r.result == Result.NOT_READY and r.subcode == Subcode.NOT_READY_SERVO_OFF
    run(core, 10)
    assert np.array_equal(core.q, q_at)
    assert core.command(Command.START_TRAJ_MODE, ME).ok
    assert core.submit(trajectory(t2, p2, v2), ME).ok
    run(core, int(t2[-1] / DT) + 3)
    assert np.allclose(core.q, 0)


def test_stop_decelerates_within_limits_on_the_path_and_drops_the_queue():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.8), fraction=0.99)  # close to the limits
    assert core.submit(trajectory(t, p, v), ME).ok
    t2, p2, v2 = planned(p[-1], np.zeros(N))
    assert core.submit(trajectory(t2, p2, v2), ME).ok
    assert core.queue_count == 2
    fbs = run(core, int(t[-1] / DT / 2))
    assert core.command(Command.STOP_MOTION, ME).ok
    stop_fbs = run(core, 200)
    check_limits(fbs + stop_fbs)
    assert core.queue_count == 0 and not core.status().in_motion and np.all(core.v == 0)
    # it stopped on the accepted path, between where it was and the goal
    dense, _, _ = sample(t, p, v, np.linspace(0, t[-1], 20001))
    assert np.abs(dense - core.q).max(axis=1).min() < 1e-3
    assert not np.allclose(core.q, p[-1], atol=1e-3)
    q_stop = core.q.copy()
    run(core, 100)
    assert np.array_equal(core.q, q_stop)


def test_hold_pauses_and_resume_continues():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, -0.5))
    assert core.submit(trajectory(t, p, v), ME).ok
    fbs = run(core, 50)
    assert core.command(Command.HOLD, ME).ok
    fbs += run(core, 150)
    st = core.status()
    assert st.held and not st.in_motion and st.queue_count == 1
    q_held = core.q.copy()
    fbs += run(core, 100)
    assert np.array_equal(core.q, q_held)
    r = core.submit(trajectory(t, p, v), ME)
    assert r.subcode == Subcode.NOT_READY_HOLD
    assert core.command(Command.RESUME, ME).ok
    fbs += run(core, int(t[-1] / DT) + 200)
    check_limits(fbs)
    assert np.allclose(core.q, p[-1]) and core.queue_count == 0


def test_alarm_aborts_with_smooth_stop_and_refuses_motion_until_reset():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.5))
    assert core.submit(trajectory(t, p, v), ME).ok
    fbs = run(core, 80)
    assert core.command(EmulatorCommand.FAULT_ALARM_ON, ME).ok
    fbs += run(core, 200)
    check_limits(fbs)
    st = core.status()
    assert st.in_error and st.error_code == Alarm.INJECTED and not st.in_motion and st.queue_count == 0
    assert not np.allclose(core.q, p[-1], atol=1e-3)
    t2, p2, v2 = planned(core.q, np.zeros(N))
    r = core.submit(trajectory(t2, p2, v2), ME)
    assert r.result == Result.NOT_READY and r.subcode == Subcode.NOT_READY_ALARM
    assert core.command(Command.RESET_ALARM, ME).ok
    assert not core.status().in_error
    assert core.submit(trajectory(t2, p2, v2), ME).ok


def test_move_to_reaches_target_within_limits_synchronised():
    rng = np.random.default_rng(11)
    for _ in range(8):
        core = ready_core()
        target = rng.uniform(RC.lower * 0.8, RC.upper * 0.8)
        r = core.command(Command.MOVE_TO, ME, values=target.tolist())
        assert r.ok, r
        fbs = run(core, 2000)
        check_limits(fbs)
        assert np.allclose(core.q, target, atol=1e-9)
        v = np.array([fb.velocities for fb in fbs])
        moving = np.abs(v) > 1e-9
        last = [int(np.nonzero(moving[:, j])[0].max()) for j in range(N) if moving[:, j].any()]
        assert max(last) - min(last) <= 1  # all axes finish on the same tick


def test_move_to_rejects_bad_targets():
    core = ready_core()
    r = core.move_to(np.full(N - 1, 0.1), ME)
    assert r.result == Result.INVALID and r.subcode == Subcode.BAD_ARGUMENT
    bad = np.zeros(N)
    bad[3] = 10.0
    r = core.move_to(bad, ME)
    assert r.subcode == Subcode.INVALID_DATA_POSITION and r.joint == RC.joint_names[3]
    assert r.text.startswith(f"move_to: {RC.joint_names[3]} target 10.000000 rad is outside")


def test_move_to_where_the_queue_ends_is_done_at_once():
    core = ready_core()
    r = core.move_to(core.q, ME)
    assert r.ok and r.text == "move_to: already at the target" and core.queue_count == 0
    r = core.command(Command.JOG, ME, joint="r1_joint_s", values=[0.0])
    assert r.ok and r.text == "jog: already at the target"
    # the lease and readiness come before: a session without the lease is refused, not told "done"
    assert core.move_to(core.q, "other").subcode == Subcode.LEASE_HELD


def test_lease_one_commander():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.3))
    r = core.submit(trajectory(t, p, v), "session-b")
    assert r.result == Result.FAILURE and r.subcode == Subcode.LEASE_HELD and ME in r.text
    assert core.command(Command.LEASE_ACQUIRE, "session-b").subcode == Subcode.LEASE_HELD
    assert core.command(Command.HOLD, "session-b").subcode == Subcode.LEASE_HELD
    assert core.command(Command.GRIP_CLOSE, "session-b", arm="r1").subcode == Subcode.LEASE_HELD
    assert core.command(Command.LEASE_RELEASE, "session-b").subcode == Subcode.NO_LEASE
    assert core.submit(trajectory(t, p, v), ME).ok
    run(core, 60)
    assert core.status().in_motion
    core.lease_lost(ME)  # the holder's liveliness token vanished
    run(core, 200)
    st = core.status()
    assert not st.in_motion and st.lease_holder == "" and st.queue_count == 0
    assert core.submit(trajectory(t, p, v), ME).subcode == Subcode.NO_LEASE
    assert core.command(Command.LEASE_ACQUIRE, "session-b").ok


def test_grippers_per_arm():
    core = ready_core()
    assert core.grippers == {"r1": False, "r2": False}
    assert core.command(Command.GRIP_CLOSE, ME, arm="r1").ok
    assert core.grippers == {"r1": True, "r2": False}
    assert core.command(Command.GRIP_OPEN, ME, arm="r1").ok
    assert core.command(Command.GRIP_CLOSE, ME, arm="r3").subcode == Subcode.BAD_ARGUMENT
    master = ready_core("master")
    assert list(master.grippers) == ["r1"]
    assert master.command(Command.GRIP_CLOSE, ME, arm="r2").subcode == Subcode.BAD_ARGUMENT


def test_queue_start_tick_and_busy():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.2))
    t2, p2, v2 = planned(p[-1], np.zeros(N))
    assert core.submit(trajectory(t, p, v), ME, start_tick=core.tick + 50).ok
    run(core, 49)
    assert np.all(core.q == 0)
    run(core, 2)
    assert np.abs(core.q).max() > 0
    # a queued trajectory must start where the queue ends
    assert core.submit(trajectory(t, p, v), ME).subcode == Subcode.INVALID_DATA_START_POS
    legs = [(t2, p2, v2), (t, p, v)]  # back and forth, each starting where the queue ends
    for i in range(CFG.queue_size - 1):
        tt, pp, vv = legs[i % 2]
        assert core.submit(trajectory(tt, pp, vv), ME).ok
    assert core.queue_count == CFG.queue_size
    tt, pp, vv = legs[(CFG.queue_size - 1) % 2]
    assert core.submit(trajectory(tt, pp, vv), ME).result == Result.BUSY
    assert core.command(Command.CHECK_QUEUE_CNT, ME).subcode == CFG.queue_size
    run(core, 3000)
    assert core.queue_count == 0


def test_readiness_modes_via_pendant():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.2))
    core.command(EmulatorCommand.PENDANT_TEACH, ME)
    assert core.status().mode == Mode.MANUAL
    assert core.submit(trajectory(t, p, v), ME).subcode == Subcode.NOT_READY_NOT_PLAY
    core.command(EmulatorCommand.PENDANT_PLAY, ME)
    core.command(EmulatorCommand.PENDANT_REMOTE_OFF, ME)
    assert core.submit(trajectory(t, p, v), ME).subcode == Subcode.NOT_READY_NOT_REMOTE
    core.command(EmulatorCommand.PENDANT_REMOTE_ON, ME)
    core.command(Command.STOP_TRAJ_MODE, ME)
    assert core.submit(trajectory(t, p, v), ME).subcode == Subcode.NOT_READY_NOT_STARTED
    core.command(Command.STOP_SERVOS, ME)
    assert core.submit(trajectory(t, p, v), ME).subcode == Subcode.NOT_READY_SERVO_OFF
    core.command(Command.START_SERVOS, ME)
    assert core.command(Command.CHECK_MOTION_READY, ME).subcode == Subcode.NOT_READY_NOT_STARTED
    core.command(Command.START_TRAJ_MODE, ME)
    assert core.command(Command.CHECK_MOTION_READY, ME).ok
    assert core.submit(trajectory(t, p, v), ME).ok


def test_unknown_command_and_fault_arguments():
    core = ready_core()
    assert core.command(123456, ME).subcode == Subcode.INVALID_COMMAND
    latency_on = EmulatorCommand.FAULT_REPLY_LATENCY_ON
    assert core.command(latency_on, ME, values=[0.1]).subcode == Subcode.BAD_ARGUMENT
    assert core.command(EmulatorCommand.FAULT_REPLY_LATENCY_ON, ME, values=[0.05, 0.01]).ok
    assert core.faults.reply_latency == 0.05 and core.faults.reply_jitter == 0.01
    assert core.command(EmulatorCommand.FAULT_REPLY_LATENCY_OFF, ME).ok and core.faults.reply_latency == 0
    slow_on = EmulatorCommand.FAULT_SLOW_LOOP_ON
    assert core.command(slow_on, ME, values=[0.5]).subcode == Subcode.BAD_ARGUMENT
    assert core.command(slow_on, ME, values=[3.0]).ok and core.faults.slow_loop_factor == 3
    assert core.command(EmulatorCommand.FAULT_SLOW_LOOP_OFF, ME).ok and core.faults.slow_loop_factor == 1
    assert core.command(EmulatorCommand.FAULT_DROP_SLAVE_LINK_ON, ME).ok and core.faults.drop_slave_link
    assert core.command(EmulatorCommand.FAULT_DROP_SLAVE_LINK_OFF, ME).ok and not core.faults.drop_slave_link


def test_freeze_feedback_repeats_the_last_sample():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.3))
    core.submit(trajectory(t, p, v), ME)
    run(core, 20)
    assert core.command(EmulatorCommand.FAULT_FREEZE_FEEDBACK_ON, ME).ok
    frozen = core.feedback()
    fbs = run(core, 30)
    assert all(fb is frozen for fb in fbs)
    assert not np.allclose(core.q, frozen.positions)  # the robot itself kept moving
    core.command(EmulatorCommand.FAULT_FREEZE_FEEDBACK_OFF, ME)
    assert np.array_equal(core.step().positions, core.q)


def test_limit_violation_is_clamped_with_alarm():
    # bypass acceptance: the core must still never command beyond a limit
    core = ready_core()
    t = np.array([0.0, 1.0])
    p = np.zeros((2, N))
    p[1, 0] = RC.upper[0] + 1.0
    core._queue.append(PreparedTrajectory.build(trajectory(t, p, None), core.tick + 1))
    fbs = run(core, 400)
    assert core.alarm_code == Alarm.LIMIT_EXCEEDED
    assert max(fb.positions[0] for fb in fbs) <= RC.upper[0]
    check_limits(fbs, fd_tol=10.0)  # the clamp itself may jerk; the values stay inside


def test_status_fields_and_lease_not_required():
    cfg = replace(CFG, lease_required=False)
    core = ControllerCore(RC, cfg)
    st = core.status()
    assert not st.drives_powered and not st.e_stopped and not st.in_error and st.mode == Mode.AUTO
    assert [g.name for g in st.groups] == ["R1", "R2", "B1"]
    assert core.command(Command.START_TRAJ_MODE, "").ok
    st = core.status()
    assert st.drives_powered and st.motion_possible
    fb = core.step()
    assert fb.stamp == pytest.approx(DT) and fb.joint_names == RC.joint_names and np.all(fb.efforts == 0)


def test_role_and_initial_position_validation():
    with pytest.raises(ValueError, match="role"):
        ControllerCore(RC, CFG, "boss")
    with pytest.raises(ValueError, match="initial_position"):
        ControllerCore(RC, CFG, "master", initial_position=np.zeros(N))
    slave = ControllerCore(RC, CFG, "slave")
    assert slave.joint_names == RC.group("R2").joints


def test_jog_moves_one_joint():
    core = ready_core()
    r = core.command(Command.JOG, ME, joint="r2_joint_b", values=[0.3])
    assert r.ok, r
    run(core, 1000)
    expected = np.zeros(N)
    expected[RC.index("r2_joint_b")] = 0.3
    assert np.allclose(core.q, expected)
    assert core.command(Command.JOG, ME, joint="nope", values=[0.1]).subcode == Subcode.BAD_ARGUMENT
    assert core.command(Command.JOG, ME, joint="r1_joint_s", values=[]).subcode == Subcode.BAD_ARGUMENT
    assert core.command(Command.JOG, "other", joint="r1_joint_s", values=[0.1]).subcode == Subcode.LEASE_HELD
    r = core.command(Command.JOG, ME, joint="r1_joint_s", values=[10.0])
    assert r.subcode == Subcode.INVALID_DATA_POSITION and r.joint == "r1_joint_s"
    assert r.text.startswith("jog: r1_joint_s target")


def test_trajectory_ids_and_fault_names_in_status():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.2))
    t2, p2, v2 = planned(p[-1], np.zeros(N))
    r1 = core.submit(trajectory(t, p, v), ME)
    r2 = core.submit(trajectory(t2, p2, v2), ME)
    assert r1.trajectory_id > 0 and r2.trajectory_id == r1.trajectory_id + 1
    assert core.queued_ids == (r1.trajectory_id, r2.trajectory_id) and core.trajectory_id == 0
    core.step()
    assert core.trajectory_id == r1.trajectory_id
    run(core, int(t[-1] / DT) + 5)
    assert core.trajectory_id == r2.trajectory_id
    assert core.status().faults == ()
    core.command(EmulatorCommand.FAULT_SLOW_LOOP_ON, ME, values=[2.0])
    core.command(EmulatorCommand.FAULT_FREEZE_FEEDBACK_ON, ME)
    assert core.status().faults == ("freeze_feedback", "slow_loop")
    assert core.status().trajectory_mode


def test_submit_during_a_stop_is_busy():
    core = ready_core()
    t, p, v = planned(core.q, np.full(N, 0.8))
    assert core.submit(trajectory(t, p, v), ME).ok
    run(core, 60)
    core.command(Command.STOP_MOTION, ME)
    core.step()
    assert core.status().in_motion
    r = core.submit(trajectory(t, p, v), ME)
    assert r.result == Result.BUSY and "stop" in r.text
    run(core, 300)
    t2, p2, v2 = planned(core.q, np.zeros(N))
    assert core.submit(trajectory(t2, p2, v2), ME).ok
