"""IK round trips (FK(IK(p)) within 1 mm and 0.5 deg), the turn-table as extra DOF, reachability."""

import math

import numpy as np
import pinocchio as pin
import pytest

from cell.planning.folds import FoldPlanner
from cell.planning.ik import look_rotation
from cell.planning.motion import MotionPlanner


@pytest.fixture(scope="module")
def mp() -> MotionPlanner:
    return MotionPlanner()


def _seeds(mp: MotionPlanner, arm: str, base: np.ndarray) -> list[np.ndarray]:
    out = []
    for s in mp.config.ik_seeds:
        q = base.copy()
        q[mp.arm_indices[arm]] = s
        out.append(q)
    return out


def _pose_error(A: np.ndarray, B: np.ndarray) -> tuple[float, float]:
    dp = float(np.linalg.norm(A[:3, 3] - B[:3, 3]))
    da = float(np.linalg.norm(pin.log3(A[:3, :3] @ B[:3, :3].T)))
    return dp, math.degrees(da)


@pytest.mark.parametrize("arm", ["r1", "r2"])
def test_ik_round_trip_random_reachable_targets(mp, arm):
    """Targets are FK of random joint vectors around the working postures (so reachable); IK
    starts from the configured seeds, not from the answer."""
    rng = np.random.default_rng(7 if arm == "r1" else 8)
    idx = mp.arm_indices[arm]
    solved = 0
    trials = 60
    for _ in range(trials):
        q_true = mp.perceive.copy()
        seed = np.array(mp.config.ik_seeds[rng.integers(len(mp.config.ik_seeds))])
        q_true[idx] = seed + rng.uniform(-0.4, 0.4, 6)
        q_true = np.clip(q_true, mp.robot.lower + 0.05, mp.robot.upper - 0.05)
        target = mp.kin.tcp_pose(q_true, arm)
        r = mp.ik.solve_multi(arm, target, _seeds(mp, arm, mp.perceive))
        if not r.success:
            continue
        solved += 1
        dp, da = _pose_error(mp.kin.tcp_pose(r.q, arm), target)
        assert dp < 1e-3 and da < 0.5
        assert np.all(r.q >= mp.robot.lower) and np.all(r.q <= mp.robot.upper)
        # IK moves only this arm
        others = np.setdiff1d(np.arange(13), idx)
        np.testing.assert_array_equal(r.q[others], mp.perceive[others])
    assert solved >= 0.95 * trials


def test_ik_on_table_grasp_poses(mp):
    """Low, nearly horizontal approach to points of the reachable table area."""
    fp = FoldPlanner(mp)
    rng = np.random.default_rng(3)
    for _ in range(40):
        xy = np.array([rng.uniform(0.05, 0.45), rng.uniform(0.1, 1.1)])
        w = fp.table.table_to_world(xy)[0] + [0, 0, 0.005]
        yaw = rng.uniform(-math.pi, math.pi)
        a = np.array([math.cos(yaw) * math.cos(0.45), math.sin(yaw) * math.cos(0.45), -math.sin(0.45)])
        T = np.eye(4)
        T[:3, :3] = look_rotation(a)
        T[:3, 3] = w
        arm = "r1" if w[1] > 0 else "r2"
        r = mp.ik.solve_multi(arm, T, _seeds(mp, arm, mp.perceive), use_turntable=True)
        assert r.success, (xy, yaw)
        dp, da = _pose_error(mp.kin.tcp_pose(r.q, arm), T)
        assert dp < 1e-3 and da < 0.5


def test_turntable_extends_reach(mp):
    # a point beside the cell on r2's side, out of r2's reach with the turn-table at 0
    T = np.eye(4)
    T[:3, :3] = look_rotation(np.array([0.0, -1.0, -0.3]))
    T[:3, 3] = [-0.9, -1.0, 0.9]
    seeds = _seeds(mp, "r2", mp.perceive)
    assert not mp.ik.solve_multi("r2", T, seeds, use_turntable=False).success
    r = mp.ik.solve_multi("r2", T, seeds, use_turntable=True)
    assert r.success
    assert abs(r.q[mp.ext_index]) > 0.1
    dp, da = _pose_error(mp.kin.tcp_pose(r.q, "r2"), T)
    assert dp < 1e-3 and da < 0.5


def test_reachability_query(mp):
    fp = FoldPlanner(mp)
    assert fp.reachable((0.3, 0.6))
    assert fp.reachable((0.2, 0.2), arm="r2")
    assert not fp.reachable((3.0, 0.6))


def test_look_rotation_is_a_rotation():
    for a in ([1, 0, 0], [0.3, -0.5, -0.8], [0, 0, -1]):
        R = look_rotation(np.array(a, dtype=float))
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R[:, 2], np.array(a) / np.linalg.norm(a))
        assert R[2, 0] <= 1e-12   # jaw axis never points up
