"""What the cell reports as it works: perceptions, fold outcomes, and the sink they go to."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from cell.perception.pipeline import Observation
from cell.planning.folds import FoldPlan
from drivers.camera.base import Frame
from drivers.camera.model import CameraModel
from drivers.common.landmarks import Landmarks
from drivers.common.outcomes import FoldOutcome
from statemachine.machine import TransitionRecord


@dataclass(frozen=True)
class PerceptionReport:
    """One perception: the pipeline's observation of an image, where the job stands, and the named
    landmarks on the table (m)."""

    category: str
    fold_index: int                          # folds done before this image
    frame: Frame
    camera: CameraModel                      # the camera as it was for this image (pixels <-> table)
    observation: Observation
    landmarks_table: Landmarks               # table frame
    purpose: str                             # perceive | verify

    @property
    def polygon_px(self) -> np.ndarray:
        return self.observation.polygon

    @property
    def landmarks_px(self) -> Landmarks:
        return self.observation.landmarks

    @property
    def cost(self) -> float:
        return self.observation.cost

    @property
    def timings_s(self) -> dict[str, float]:
        return self.observation.timings_s


@dataclass(frozen=True)
class FoldReport:
    category: str
    fold_index: int
    attempt: int
    outcome: FoldOutcome
    cause: str                               # why it was imperfect or failed ('' when done)
    verify_iou: float
    timings_s: dict[str, float]              # perception, planning, execution...
    robot_time_s: float


class CellEvents(Protocol):
    def state_changed(self, record: TransitionRecord | None) -> None: ...
    def perceived(self, report: PerceptionReport) -> None: ...
    def planned(self, plan: FoldPlan) -> None: ...
    def fold_finished(self, report: FoldReport) -> None: ...
    def fault_cause(self, reason: str) -> str:
        """The reason a fault is kept with: `reason`, or what the process itself went through that
        explains it better (it was stopped, so its requests timed out and its peers lost sight of it)."""
        ...
