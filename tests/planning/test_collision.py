"""Collision checking: arm/arm, arm/table, arm/turn-table, self-collision, finger contact, fcl = coal."""

import math

import numpy as np
import pytest

from cell.planning.ik import look_rotation
from cell.planning.motion import MotionPlanner


@pytest.fixture(scope="module")
def mp() -> MotionPlanner:
    return MotionPlanner()


def q_of(mp, **joints) -> np.ndarray:
    q = mp.perceive.copy()
    for name, v in joints.items():
        q[mp.robot.index(name)] = v
    return q


def test_perceive_and_home_are_free(mp):
    assert not mp.collision.in_collision(mp.perceive)
    assert not mp.collision.in_collision(np.array(mp.robot.home))


def test_arm_against_arm(mp):
    # both arms swung towards each other, level: forearms cross in front of the turn-table
    q = q_of(mp, r1_joint_s=-0.8, r2_joint_s=0.8)
    for backend in ("coal", "fcl"):
        assert mp.collision.in_collision(q, backend=backend)
    names = {n for pair in mp.collision.colliding_pairs(q) for n in pair}
    assert any(n.startswith("r1_") for n in names) and any(n.startswith("r2_") for n in names)


def test_arm_against_table(mp):
    # r1 facing the table, upper arm leaning far forward: forearm through the table top
    q = q_of(mp, r1_joint_s=0.0, r1_joint_l=1.3, r1_joint_u=0.0)
    assert mp.collision.in_collision(q)
    assert any("table_0" in pair for pair in mp.collision.colliding_pairs(q))


def test_arm_against_turntable(mp):
    # r1 leaning forward with the elbow folded: the gripper comes back down onto the pedestal
    q = q_of(mp, r1_joint_s=0.0, r1_joint_l=2.7, r1_joint_u=-0.5)
    pairs = mp.collision.colliding_pairs(q)
    assert any(("turntable_0" in p or "turntable_base_0" in p) for p in pairs), pairs


def test_self_collision_non_adjacent_links(mp):
    # elbow folded back so that the gripper comes down on the upper arm / base
    q = q_of(mp, r1_joint_s=0.0, r1_joint_l=0.0, r1_joint_u=3.2, r1_joint_b=0.0)
    pairs = mp.collision.colliding_pairs(q)
    assert any(p[0].startswith("r1_") and p[1].startswith("r1_") for p in pairs), pairs


def test_fingers_may_touch_table_only_when_allowed(mp):
    # TCP 2 mm above the table top with the approach pitched down: the fingertips reach into the table
    w = np.array([0.9, 0.3, 0.752])
    T = np.eye(4)
    T[:3, :3] = look_rotation(np.array([math.cos(0.45), 0.0, -math.sin(0.45)]))
    T[:3, 3] = w
    seeds = []
    for s in mp.config.ik_seeds:
        q = mp.perceive.copy()
        q[mp.arm_indices["r1"]] = s
        seeds.append(q)
    r = mp.ik.solve_multi("r1", T, seeds)
    assert r.success
    pairs = mp.collision.colliding_pairs(r.q)
    assert pairs == [("table_0", "r1_fingers_0")]
    assert mp.collision.in_collision(r.q)
    assert not mp.collision.in_collision(r.q, allow_finger_contact=True)
    assert not mp.collision.in_collision(r.q, allow_finger_contact=True, backend="fcl")


def test_fcl_and_coal_agree(mp):
    rng = np.random.default_rng(11)
    qs = rng.uniform(mp.robot.lower, mp.robot.upper, (300, 13))
    a = [mp.collision.in_collision(q, backend="coal") for q in qs]
    b = [mp.collision.in_collision(q, backend="fcl") for q in qs]
    assert a == b
    assert 0 < sum(a) < len(a)
