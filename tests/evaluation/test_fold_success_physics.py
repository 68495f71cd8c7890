"""The fold-success measure on cloth: the oracle's grippers (no robot, no planner) fold the towel's
first fold in the physics world, then err on purpose by a known amount; the measure must name the
error. The reference is what the grippers were told to do, not anything the measure computes."""

from __future__ import annotations

import numpy as np
import pytest

from cell.evaluation.fold_success import load_success_criteria, score_fold
from cell.evaluation.ideal_fold import ideal_folds
from cell.evaluation.sim_fold import OracleHands, landmark_state, took_cloth
from cell.planning.config import load_planning_config
from cell.planning.folds import fold_moves, load_recipe
from drivers.robot.config import load_robot_config
from drivers.sim.world import GarmentWorld

pytestmark = pytest.mark.slow
SEED = 5


def first_fold(short_m: float = 0.0, release_share: float = 1.0, drag_m: float = 0.0):
    world = GarmentWorld(seed=SEED, category="towel", folding="physics")
    grasp = load_planning_config().grasp
    hands = OracleHands(world, tuple(arm.name for arm in load_robot_config().arms), grasp.height,
                        grasp.release_height)
    flat = dict(zip(*world.flat_polygon(), strict=True))
    before, _ = landmark_state(world)
    spec = load_recipe("towel").folds[0]
    landmarks = {n: (float(x), float(y)) for n, (x, y) in world.truth_landmarks().items()}
    grasps, _ = fold_moves(landmarks, spec)
    line = ideal_folds("towel", flat)[0]
    hands.fold(line, grasps, spec.lift_fraction, short_m=short_m, release_share=release_share)
    world.catch_up()
    if drag_m:
        # the side that stays, slid along the fold line's normal from its far corner
        corner = before["top-left"]
        hands.slide(corner, drag_m * np.asarray(line.normal))
        world.catch_up()
    after, area = landmark_state(world)
    return score_fold("towel", flat, world.garment.outline, 0, before, after, area, load_success_criteria(),
                      took_cloth(world, 0))


@pytest.fixture(scope="module")
def oracle():
    return first_fold()


def test_a_flap_laid_4_cm_short_is_short_by_about_that(oracle) -> None:
    short = first_fold(short_m=0.04)
    assert not short.success and short.cause == "short", short
    assert short.mean_error_m - oracle.mean_error_m == pytest.approx(0.04, abs=0.015)


def test_grippers_that_let_go_half_way_slipped(oracle) -> None:
    slipped = first_fold(release_share=0.4)
    assert not slipped.success and slipped.cause == "slipped", slipped


def test_a_base_dragged_3_cm_is_dragged(oracle) -> None:
    dragged = first_fold(drag_m=0.03)
    assert not dragged.success and dragged.cause == "dragged", dragged
    assert dragged.drift_m["top-left"] == pytest.approx(0.03, abs=0.01)
    assert oracle.drift_m["top-left"] < 0.01
