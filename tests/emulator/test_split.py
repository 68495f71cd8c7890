"""Master/slave: splitting a cell trajectory, synchronous start, merged feedback, link loss."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.controller.acceptance import check_trajectory
from drivers.controller.codes import Alarm, Command, Result, Subcode
from drivers.controller.config import default_controller_config
from drivers.controller.motion import plan_point_to_point
from drivers.controller.trajectory import JointTrajectory
from drivers.emulator.commands import EmulatorCommand
from drivers.emulator.core import ControllerCore
from drivers.emulator.split import (
    LinkMonitor,
    common_start_tick,
    joints_of,
    merge_feedback,
    merge_status,
    split_trajectory,
)
from drivers.robot.config import default_robot_config

RC = default_robot_config()
CFG = default_controller_config()
N = len(RC.joint_names)
ME = "s"


def ready(role):
    core = ControllerCore(RC, CFG, role)
    assert core.command(Command.LEASE_ACQUIRE, ME).ok and core.command(Command.START_TRAJ_MODE, ME).ok
    return core


def planned(start, target):
    return plan_point_to_point(start, target, RC.max_velocity * 0.8, RC.max_acceleration * 0.8,
                               RC.max_jerk * 0.8, CFG.max_points)


def whole(t, p, v, names=RC.joint_names) -> JointTrajectory:
    return JointTrajectory(names, t, p, v)


def test_split_by_default_ownership():
    t, p, v = planned(np.zeros(N), np.linspace(0.1, 0.5, N))
    parts = split_trajectory(RC, CFG.group_owners, whole(t, p, v))
    m, s = parts["master"], parts["slave"]
    assert m.joint_names == (*RC.group("R1").joints, "ext_axis")
    assert s.joint_names == RC.group("R2").joints
    assert np.array_equal(m.positions[:, :6], p[:, :6]) and np.array_equal(m.positions[:, 6], p[:, 12])
    assert np.array_equal(s.velocities, v[:, 6:12]) and np.array_equal(s.times, t)
    none = split_trajectory(RC, CFG.group_owners, whole(t, p, None))
    assert none["slave"].velocities is None


def test_split_with_other_ownership_and_bad_names():
    owners = {"R1": "slave", "R2": "master", "B1": "slave"}
    assert joints_of(RC, owners, "master") == RC.group("R2").joints
    t, p, v = planned(np.zeros(N), np.full(N, 0.2))
    parts = split_trajectory(RC, owners, whole(t, p, v))
    assert parts["slave"].joint_names == (*RC.group("R1").joints, "ext_axis")
    one = {"R1": "master", "R2": "master", "B1": "master"}
    all_master = split_trajectory(RC, one, whole(t, p, v))
    assert list(all_master) == ["master"]
    names = RC.joint_names[:6] + RC.joint_names[7:]
    with pytest.raises(ValueError, match="r2_joint_s"):
        split_trajectory(RC, CFG.group_owners, whole(t, p[:, 1:], v[:, 1:], names))


def test_master_and_slave_start_on_the_same_tick_and_merge_like_one_controller():
    master, slave, both = ready("master"), ready("slave"), ready("both")
    t, p, v = planned(np.zeros(N), np.linspace(-0.6, 0.6, N))
    # the master validates the whole trajectory before forwarding anything
    assert check_trajectory(whole(t, p, v), np.zeros(N), RC, CFG).ok
    parts = split_trajectory(RC, CFG.group_owners, whole(t, p, v))
    start = common_start_tick(master.tick, master.projected_end_tick(), slave.projected_end_tick(), 10)
    assert start == 10
    sp, mp = parts["slave"], parts["master"]
    assert slave.submit(sp, ME, start_tick=start).ok
    run_ticks = 3  # the slave's acceptance takes a few ticks to come back
    for _ in range(run_ticks):
        master.step(), slave.step(), both.step()
    assert master.submit(mp, ME, start_tick=start).ok
    assert both.submit(whole(t, p, v), ME, start_tick=start).ok
    first_move = {}
    for _ in range(int(t[-1] / CFG.interpolation_period) + 20):
        fm, fs, fb = master.step(), slave.step(), both.step()
        merged = merge_feedback(RC, [fm, fs])
        assert merged.joint_names == RC.joint_names
        assert np.allclose(merged.positions, fb.positions, atol=1e-12)
        assert np.allclose(merged.velocities, fb.velocities, atol=1e-12)
        assert merged.stamp == fb.stamp
        for name, f in (("master", fm), ("slave", fs)):
            if name not in first_move and np.abs(f.velocities).max() > 0:
                first_move[name] = f.stamp
    assert first_move["master"] == first_move["slave"]
    assert np.allclose(merge_feedback(RC, [master.feedback(), slave.feedback()]).positions, p[-1])
    st = merge_status(RC, [master.status(), slave.status()])
    assert [g.name for g in st.groups] == ["R1", "R2", "B1"]
    assert [g.controller for g in st.groups] == ["master", "slave", "master"]
    assert st.lease_holder == ME and st.drives_powered and not st.in_motion


def test_merge_status_keeps_every_fault():
    master, slave = ready("master"), ready("slave")
    assert master.command(EmulatorCommand.FAULT_FREEZE_FEEDBACK_ON, ME).ok
    assert merge_status(RC, [master.status(), slave.status()]).faults == ("freeze_feedback",)


def test_merge_feedback_rejects_missing_and_duplicate_joints():
    master, slave = ControllerCore(RC, CFG, "master"), ControllerCore(RC, CFG, "slave")
    with pytest.raises(ValueError, match="missing"):
        merge_feedback(RC, [master.feedback()])
    with pytest.raises(ValueError, match="twice"):
        merge_feedback(RC, [master.feedback(), slave.feedback(), slave.feedback()])


def test_link_monitor_fires_once_after_timeout():
    mon = LinkMonitor(CFG.link_stall_timeout, now=0.0)
    assert not mon.check(CFG.link_stall_timeout * 0.9)
    mon.heard(0.05)
    assert not mon.check(0.05 + CFG.link_stall_timeout * 0.99)
    assert mon.check(0.05 + CFG.link_stall_timeout * 1.01)
    assert not mon.check(1.0)  # reported once
    mon.heard(1.1)
    assert not mon.lost
    with pytest.raises(ValueError):
        LinkMonitor(0.0)


def test_slave_link_loss_alarms_and_stops_all_groups_within_one_status_period():
    master, slave = ready("master"), ready("slave")
    LINK_TIMEOUT = 0.5   # s: how fast the monitor is told to declare the link lost (any value will do)
    t, p, v = planned(np.zeros(N), np.full(N, 0.7))
    parts = split_trajectory(RC, CFG.group_owners, whole(t, p, v))
    for core, part in ((master, parts["master"]), (slave, parts["slave"])):
        assert core.submit(part, ME, start_tick=5).ok
    mon = LinkMonitor(LINK_TIMEOUT, now=master.stamp)
    slave_alive = True
    lost_at = None
    dt = CFG.interpolation_period
    for i in range(400):
        fm = master.step()
        if slave_alive:
            slave.step()
            mon.heard(master.stamp)
        if i == 60:
            assert master.status().in_motion
            slave_alive = False  # the slave process is killed
            killed_at = master.stamp
        if mon.check(master.stamp):
            master.link_lost("slave")
            lost_at = master.stamp
        if lost_at is not None and master.stamp >= lost_at + dt:
            assert np.all(fm.velocities == 0)
    assert lost_at is not None and lost_at - killed_at <= LINK_TIMEOUT + dt
    st = master.status()
    assert st.in_error and st.error_code == Alarm.SLAVE_LINK_LOST and not st.in_motion
    r = master.submit(parts["master"], ME)
    assert r.result == Result.NOT_READY and r.subcode == Subcode.NOT_READY_ALARM
    # the slave, told (or noticing) that the master is gone, stops too
    slave.link_lost("master")
    assert slave.status().error_code == Alarm.MASTER_LINK_LOST
    assert np.all(slave.step().velocities == 0)
