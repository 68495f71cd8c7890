"""Every acceptance rule rejects its bad trajectory with the right code, subcode, point and joint."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from drivers.controller.acceptance import Readiness, check_ready, check_trajectory
from drivers.controller.codes import Result, Subcode
from drivers.controller.config import default_controller_config
from drivers.controller.motion import plan_point_to_point
from drivers.controller.trajectory import JointTrajectory
from drivers.robot.config import default_robot_config

RC = default_robot_config()
CFG = default_controller_config()
NAMES = RC.joint_names
N = len(NAMES)
CUR = np.zeros(N)


def good() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A valid trajectory from CUR (ruckig, at 80 % of the limits)."""
    target = np.linspace(-0.4, 0.6, N)
    t, p, v = plan_point_to_point(CUR, target, RC.max_velocity * 0.8, RC.max_acceleration * 0.8,
                                  RC.max_jerk * 0.8, CFG.max_points)
    return p, v, t


def check(p, v, t, names=NAMES, cur=CUR):
    return check_trajectory(JointTrajectory(names, t, p, v), cur, RC, CFG)


def assert_rejected(reply, result, subcode, point=None, joint=None):
    assert reply.result == result, reply
    assert reply.subcode == subcode, reply
    if point is not None:
        assert reply.point == point, reply
        assert str(point) in reply.text
    if joint is not None:
        assert reply.joint == joint, reply
        assert joint in reply.text


def test_good_trajectory_is_accepted():
    p, v, t = good()
    reply = check(p, v, t)
    assert reply.ok and reply.result == Result.SUCCESS


def test_positions_shape():
    p, v, t = good()
    assert_rejected(check(p[:, :-1], v, t), Result.INVALID, Subcode.INVALID_MSGSIZE)
    assert_rejected(check(p, v[:, :-1], t), Result.INVALID, Subcode.INVALID_MSGSIZE)
    assert_rejected(check(p, v, t[:-1]), Result.INVALID, Subcode.INVALID_MSGSIZE)


def test_unknown_joint_name():
    p, v, t = good()
    names = list(NAMES)
    names[4] = "r1_joint_x"
    assert_rejected(check(p, v, t, names), Result.INVALID, Subcode.INVALID_DATA, joint="r1_joint_x")


def test_duplicate_joint_name():
    p, v, t = good()
    names = list(NAMES)
    names[5] = "r1_joint_s"
    assert_rejected(check(p, v, t, names), Result.INVALID, Subcode.INVALID_DATA, joint="r1_joint_s")


def test_missing_joint():
    p, v, t = good()
    reply = check(p[:, :-1], v[:, :-1], t, NAMES[:-1])
    assert_rejected(reply, Result.INVALID, Subcode.INVALID_DATA, joint="ext_axis")


def test_joint_order():
    p, v, t = good()
    names = list(NAMES)
    names[0], names[1] = names[1], names[0]
    reply = check(p, v, t, names)
    assert_rejected(reply, Result.INVALID, Subcode.INVALID_DATA, joint="r1_joint_l")
    assert "order" in reply.text


def test_at_least_two_points():
    p, v, t = good()
    assert_rejected(check(p[:1], v[:1], t[:1]), Result.INVALID, Subcode.INVALID_DATA_INSUFFICIENT)


def test_at_most_max_points():
    k = CFG.max_points + 1
    t = np.arange(k) * 0.1
    p = np.zeros((k, N))
    assert_rejected(check(p, np.zeros_like(p), t), Result.INVALID, Subcode.INVALID_MSGSIZE)
    ok = check(p[:-1], np.zeros_like(p[:-1]), t[:-1])
    assert ok.ok


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_finite_positions_and_velocities(bad):
    p, v, t = good()
    p2 = p.copy()
    p2[3, 7] = bad
    assert_rejected(check(p2, v, t), Result.INVALID, Subcode.INVALID_DATA, point=3, joint=NAMES[7])
    v2 = v.copy()
    v2[2, 12] = bad
    assert_rejected(check(p, v2, t), Result.INVALID, Subcode.INVALID_DATA, point=2, joint=NAMES[12])
    t2 = t.copy()
    t2[4] = bad
    assert_rejected(check(p, v, t2), Result.INVALID, Subcode.INVALID_DATA, point=4)


def test_first_time_zero():
    p, v, t = good()
    assert_rejected(check(p, v, t + 0.1), Result.INVALID, Subcode.INVALID_DATA_TIME, point=0)


@pytest.mark.parametrize("delta", [0.0, -0.01])
def test_time_strictly_increasing(delta):
    p, v, t = good()
    t2 = t.copy()
    t2[5] = t2[4] + delta
    assert_rejected(check(p, v, t2), Result.INVALID, Subcode.INVALID_DATA_TIME, point=5)


def test_start_position():
    p, v, t = good()
    cur = CUR.copy()
    cur[9] += CFG.start_tolerance * 2
    assert_rejected(check(p, v, t, cur=cur), Result.INVALID, Subcode.INVALID_DATA_START_POS,
                    point=0, joint=NAMES[9])
    cur[9] = CUR[9] + CFG.start_tolerance * 0.5
    assert check(p, v, t, cur=cur).ok


def test_position_limits_at_a_point():
    t = np.array([0.0, 2.0, 4.0])
    p = np.zeros((3, N))
    p[1, 1] = RC.upper[1] + 0.01
    assert_rejected(check(p, None, t), Result.INVALID, Subcode.INVALID_DATA_POSITION, point=1, joint=NAMES[1])


def test_velocity_limit_at_a_point():
    p, v, t = good()
    v2 = v.copy()
    v2[2, 3] = RC.max_velocity[3] * 1.01
    assert_rejected(check(p, v2, t), Result.INVALID, Subcode.INVALID_DATA_SPEED, point=2, joint=NAMES[3])


def test_implied_velocity():
    t = np.array([0.0, 0.1, 10.0])
    p = np.zeros((3, N))
    p[1, 12] = RC.max_velocity[12] * 0.1 * 1.5  # 1.5 x the speed limit between points 0 and 1
    assert_rejected(check(p, None, t), Result.INVALID, Subcode.INVALID_DATA_SPEED, point=1, joint=NAMES[12])


def test_last_point_at_rest():
    p, v, t = good()
    v2 = v.copy()
    v2[-1, 6] = 0.01
    k = len(t) - 1
    assert_rejected(check(p, v2, t), Result.INVALID, Subcode.INVALID_DATA_SPEED, point=k, joint=NAMES[6])


def test_interpolated_position_overshoot():
    # points inside the limits, but the Hermite cubic overshoots the upper limit between points 1 and 2
    t = np.array([0.0, 1.0, 2.0])
    p = np.zeros((3, N))
    v = np.zeros((3, N))
    j = 4
    p[1, j] = RC.upper[j] - 0.001
    v[1, j] = RC.max_velocity[j] * 0.5
    assert_rejected(check(p, v, t), Result.INVALID, Subcode.INVALID_DATA_POSITION, point=2, joint=NAMES[j])


def test_interpolated_velocity():
    # zero velocities at the points: the cubic peaks at 1.5 x the mean speed
    j = 0
    T = 0.5
    t = np.array([0.0, T])
    p = np.zeros((2, N))
    p[1, j] = RC.max_velocity[j] * 0.9 * T
    assert_rejected(check(p, None, t), Result.INVALID, Subcode.INVALID_DATA_SPEED, point=1, joint=NAMES[j])


def test_interpolated_acceleration():
    j = 2
    T = 0.1
    t = np.array([0.0, T, 5.0])
    p = np.zeros((3, N))
    p[1:, j] = RC.max_velocity[j] * 0.3 * T  # slow, but 6 dp / T^2 is above the limit
    assert_rejected(check(p, None, t), Result.INVALID, Subcode.INVALID_DATA_ACCEL, point=1, joint=NAMES[j])


def test_missing_velocities_are_zero():
    t = np.array([0.0, 2.0, 4.0])
    p = np.zeros((3, N))
    p[1, :] = 0.2
    assert check(p, None, t).ok
    assert check(p, np.zeros_like(p), t).ok


def test_subset_of_joints():
    names = RC.group("R2").joints
    t = np.array([0.0, 2.0])
    p = np.zeros((2, 6))
    p[1] = 0.1
    assert check_trajectory(JointTrajectory(names, t, p), np.zeros(6), RC, CFG, expected_joints=names).ok
    reply = check_trajectory(JointTrajectory(NAMES[:6], t, p), np.zeros(6), RC, CFG, expected_joints=names)
    assert reply.subcode == Subcode.INVALID_DATA


READY = Readiness(e_stopped=False, alarm_code=0, servo_on=True, held=False, play_mode=True, remote=True,
                  traj_mode=True, queue_count=0, queue_size=4)


@pytest.mark.parametrize("change, subcode", [
    ({"e_stopped": True}, Subcode.NOT_READY_ESTOP),
    ({"alarm_code": 4900}, Subcode.NOT_READY_ALARM),
    ({"servo_on": False}, Subcode.NOT_READY_SERVO_OFF),
    ({"held": True}, Subcode.NOT_READY_HOLD),
    ({"play_mode": False}, Subcode.NOT_READY_NOT_PLAY),
    ({"remote": False}, Subcode.NOT_READY_NOT_REMOTE),
    ({"traj_mode": False}, Subcode.NOT_READY_NOT_STARTED),
])
def test_readiness(change, subcode):
    assert check_ready(READY).ok
    reply = check_ready(replace(READY, **change))
    assert reply.result == Result.NOT_READY and reply.subcode == subcode


def test_queue_full_is_busy():
    reply = check_ready(replace(READY, queue_count=4))
    assert reply.result == Result.BUSY
    assert check_ready(replace(READY, queue_count=3)).ok
