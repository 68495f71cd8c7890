"""A demo run scored against the simulated world's ground truth: the observer that follows the cell
(states, perceptions with their ground truth, fold reports) and the summary of each garment it
computes. The demo (`tools/demo_cli.py`) starts the processes and prints; this says what happened.
"""

from __future__ import annotations

import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from cell.evaluation.dataset import best_naming
from drivers.common.garments import LANDMARKS
from drivers.common.outcomes import FoldOutcome, GarmentOutcome
from drivers.common.plane import signed_area
from drivers.wire import messages
from drivers.wire.transport import Wire

# the cell states that end a garment
TERMINAL_STATES = {"done": GarmentOutcome.DONE, "failed": GarmentOutcome.FAILED,
                   "fault": GarmentOutcome.FAULT}
NOTED_TRIGGERS = ("retry", "interrupt")  # steps redone on the way: notes, not the garment's failure
IOU_RESOLUTION_M = 0.001       # raster cell when comparing the final outline with the ideal fold


class Stop(Protocol):
    def is_set(self) -> bool: ...


class Processes(Protocol):
    def dead(self) -> list[str]: ...


@dataclass
class GarmentRun:
    category: str
    seed: int
    outcome: GarmentOutcome | None = None   # None while in work
    reason: str = ""   # why the garment did not end done; empty when it did
    notes: list[str] = field(default_factory=list)  # steps redone on the way, and why
    states: list[str] = field(default_factory=list)
    perceptions: list[dict] = field(default_factory=list)
    fold_reports: list[dict] = field(default_factory=list)
    final_truth: Any = None             # the last ground truth (SimTruth) once the garment ended
    truth_landmarks: dict[str, tuple[float, float]] = field(default_factory=dict)
    wall_time_s: float = 0.0
    naming: dict[str, str] | None = None   # the cell's flat landmark names -> the truth's (symmetry)


class Observer:
    """The demo's view of the cell: states, perceptions with their ground truth, fold reports."""

    def __init__(self, wire: Wire, progress: bool):
        self.wire = wire
        self.progress = progress
        self.lock = threading.Condition()
        self.state = ""
        self.state_msg: Any = None
        self.reason_shown = ""
        self.run: GarmentRun | None = None
        self.truth: Any = None
        self.truths = 0
        self.transitions_seen: set[tuple[int, str]] = set()  # (stamp, trigger) of the cell's history
        wire.subscribe("cell/state", self._on_state)
        wire.subscribe("perception/observation", self._on_observation)
        wire.subscribe("sim/truth", self._on_truth)
        wire.subscribe("cell/fold_report", self._on_report)

    def _on_state(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            changed = msg.state != self.state
            self.state, self.state_msg = msg.state, msg
            self._note_redone_steps(msg)
            if changed and self.run is not None:
                self.run.states.append(msg.state)
                if self.progress:
                    where = f" fold {msg.fold_index}/{msg.fold_count}" if msg.fold_count else ""
                    # a reason once, when it comes: the cell keeps it through the states that follow
                    why = f" ({msg.reason})" if msg.reason and msg.reason != self.reason_shown else ""
                    self.reason_shown = msg.reason
                    print(f"  [{self.run.category}]{where} {msg.state}{why}", file=sys.stderr, flush=True)
            self.lock.notify_all()

    def _note_redone_steps(self, msg: Any) -> None:
        """Each retry or interruption in the cell's history, once, as a note of the garment (those seen
        before it began are marked seen and belong to no garment)."""
        for t in msg.history:
            seen = (messages.stamp_to_ns(t.stamp), t.trigger)
            if t.trigger in NOTED_TRIGGERS and seen not in self.transitions_seen:
                self.transitions_seen.add(seen)
                if self.run is not None:
                    self.run.notes.append(f"{t.trigger} after {t.source}: {t.reason}")

    def _on_truth(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            self.truth = msg
            self.truths += 1
            self.lock.notify_all()

    def fresh_truth(self, timeout_s: float) -> Any:
        """The first ground truth published from now on (a physics world publishes once it has
        simulated what it was shown); the last one when none comes within `timeout_s`."""
        with self.lock:
            seen = self.truths
            self.lock.wait_for(lambda: self.truths > seen, timeout_s)
            return self.truth

    def _on_observation(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            if self.run is None or self.truth is None:
                return
            truth = {lm.name: (lm.x_table, lm.y_table) for lm in self.truth.landmarks}
            seen = {lm.name: (lm.x_table, lm.y_table) for lm in msg.landmarks}
            flat = LANDMARKS[self.run.category]
            if self.run.naming is None and all(n in seen and n in truth for n in flat):
                # a towel turned by 180 degrees looks the same: the cell's naming of the flat garment
                # is scored as the symmetry that fits best, and its names keep that meaning after folds
                self.run.naming = best_naming(seen, truth, flat, self.run.category, facing_known=True)
            naming = self.run.naming or {}
            errors = {name: float(np.hypot(x - truth[naming.get(name, name)][0],
                                           y - truth[naming.get(name, name)][1]))
                      for name, (x, y) in seen.items() if naming.get(name, name) in truth}
            self.run.perceptions.append({
                "fold_index": int(msg.fold_index), "cost": float(msg.cost),
                "landmark_error_cm": {k: round(v * 100, 3) for k, v in errors.items()},
                "median_error_cm": (round(float(np.median(list(errors.values()))) * 100, 3)
                                    if errors else None),
                "timings_ms": {t.stage: round(t.seconds * 1e3, 2) for t in msg.timings}})

    def _on_report(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            if self.run is not None:
                self.run.fold_reports.append({
                    "fold_index": int(msg.fold_index), "attempt": int(msg.attempt),
                    "outcome": FoldOutcome.of_wire(msg.outcome), "cause": msg.cause,
                    "verify_iou": round(float(msg.verify_iou), 4),
                    "robot_time_s": round(float(msg.robot_time), 2),
                    "timings_s": {t.stage: round(t.seconds, 4) for t in msg.timings}})

    def begin(self, run: GarmentRun) -> None:
        with self.lock:
            self.run, self.truth = run, None

    def wait_state(self, state: str, timeout: float) -> bool:
        """Until the cell reports `state` (True), or `timeout` s pass."""
        with self.lock:
            return self.lock.wait_for(lambda: self.state == state, timeout)

    def wait_terminal(self, timeout: float, stop: Stop, processes: Processes) -> tuple[GarmentOutcome, str]:
        """How the garment ended and why ('' for one done): the cell's own reason, or the demo's."""
        deadline = time.monotonic() + timeout
        with self.lock:
            while self.state not in TERMINAL_STATES:
                if stop.is_set():
                    return GarmentOutcome.INTERRUPTED, "stopped by the operator while it was in work"
                if processes.dead():
                    return GarmentOutcome.ERROR, f"process {', '.join(processes.dead())} exited"
                if time.monotonic() > deadline:
                    return GarmentOutcome.TIMEOUT, f"not ended within {timeout:g} s"
                self.lock.wait(0.2)
            outcome = TERMINAL_STATES[self.state]
            # a reason left from a retried step is a note, not a failure
            done = outcome is GarmentOutcome.DONE or self.state_msg is None
            reason = "" if done else str(self.state_msg.reason)
            return outcome, reason


def _flat_garment(truth: Any) -> tuple[dict[str, tuple[float, float]], np.ndarray]:
    """The flat garment a SimTruth carries: its landmarks and outline, table frame (m)."""
    return ({lm.name: (lm.x_table, lm.y_table) for lm in truth.flat_landmarks},
            np.array([[p.x, p.y] for p in truth.flat_outline_table]))


def final_iou(category: str, truth: Any) -> float:
    """IoU of the garment's outline in the ground truth `truth` (a SimTruth) with its flat garment,
    as laid (and moved by any pull), folded perfectly by the whole recipe."""
    from cell.evaluation.ideal_fold import ideal_fold_iou, ideal_folds

    landmarks, flat_outline = _flat_garment(truth)
    silhouette = np.array([[p.x, p.y] for p in truth.silhouette_table])
    every_fold = len(ideal_folds(category, landmarks))
    return ideal_fold_iou(category, landmarks, flat_outline, every_fold, [silhouette], IOU_RESOLUTION_M)


def fold_success(category: str, truth: Any) -> dict | None:
    """The fold-success measure of the whole recipe (cell/evaluation/fold_success.py) on the ground
    truth `truth` (a SimTruth): where the garment's landmarks lie against the open-loop ideal, and its
    area. None where the world does not follow landmarks through the cloth (the geometric world)."""
    from cell.evaluation.fold_success import load_success_criteria, score_recipe

    if not truth.landmark_vertex_names:
        return None
    flat, flat_outline = _flat_garment(truth)
    after = {name: (p.x, p.y)
             for name, p in zip(truth.landmark_vertex_names, truth.landmark_vertices, strict=True)}
    area = abs(signed_area(np.array([[p.x, p.y] for p in truth.silhouette_table])))
    score = score_recipe(category, flat, flat_outline, after, area, load_success_criteria())
    return {"success": score.success, "cause": score.cause, "detail": score.detail,
            "landmark_error_cm_max": round(score.max_error_m * 100, 2),
            "landmark_error_cm_mean": round(score.mean_error_m * 100, 2),
            "area_ratio": round(score.area_ratio, 3)}


def summarise(run: GarmentRun) -> dict:
    # the last report of each fold says how it ended; a fold done imperfectly is done (the garment went
    # on from it) and counted apart as well
    last = {r["fold_index"]: r["outcome"] for r in run.fold_reports}
    folds_done = sum(1 for outcome in last.values() if outcome is not None and outcome.completed)
    folds_imperfect = sum(1 for outcome in last.values() if outcome is FoldOutcome.IMPERFECT)
    iou = None
    iou_note = ""
    measure = None
    if run.final_truth is not None:
        try:
            iou = round(final_iou(run.category, run.final_truth), 4)
            if run.outcome is GarmentOutcome.DONE:
                measure = fold_success(run.category, run.final_truth)
        except ValueError as exc:  # the ideal fold is not defined on this garment
            iou_note = f"no ideal fold to compare with: {exc}"
    stage_totals: dict[str, float] = {}
    for r in run.fold_reports:
        for k, v in r["timings_s"].items():
            stage_totals[k] = stage_totals.get(k, 0.0) + v
    errors = [p["median_error_cm"] for p in run.perceptions if p["median_error_cm"] is not None]
    return {
        "garment": run.category, "seed": run.seed, "outcome": run.outcome, "reason": run.reason,
        "notes": list(run.notes),
        "folds_done": folds_done, "folds_imperfect": folds_imperfect, "final_iou": iou,
        **({"final_iou_note": iou_note} if iou_note else {}),
        "fold_success": measure,
        "landmark_error_cm": {"per_perception_median": errors,
                              "median": round(float(np.median(errors)), 3) if errors else None},
        "compute_s": {k: round(v, 3) for k, v in stage_totals.items() if k != "execute"},
        "robot_time_s": round(sum(r["robot_time_s"] for r in run.fold_reports), 2),
        "wall_time_s": round(run.wall_time_s, 1), "states": run.states,
        "perceptions": run.perceptions, "folds": run.fold_reports,
    }
