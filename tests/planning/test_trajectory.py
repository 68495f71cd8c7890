"""Time parameterisation (ruckig) checked by the controller's own acceptance rules; free moves with
RRT-Connect."""

import dataclasses
import itertools

import numpy as np
import pytest

from cell.planning.errors import InvalidTrajectory, PlanningError
from cell.planning.motion import MotionPlanner
from cell.planning.trajectory import Limits, PlannedTrajectory, path_trajectory, ptp_trajectory
from drivers.controller.acceptance import check_trajectory
from drivers.controller.codes import OK


@pytest.fixture(scope="module")
def mp() -> MotionPlanner:
    return MotionPlanner()


def _random_free_pair(mp, rng, spread=0.6):
    for _ in range(10000):
        a = mp.perceive + rng.uniform(-spread, spread, 13)
        b = mp.perceive + rng.uniform(-spread, spread, 13)
        a, b = np.clip(a, mp.robot.lower, mp.robot.upper), np.clip(b, mp.robot.lower, mp.robot.upper)
        if mp.valid(a) and mp.valid(b):
            return a, b
    raise AssertionError("no collision-free pair found")


def test_ptp_is_straight_synchronised_and_within_limits(mp):
    rng = np.random.default_rng(5)
    for _ in range(20):
        a, b = _random_free_pair(mp, rng)
        t = ptp_trajectory(np.vstack([a, b]), mp.limits)
        assert check_trajectory(t, a, mp.robot, mp.controller_config) == OK
        # every point on the segment a-b (all axes synchronised: one shape for all)
        s = (t.positions - a) @ (b - a) / np.dot(b - a, b - a)
        np.testing.assert_allclose(t.positions, a + np.outer(s, b - a), atol=1e-6)
        assert np.all(np.diff(s) >= -1e-9)
        dense = t.dense_positions(0.004)
        v = np.abs(np.diff(dense, axis=0)) / 0.004
        assert np.all(v <= mp.robot.max_velocity * 1.001)


def test_path_trajectory_follows_the_path(mp):
    s = np.linspace(0, 1, 60)[:, None]
    path = mp.perceive + np.hstack([np.sin(3 * s) * 0.3, s * 0.5, np.zeros((60, 11))])
    t = path_trajectory(path, mp.limits, "p", allow_finger_contact=True)
    assert check_trajectory(t, path[0], mp.robot, mp.controller_config) == OK
    assert len(t.times) <= mp.controller_config.max_points
    assert t.label == "p" and t.allow_finger_contact
    # each sample lies on the path (within interpolation error)
    for q in t.positions:
        assert np.min(np.linalg.norm(path - q, axis=1)) < 0.01
    np.testing.assert_allclose(t.positions[-1], path[-1])
    assert np.all(t.velocities[-1] == 0.0) and np.all(t.velocities[0] == 0.0)


def test_long_move_stays_within_200_points(mp):
    a = mp.perceive.copy()
    b = a.copy()
    b[mp.ext_index] = 3.0   # turn-table about half a turn
    params = dataclasses.replace(mp.config.trajectory, sample_period=0.01)   # would need > 400 points
    t = ptp_trajectory(np.vstack([a, b]), Limits(mp.robot, params, mp.controller_config))
    assert t.duration > 4.0
    assert len(t.times) == mp.controller_config.max_points == 200
    assert check_trajectory(t, a, mp.robot, mp.controller_config) == OK


def _good(mp) -> PlannedTrajectory:
    a = mp.perceive.copy()
    b = a.copy()
    b[0] += 0.2
    return ptp_trajectory(np.vstack([a, b]), mp.limits)


@pytest.mark.parametrize("breakage,match", [
    ("names", "joint order"), ("nan", "finite values"), ("time", "increase strictly"),
    ("limit", "position limits"), ("speed", "velocity limits"), ("start", "start position"),
    ("points", "point count"), ("last", "last point at rest"),
])
def test_validate_raises_the_controllers_rejection(mp, breakage, match):
    """The planner's check is the controller's: its reply's rule names the failure."""
    t = _good(mp)
    P, V, T, names = t.positions.copy(), t.velocities.copy(), t.times.copy(), t.joint_names
    if breakage == "names":
        names = tuple(reversed(names))
    elif breakage == "nan":
        P[3, 2] = np.nan
    elif breakage == "time":
        T[4] = T[3]
    elif breakage == "limit":
        P[:, 1] = mp.robot.upper[1] + 0.1
    elif breakage == "speed":
        V[2, 0] = mp.robot.max_velocity[0] * 2
    elif breakage == "points":
        n = 250
        P = np.repeat(P[:1], n, axis=0)
        V = np.zeros_like(P)
        T = np.linspace(0, 10, n)
    elif breakage == "last":
        V[-1, 0] = 0.1
    current = P[0] + (3 * mp.controller_config.start_tolerance if breakage == "start" else 0.0)
    with pytest.raises(InvalidTrajectory, match=match):
        mp.validate(PlannedTrajectory(names, T, P, V, "broken"), current)


def test_free_moves_around_obstacles(mp):
    """Random start/goal pairs whose straight segment collides: RRT-Connect (and the planner's
    detours) give a path whose trajectory passes the dense check at the 4 ms interpolation tick."""
    rng = np.random.default_rng(21)
    done = 0
    for _ in range(500):
        if done == 3:
            break
        a, b = _random_free_pair(mp, rng, spread=1.5)
        if mp.segment_free(a, b):
            continue
        wps = mp.rrt_connect(a, b)
        np.testing.assert_allclose(wps[0], a)
        np.testing.assert_allclose(wps[-1], b)
        assert all(mp.segment_free(x, y) for x, y in itertools.pairwise(wps))
        t = mp.free_move(a, b)
        mp.validate(t, a, period=0.004)
        np.testing.assert_allclose(t.positions[-1], b)
        done += 1
    assert done == 3


def test_invalid_goal_is_refused(mp):
    q = mp.perceive.copy()
    q[mp.robot.index("r1_joint_s")] = -0.8
    q[mp.robot.index("r2_joint_s")] = 0.8
    with pytest.raises(PlanningError, match="goal"):
        mp.free_move(mp.perceive, q)
