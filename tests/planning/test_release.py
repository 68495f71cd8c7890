"""Letting go of held cloth without the plan in hand: carried on along the fold's path to where the fold
lays it, or lowered where it is; checked by forward kinematics of the motions planned, against the
fold plan the gripper closed for."""

import numpy as np
import pytest

from cell.planning.folds import FoldPlanner, GripperAction
from cell.planning.motion import MotionPlanner
from cell.planning.release import carry_of, plan_release
from cell.planning.trajectory import PlannedTrajectory
from drivers.sim.garments import place_garment


@pytest.fixture(scope="module")
def fold():
    planner = FoldPlanner(MotionPlanner())
    lm = place_garment("towel", planner.table, np.random.default_rng(7),
                       reach_radius=planner.config.reach_radius)
    plan = planner.plan_fold("towel", 0, lm, planner.motion.perceive.copy())
    carry = next(s for s in plan.steps if isinstance(s, PlannedTrajectory) and s.label == "fold")
    return planner, plan, carry


def tcp_z(planner: FoldPlanner, q: np.ndarray, arm: str) -> float:
    return float(planner.motion.kin.tcp_pose(q, arm)[2, 3] - planner.table.height)


# stopped on its way up (short of the apex), or on its way down
@pytest.mark.parametrize(("stopped_at", "rising"), [(0.2, True), (0.75, False)])
def test_held_cloth_is_carried_on_along_the_fold_s_path_to_its_place(fold, stopped_at, rising):
    planner, plan, carry = fold
    motion, grasp = planner.motion, planner.config.grasp
    stopped = carry.positions[int(len(carry.positions) * stopped_at)]
    held = {arm: carry_of(plan, arm, motion) for arm in plan.arms}
    release = plan_release(motion, stopped, held, planner.table.height)
    move, *opens, retreat = release.steps
    assert opens == [GripperAction(arm, "open") for arm in plan.arms]
    assert isinstance(move, PlannedTrajectory) and isinstance(retreat, PlannedTrajectory)
    np.testing.assert_allclose(move.positions[0], stopped)
    for arm in plan.arms:
        # where the plan's own fold lays the cloth, at the release height
        planned = motion.kin.tcp_pose(carry.positions[-1], arm)[:3, 3]
        laid = motion.kin.tcp_pose(move.positions[-1], arm)[:3, 3]
        np.testing.assert_allclose(laid, planned, atol=2e-3)
        # over the fold line as high as the plan went (the flap is carried over, not dragged), or
        # from where it stopped past that, straight down to the place
        highest = max(tcp_z(planner, q, arm) for q in (carry.positions if rising else [stopped]))
        assert max(tcp_z(planner, q, arm) for q in move.positions) == pytest.approx(highest, abs=0.01)
        # then out and up
        assert tcp_z(planner, retreat.positions[-1], arm) == pytest.approx(
            grasp.release_height + grasp.retreat_lift, abs=2e-3)


def test_cloth_whose_carry_is_unknown_is_lowered_where_it_is(fold):
    planner, plan, carry = fold
    motion, grasp = planner.motion, planner.config.grasp
    stopped = carry.positions[len(carry.positions) // 2]
    release = plan_release(motion, stopped, dict.fromkeys(plan.arms), planner.table.height)
    move = release.steps[0]
    assert "lowered where it is" in release.how
    for arm in plan.arms:
        start = motion.kin.tcp_pose(stopped, arm)[:3, 3]
        laid = motion.kin.tcp_pose(move.positions[-1], arm)[:3, 3]
        np.testing.assert_allclose(laid[:2], start[:2], atol=2e-3)
        assert laid[2] - planner.table.height == pytest.approx(grasp.release_height, abs=2e-3)
