"""The cell's work loop in one process: the sim camera, an in-process controller, real perception and
planning. Garments are folded through their whole recipe; failures end in `failed` with the reason."""

from __future__ import annotations

import pytest

from cell.perception.config import load_perception_config
from cell.perception.pipeline import load_garment_models, load_table_model
from cell.planning.folds import FoldPlanner
from cell.runner import Perception
from drivers.controller.interface import TrajectoryRejected
from drivers.robot.kinematics import CellKinematics
from drivers.sim.camera import SimCamera
from tests.cell.sim_cell import SimBridgedController, fold_in_process


@pytest.fixture(scope="module")
def shared():
    pcfg = load_perception_config()
    perception = Perception(pcfg, load_table_model(None, pcfg), load_garment_models(pcfg))
    return perception, FoldPlanner(), CellKinematics()


def fold(shared, category: str, seed: int, controller_type=SimBridgedController):  # noqa: ANN001, ANN201
    perception, planner, kinematics = shared
    run = fold_in_process(perception, planner, kinematics, category, seed, controller_type=controller_type)
    return run.runner, run.events, run.controller


@pytest.mark.parametrize("category", ["towel", "pants", "short-sleeve", "long-sleeve"])
def test_a_garment_is_folded_through_its_recipe(shared, category):
    runner, events, controller = fold(shared, category, seed=3)
    assert runner.machine.state == "done", (runner.machine.reason, events.states)
    recipe = shared[1].recipe(category)
    assert [f.outcome for f in events.folds][-len(recipe.folds):] == ["done"] * len(recipe.folds)
    world = controller.camera.world
    assert world.silhouette_iou() > 0.9
    assert len(world.history) == len(recipe.folds)


class FailsOnceHolding(SimBridgedController):
    """Refuses the first trajectory sent while a gripper is closed: a fold that stops half way,
    fingers on the cloth."""

    def __init__(self, camera: SimCamera, kinematics: CellKinematics):
        super().__init__(camera, kinematics)
        self.closed: set[str] = set()
        self.failed = False

    def grip(self, arm: str, closed: bool) -> None:
        super().grip(arm, closed)
        (self.closed.add if closed else self.closed.discard)(arm)

    def execute(self, trajectory):
        if self.closed and not self.failed:
            self.failed = True
            raise TrajectoryRejected("injected: the fold stops here", 1, 0)
        return super().execute(trajectory)


def test_a_fold_stopped_with_the_cloth_in_hand_is_retried(shared):
    runner, events, controller = fold(shared, "towel", 1, controller_type=FailsOnceHolding)
    assert controller.failed
    # the retry let go, lifted the fingers off the table, perceived again and finished the recipe
    assert runner.machine.state == "done", runner.machine.reason
    assert not controller.closed
    assert events.states.count("perceiving") > len(shared[1].recipe("towel").folds)
