"""The cell's work loop in one process, on the simulated world: shared by the cell tests and the
cell benchmark. The sim camera, an in-process controller whose grippers act on the sim's cloth (TCP
from forward kinematics), real perception and planning, the real `CellRunner`."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from cell.config import load_cell_config
from cell.reports import FoldReport
from cell.runner import CellRunner, Perception
from drivers.emulator.local import LocalController
from drivers.robot.kinematics import CellKinematics
from drivers.robot.table import default_table_config
from drivers.sim.camera import SimCamera

END_STATES = ("done", "failed", "fault")


class RecordingEvents:
    """A `CellEvents` sink that keeps everything the cell reports."""

    def __init__(self) -> None:
        self.states: list[str | None] = []
        self.perceptions: list = []
        self.plans: list = []
        self.folds: list[FoldReport] = []

    def state_changed(self, record) -> None:
        self.states.append(record.dest if record else None)

    def perceived(self, report) -> None:
        self.perceptions.append(report)

    def planned(self, plan) -> None:
        self.plans.append(plan)

    def fold_finished(self, report: FoldReport) -> None:
        self.folds.append(report)

    def fault_cause(self, reason: str) -> str:
        return reason


class SimBridgedController(LocalController):
    """The in-process controller whose grippers act on the simulated world, as the emulator's do."""

    def __init__(self, camera: SimCamera, kinematics: CellKinematics):
        super().__init__()
        self.camera = camera
        self.kinematics = kinematics
        self.grasps: list = []

    def grip(self, arm: str, closed: bool) -> None:
        super().grip(arm, closed)
        tcp = self.kinematics.tcp_pose(self.joint_state().positions, arm)[:3, 3]
        result = self.camera.gripper_event(arm, closed, self._world_position(arm, closed, tcp))
        if result is not None:
            self.grasps.append(result)

    def _world_position(self, arm: str, closed: bool, tcp: np.ndarray) -> np.ndarray:
        """Where the world sees the gripper act: at its TCP (tests change this to inject faults)."""
        return tcp


@dataclass
class InProcessFold:
    runner: CellRunner
    events: RecordingEvents
    controller: SimBridgedController
    state: str                      # done | failed | fault | timeout


def fold_in_process(perception: Perception, planner, kinematics: CellKinematics, category: str,
                    seed: int, timeout_s: float = 120.0,
                    controller_type: type[SimBridgedController] = SimBridgedController) -> InProcessFold:
    """Fold the garment of (category, seed) through its recipe; returns when the cell ends or times out."""
    # the geometric world: these folds test the cell's logic, and the controller here moves the
    # grippers by events without a recorded path for the cloth physics to follow
    camera = SimCamera(seed=seed, category=category, folding="geometric")
    camera.connect()
    controller = controller_type(camera, kinematics)
    controller.connect()
    controller.acquire_lease()
    events = RecordingEvents()
    runner = CellRunner(camera, controller, planner, perception, load_cell_config(), events,
                        default_table_config(), lambda: 1.0)
    stop = threading.Event()
    worker = threading.Thread(target=runner.run, args=(stop,), daemon=True)
    worker.start()
    try:
        ok, text = runner.command("fold", category)
        if not ok:
            raise RuntimeError(f"fold {category} seed {seed} refused: {text}")
        deadline = time.monotonic() + timeout_s
        while runner.machine.state not in END_STATES and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        stop.set()
        worker.join(10)
    state = runner.machine.state if runner.machine.state in END_STATES else "timeout"
    return InProcessFold(runner, events, controller, state)
