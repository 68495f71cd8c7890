"""A long-sleeve shirt laid out of reach, in the cloth physics: the planner's hands pull it towards the
robot and then fold it. The scene lies on a table deeper than the cell's, the shirt at its far end
(1.5-2.1 m from the turn-table axis); the reference for "out of reach" is the planner failing on the
shirt as laid, and for "pulled" the cloth's own vertices."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cell.evaluation.sim_fold import landmark_state, run_recipe
from cell.planning.errors import Unreachable
from cell.planning.folds import FoldPlanner
from drivers.camera.model import CameraModel, default_camera_config
from drivers.robot.config import load_robot_config
from drivers.robot.table import default_table_config
from drivers.sim.config import default_sim_config
from drivers.sim.world import GarmentWorld

pytestmark = pytest.mark.slow
SEED = 3


def far_shirt() -> tuple[GarmentWorld, FoldPlanner]:
    table = dataclasses.replace(default_table_config(), size_x=1.6)
    sim = default_sim_config()
    sim = dataclasses.replace(sim, pose=dataclasses.replace(sim.pose, cell_area=((0.85, 1.6), (0.0, 1.2))))
    camera = default_camera_config()
    pose = camera.fixed_pose_in_world.copy()
    pose[0, 3] += 0.4           # above the deep table's middle, higher up to see all of it
    pose[2, 3] += 0.8
    world = GarmentWorld(seed=SEED, category="long-sleeve", config=sim, table=table, folding="physics",
                         camera=CameraModel(camera, pose_in_world=pose, table=table))
    return world, FoldPlanner(table=table)


def test_a_long_sleeve_laid_out_of_reach_is_pulled_into_reach_and_folded() -> None:
    world, planner = far_shirt()
    laid = {name: (float(x), float(y)) for name, (x, y) in world.truth_landmarks().items()}
    with pytest.raises(Unreachable):
        planner.plan_fold("long-sleeve", 0, laid, np.asarray(load_robot_config().home, dtype=float),
                          include_perceive=False)
    before, _ = landmark_state(world)
    result = run_recipe("long-sleeve", SEED, planner, world=world)
    assert result.pulls and result.pulls[0].fold_index == 0
    # every fold was reached and done (how well the shirt folds is the measure's business)
    assert len(result.scores) == 3 and all(score.cause != "unreachable" for score in result.scores)
    assert len(world.history) == 3
    # the cloth came towards the turn-table by about the pulls' length
    after, _ = landmark_state(world)
    axis = world.table.world_to_table(np.zeros((1, 3)))[0]
    came = np.mean([np.linalg.norm(before[n][:2] - axis) - np.linalg.norm(after[n][:2] - axis)
                    for n in before])
    assert came > 0.5 * sum(pull.distance for pull in result.pulls), came
