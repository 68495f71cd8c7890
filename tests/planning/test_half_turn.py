"""A towel has no top: when the recipe's first fold (bottom onto top) is out of two arms' reach as
named, the planner lays the top onto the bottom instead, with both arms, along the same line."""

from __future__ import annotations

import numpy as np
import pytest

from cell.planning.folds import FoldPlanner
from drivers.robot.config import load_robot_config
from drivers.sim.world import GarmentWorld

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def planner() -> FoldPlanner:
    return FoldPlanner()


def test_a_towel_both_arms_cannot_fold_as_named_is_folded_turned_half_round(planner) -> None:
    world = GarmentWorld(seed=3, category="towel")   # lies so that bottom-onto-top points at the robot
    landmarks = {n: (float(x), float(y)) for n, (x, y) in world.truth_landmarks().items()}
    home = np.asarray(load_robot_config().home, dtype=float)
    as_named = planner._plan_named("towel", 0, landmarks, home, False)
    assert len(as_named.arms) == 1        # the premise: as named, one arm at the edge's middle
    plan = planner.plan_fold("towel", 0, landmarks, home, include_perceive=False)
    assert len(plan.arms) == 2
    # it grasps the top corners and lays them on the bottom ones: their mirror images across the
    # line through the middles of the long sides (worked out from the landmarks, not the plan)
    top = np.array([landmarks["top-left"], landmarks["top-right"]])
    bottom = np.array([landmarks["bottom-left"], landmarks["bottom-right"]])
    for grasp in plan.grasp_points:
        assert np.min(np.linalg.norm(top - np.asarray(grasp), axis=1)) < 0.05, (grasp, top)
    for place in plan.place_points:
        assert np.min(np.linalg.norm(bottom - np.asarray(place), axis=1)) < 0.05, (place, bottom)


def test_a_towel_two_arms_can_fold_as_named_keeps_its_names(planner) -> None:
    world = GarmentWorld(seed=2, category="towel")
    landmarks = {n: (float(x), float(y)) for n, (x, y) in world.truth_landmarks().items()}
    plan = planner.plan_fold("towel", 0, landmarks, np.asarray(load_robot_config().home, dtype=float),
                             include_perceive=False)
    bottom = np.array([landmarks["bottom-left"], landmarks["bottom-right"]])
    assert len(plan.arms) == 2
    for grasp in plan.grasp_points:
        assert np.min(np.linalg.norm(bottom - np.asarray(grasp), axis=1)) < 0.05


def test_the_next_fold_goes_on_in_the_turned_naming(planner) -> None:
    world = GarmentWorld(seed=3, category="towel")
    landmarks = {n: (float(x), float(y)) for n, (x, y) in world.truth_landmarks().items()}
    home = np.asarray(load_robot_config().home, dtype=float)
    first = planner.plan_fold("towel", 0, landmarks, home, include_perceive=False)
    world.apply_fold([(np.asarray(g), np.asarray(p)) for g, p in zip(first.grasp_points, first.place_points,
                                                                     strict=True)])
    folded = {n: (float(x), float(y)) for n, (x, y) in world.truth_landmarks().items()}
    # the world names what lies as it lies: the bottom corners stayed, the top ones went under them
    assert {"bottom-left", "bottom-right"} <= set(folded) and "top-left" not in folded
    second = planner.plan_fold("towel", 1, folded, home, include_perceive=False)
    # it grasps its "top-left", the corner the world calls bottom-right, with "fold1-from" (or one arm
    # between the two, the half towel's side being short)
    corner, crease_end = np.asarray(folded["bottom-right"]), np.asarray(folded["fold1-from"])
    expected = np.array([corner, crease_end, (corner + crease_end) / 2])
    for grasp in second.grasp_points:
        assert np.min(np.linalg.norm(expected - np.asarray(grasp), axis=1)) < 0.05, (grasp, expected)
