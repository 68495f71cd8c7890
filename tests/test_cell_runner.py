"""The cell's work loop in one process: the sim camera, an in-process controller, real perception and
planning. Garments are folded through their whole recipe; failures end in `failed` with the reason."""

from __future__ import annotations

import threading
import time

import pytest

from cell.config import load_cell_config
from cell.perception.config import load_perception_config
from cell.perception.pipeline import load_garment_models, load_table_model
from cell.planning.folds import FoldPlanner
from cell.runner import CellRunner, Perception
from drivers.camera.sim import SimCamera
from drivers.controller import TrajectoryRejected
from drivers.dx100.local import LocalController
from drivers.kinematics import CellKinematics
from drivers.table_config import default_table_config


class Events:
    def __init__(self):
        self.states, self.perceptions, self.plans, self.folds = [], [], [], []

    def state_changed(self, record):
        self.states.append(record.dest if record else None)

    def perceived(self, report):
        self.perceptions.append(report)

    def planned(self, plan):
        self.plans.append(plan)

    def fold_finished(self, report):
        self.folds.append(report)


class SimBridgedController(LocalController):
    """The in-process controller whose grippers act on the simulated world, as the emulator's do over Zenoh."""

    def __init__(self, camera: SimCamera, kinematics: CellKinematics):
        super().__init__()
        self.camera = camera
        self.kinematics = kinematics

    def grip(self, arm: str, closed: bool) -> None:
        super().grip(arm, closed)
        tcp = self.kinematics.tcp_pose(self.joint_state().positions, arm)
        self.camera.gripper_event(arm, closed, tcp[:3, 3])


@pytest.fixture(scope="module")
def shared():
    pcfg = load_perception_config()
    perception = Perception(pcfg, load_table_model(None, pcfg), load_garment_models(pcfg))
    return perception, FoldPlanner(), CellKinematics()


def fold(shared, category: str, seed: int, timeout: float = 120.0, controller_type=SimBridgedController):
    perception, planner, kinematics = shared
    camera = SimCamera(seed=seed, category=category)
    camera.connect()
    controller = controller_type(camera, kinematics)
    controller.connect()
    controller.acquire_lease()
    events = Events()
    runner = CellRunner(camera, controller, planner, perception, load_cell_config(), events,
                        default_table_config(), lambda: 1.0)
    stop = threading.Event()
    worker = threading.Thread(target=runner.run, args=(stop,), daemon=True)
    worker.start()
    ok, text = runner.command("fold", category)
    assert ok, text
    deadline = time.monotonic() + timeout
    while runner.machine.state not in ("done", "failed", "fault") and time.monotonic() < deadline:
        time.sleep(0.05)
    stop.set()
    worker.join(10)
    return runner, events, controller


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
