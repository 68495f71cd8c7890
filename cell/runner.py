"""The cell's work loop: the state machine's steps done with a camera, perception, planning and a controller.

No Zenoh here: the devices come in as the `Camera` and `Controller` interfaces and everything the
cell reports goes to a `CellEvents` sink, so the loop runs the same against the emulator over Zenoh
(the daemon), an in-process controller (tests) or real hardware.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import cv2
import numpy as np

from cell.config import CellConfig
from cell.perception.config import PerceptionConfig
from cell.perception.errors import PerceptionError
from cell.perception.folded import derive_folded_model, folded_polygon
from cell.perception.geometry import polygon_edge_lengths
from cell.perception.models import PolygonalModel
from cell.perception.pipeline import Observation, Outline, extract_outline, match_outline
from cell.perception.table_model import TableModel
from cell.planning.errors import PlanningError, PlanningInputError, Unreachable
from cell.planning.folds import FoldPlan, FoldPlanner, GripperAction
from cell.planning.trajectory import PlannedTrajectory
from drivers.camera.base import Camera, Frame
from drivers.camera.errors import CameraError
from drivers.camera.model import CameraModel
from drivers.controller.codes import Command, Subcode
from drivers.controller.errors import ControllerError, ControllerGone, ControllerTimeout
from drivers.controller.interface import Controller, MotionStatus
from drivers.robot.table import TableConfig
from statemachine.machine import WORK_STATES, CellMachine, InvalidCommand, TransitionRecord

log = logging.getLogger(__name__)

COMMANDS = ("fold", "pause", "resume", "abort", "status", "reset")


# --------------------------------------------------------------------------------- what the cell reports
@dataclass(frozen=True)
class PerceptionReport:
    """One perception: the pipeline's observation of an image, where the job stands, and the named
    landmarks on the table (m)."""

    category: str
    fold_index: int                          # folds done before this image
    frame: Frame
    observation: Observation
    landmarks_table: dict[str, tuple[float, float]]
    purpose: str                             # perceive | verify

    @property
    def polygon_px(self) -> np.ndarray:
        return self.observation.polygon

    @property
    def landmarks_px(self) -> dict[str, tuple[float, float]]:
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
    outcome: str                             # done | failed: reason
    verify_iou: float
    timings_s: dict[str, float]              # perception, planning, execution...
    robot_time_s: float


class CellEvents(Protocol):
    def state_changed(self, record: TransitionRecord | None) -> None: ...
    def perceived(self, report: PerceptionReport) -> None: ...
    def planned(self, plan: FoldPlan) -> None: ...
    def fold_finished(self, report: FoldReport) -> None: ...


class StepFailed(Exception):
    def __init__(self, reason: str, retryable: bool = True):
        super().__init__(reason)
        self.reason = reason
        self.retryable = retryable


class StepInterrupted(Exception):
    """The robot stopped under the step (e-stop, hold, the operator): the machine already knows."""


class CameraFault(Exception):
    pass


# --------------------------------------------------------------------------------- geometry helpers
def _raster(polygons: list[np.ndarray], lo: np.ndarray, size: np.ndarray, resolution: float) -> np.ndarray:
    mask = np.zeros((size[1], size[0]), np.uint8)
    for poly in polygons:
        cv2.fillPoly(mask, [np.round((poly - lo) / resolution).astype(np.int32)], 1)
    return mask.astype(bool)


def polygon_iou(a: np.ndarray, b: np.ndarray, resolution: float) -> float:
    """IoU of two polygons (same units) rasterised at `resolution` units per cell."""
    pts = np.vstack([a, b])
    lo = pts.min(axis=0) - resolution
    size = np.ceil((pts.max(axis=0) + resolution - lo) / resolution).astype(int) + 1
    ma, mb = _raster([a], lo, size, resolution), _raster([b], lo, size, resolution)
    union = np.logical_or(ma, mb).sum()
    return float(np.logical_and(ma, mb).sum() / union) if union else 0.0


def folded_outline_iou(before: np.ndarray, after: np.ndarray, line_point: np.ndarray, line_normal: np.ndarray,
                       resolution: float) -> float:
    """IoU of the outline seen after a fold against the one seen before, folded ideally along the line.

    The part of `before` behind the line (against `line_normal`) is reflected across it and laid on
    the rest: what a perfect fold shows, sleeves sticking out and all.
    """
    pts = np.vstack([before, after, before - 2.0 * ((before - line_point) @ line_normal)[:, None] * line_normal])
    lo = pts.min(axis=0) - resolution
    size = np.ceil((pts.max(axis=0) + resolution - lo) / resolution).astype(int) + 1
    prev = _raster([before], lo, size, resolution)
    ys, xs = np.nonzero(prev)
    cells = np.column_stack([xs, ys]) * resolution + lo
    side = (cells - line_point) @ line_normal
    moving = side < 0
    expected = np.zeros_like(prev)
    expected[ys[~moving], xs[~moving]] = True
    flipped = cells[moving] - 2.0 * side[moving][:, None] * line_normal
    idx = np.round((flipped - lo) / resolution).astype(int)
    ok = (idx[:, 0] >= 0) & (idx[:, 0] < size[0]) & (idx[:, 1] >= 0) & (idx[:, 1] < size[1])
    expected[idx[ok, 1], idx[ok, 0]] = True
    expected = cv2.morphologyEx(expected.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)).astype(bool)
    seen = _raster([after], lo, size, resolution)
    union = np.logical_or(expected, seen).sum()
    return float(np.logical_and(expected, seen).sum() / union) if union else 0.0


# --------------------------------------------------------------------------------- the garment being folded
@dataclass
class GarmentContext:
    category: str
    model: PolygonalModel                     # the model to match next (folded after each fold)
    flat_model: PolygonalModel
    observation: PerceptionReport | None = None
    frame: Frame | None = None                # the last image taken and the garment's outline in it
    outline: Outline | None = None
    plan: FoldPlan | None = None
    fresh: bool = False                       # the observation was taken since the last motion
    timings: dict[str, float] = field(default_factory=dict)
    robot_time: float = 0.0
    previous_model: PolygonalModel | None = None
    expected_table: dict[str, np.ndarray] | None = None  # where each landmark should be after the last fold (m)
    steps_done: set[int] = field(default_factory=set)  # indices of the plan's steps already executed


@dataclass(frozen=True)
class Perception:
    """What perception needs, loaded once."""

    config: PerceptionConfig
    table_model: TableModel
    models: dict[str, PolygonalModel]


class CellRunner:
    """Runs the state machine's steps. Thread-safe: commands come from other threads."""

    def __init__(self, camera: Camera, controller: Controller, planner: FoldPlanner, perception: Perception,
                 config: CellConfig, events: CellEvents, table: TableConfig, time_scale: Callable[[], float]):
        self.camera = camera
        self.controller = controller
        self.planner = planner
        self.perception = perception
        self.config = config
        self.events = events
        self.table = table
        self.time_scale = time_scale
        self.machine = CellMachine(config.max_attempts)
        self.machine.listeners.append(self._on_transition)
        self.lock = threading.RLock()
        self.wake = threading.Condition(self.lock)
        self.garment: GarmentContext | None = None
        self.stopping = threading.Event()

    # ---------------------------------------------------------------- commands (any thread)
    def command(self, command: str, argument: str = "") -> tuple[bool, str]:
        """Run an operator command; returns (accepted, text)."""
        with self.lock:
            try:
                if command == "fold":
                    self._prepare_controller()
                    return True, self._start(argument)
                if command == "pause":
                    return True, self.machine.request_pause()
                if command == "resume":
                    if self.machine.state != "paused":
                        raise InvalidCommand(f"resume is not allowed in state {self.machine.state}")
                    self._prepare_controller()
                    self.machine.resume_job()
                    self.wake.notify_all()
                    return True, f"resumed: {self.machine.state}"
                if command == "abort":
                    self.machine.abort_job()
                    self.stop_robot()
                    return True, "aborted; the robot stops"
                if command == "reset":
                    if self.machine.state == "paused":
                        return True, self._reset_controller()
                    self.machine.reset_cell()
                    self.garment = None
                    return True, "reset: idle"
                if command == "status":
                    return True, self.describe()
            except (InvalidCommand, ControllerError) as exc:
                return False, str(exc)
        return False, f"unknown command {command!r} (commands: {', '.join(COMMANDS)})"

    def _reset_controller(self) -> str:
        """Paused by an e-stop or an alarm: clear it (the cell holds the lease); `resume` goes on."""
        status = self.controller.status()
        done = []
        if status.e_stopped:
            self.controller.command(Command.ESTOP_RESET)
            done.append("e-stop reset")
        if status.in_error:
            self.controller.command(Command.RESET_ALARM)
            done.append("alarm reset")
        deadline = time.monotonic() + self.config.reply_timeout_s
        while done and time.monotonic() < deadline:  # the status stream catches up with the commands
            status = self.controller.status()
            if not status.e_stopped and not status.in_error:
                break
            time.sleep(0.01)
        return (", ".join(done) or "nothing to reset") + "; resume to continue"

    def _prepare_controller(self) -> None:
        """Servos on and trajectory mode, unless an e-stop or an alarm needs the operator first."""
        status = self.controller.status()
        if status.e_stopped:
            raise InvalidCommand("the e-stop is engaged: reset it first (cell command reset)")
        if status.in_error:
            raise InvalidCommand(f"controller alarm {status.error_code} ({status.alarm_text}): reset it first")
        if not status.motion_possible:
            self.controller.command(Command.START_TRAJ_MODE)

    def _start(self, category: str) -> str:
        if category not in self.perception.models:
            raise InvalidCommand(f"fold: unknown garment category {category!r} "
                                 f"(known: {', '.join(sorted(self.perception.models))})")
        recipe = self.planner.recipe(category)
        model = self.perception.models[category]
        self.garment = GarmentContext(category, model, model)
        self.machine.start_job(category, len(recipe.folds))
        self.wake.notify_all()
        return f"folding {category}: {len(recipe.folds)} fold(s)"

    def fault(self, reason: str) -> None:
        """A needed process vanished, an alarm, a camera timeout: stop and keep the reason."""
        with self.lock:
            if self.machine.state in ("fault", "done", "failed"):
                return  # already stopped for a reason worth keeping
            try:
                self.machine.raise_fault(reason)
            except InvalidCommand:
                return
            log.error("fault: %s", reason)
        self.stop_robot()

    def interrupt(self, reason: str) -> None:
        """The robot was stopped under a step (e-stop): pause; resume redoes the step."""
        with self.lock:
            if self.machine.state not in WORK_STATES:
                return
            self.machine.interrupt_step(reason)
            log.warning("interrupted: %s", reason)

    def describe(self) -> str:
        m = self.machine
        if m.job is None:
            return f"{m.state}"
        return (f"{m.state}: {m.job.category} fold {m.job.fold_index}/{m.job.fold_count} "
                f"attempt {m.job.attempt}" + (f" ({m.reason})" if m.reason else ""))

    def _on_transition(self, record: TransitionRecord) -> None:
        log.info("%s: %s -> %s%s", record.trigger, record.source, record.dest,
                 f" ({record.reason})" if record.reason else "")
        self.events.state_changed(record)

    def stop_robot(self) -> None:
        """Stop every axis now (abort, fault); a controller that does not answer is only logged."""
        try:
            self.controller.stop()
        except ControllerError as exc:
            log.warning("stop: %s", exc)

    # ---------------------------------------------------------------- the work loop (its own thread)
    def run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            with self.lock:
                state = self.machine.state
                garment = self.garment
                if state not in WORK_STATES or garment is None:
                    self.wake.wait(0.1)
                    continue
                fold_index = self.machine.job.fold_index
            try:
                self._do_step(garment, state, fold_index)
            except StepInterrupted:
                continue
            except CameraFault as exc:
                self.fault(f"camera: {exc}")
            except StepFailed as exc:
                self._fail_step(state, exc)
            except Exception as exc:  # a bug must leave the cell in a known state, not a dead thread
                log.exception("step %s crashed", state)
                self.fault(f"internal error in {state}: {type(exc).__name__}: {exc}")

    def _fail_step(self, state: str, exc: StepFailed) -> None:
        with self.lock:
            if self.machine.state != state:
                return  # aborted or faulted meanwhile
            log.warning("%s failed: %s", state, exc.reason)
            record = self.machine.step_failed(exc.reason, exc.retryable)
            g = self.garment
            if g is not None:
                if record.dest == "failed":
                    self.events.fold_finished(self._fold_report(g, f"failed: {exc.reason}", 0.0))
                g.fresh = False
                if g.previous_model is not None and state == "verifying":
                    # the fold did not take (a missed grasp leaves the garment as it was): redo it
                    g.model = g.previous_model
                    g.expected_table = None

    def _advance(self, state: str, trigger: str, reason: str = "") -> None:
        with self.lock:
            if self.machine.state == state:
                self.machine.step_done(trigger, reason)

    def _do_step(self, g: GarmentContext, state: str, fold_index: int) -> None:
        """One step on the garment `g` (a reference taken under the lock: a reset may drop it meanwhile)."""
        if state == "perceiving":
            self._perceive(g, fold_index)
            self._advance(state, "perceived")
        elif state == "matching":
            self._match(g, fold_index, purpose="perceive")
            self._advance(state, "matched", f"cost {g.observation.cost:.1f}")
        elif state == "planning":
            self._plan(g, fold_index)
            self._advance(state, "planned", f"{g.plan.fold_name}: {g.plan.robot_time:.1f} s of motion")
        elif state == "grasping":
            self._execute(g, grasp_phase=True)
            self._advance(state, "grasped")
        elif state == "folding":
            self._execute(g, grasp_phase=False)
            self._advance(state, "folded")
        elif state == "verifying":
            iou = self._verify(g, fold_index)
            outcome = "done" if iou >= self.config.verify_min_iou else f"done, imperfect (IoU {iou:.2f})"
            self.events.fold_finished(self._fold_report(g, outcome, iou))
            g.timings = {}
            g.robot_time = 0.0
            self._advance(state, "verified", f"fold {fold_index}: outline IoU {iou:.3f}")

    def _fold_report(self, g: GarmentContext, outcome: str, iou: float) -> FoldReport:
        job = self.machine.job
        fold_index, attempt = (job.fold_index, job.attempt) if job is not None else (0, 0)
        return FoldReport(g.category, fold_index, attempt, outcome, iou, dict(g.timings), g.robot_time)

    # ---------------------------------------------------------------- steps
    def _capture(self) -> Frame:
        t0 = time.perf_counter()
        try:
            frame = self.camera.capture()
        except CameraError as exc:
            raise CameraFault(str(exc)) from exc
        if time.perf_counter() - t0 > self.config.camera_timeout_s:
            raise CameraFault(f"capture took {time.perf_counter() - t0:.1f} s")
        return frame

    def _perceive(self, g: GarmentContext, fold_index: int) -> None:
        if g.fresh and g.observation is not None:
            return  # the verification image of the last fold shows the garment as it is now
        self._to_perceiving_configuration()
        frame = self._capture()
        try:
            outline = extract_outline(frame.image, self.perception.table_model, self.perception.config,
                                      [g.model])
        except PerceptionError as exc:
            raise StepFailed(f"perception: {exc}") from exc
        g.frame, g.outline = frame, outline
        for stage, seconds in outline.timings_s.items():
            g.timings[stage] = g.timings.get(stage, 0.0) + seconds

    def _to_perceiving_configuration(self) -> None:
        """Arms clear of the table and the camera's view (a wrist camera then looks at the table)."""
        motion = self.planner.motion
        here = self.controller.joint_state().positions
        goal = motion.perceive.copy()
        goal[motion.ext_index] = here[motion.ext_index]
        if float(np.max(np.abs(here - goal))) <= self.config.rejoin_tolerance_rad:
            return
        if not motion.valid(here):
            # a fold stopped half way (fingers on the cloth): let go and lift before moving away
            for arm in motion.arm_indices:
                try:
                    self.controller.grip(arm, False)
                except ControllerError as exc:
                    self._motion_failed(f"gripper {arm} open: {exc}", exc)
            try:
                self._run_trajectory(motion.lift_move(here))
            except PlanningError as exc:
                raise StepFailed(f"no way out of the fold that stopped: {exc}", retryable=False) from exc
            here = self.controller.joint_state().positions
        try:
            trajectory = motion.perceive_move(here)
        except PlanningError as exc:
            raise StepFailed(f"no way to the perceiving configuration: {exc}", retryable=False) from exc
        self._run_trajectory(trajectory)

    def _match(self, g: GarmentContext, fold_index: int, purpose: str) -> PerceptionReport:
        if g.fresh and g.observation is not None:
            g.fresh = False
            return g.observation
        assert g.frame is not None and g.outline is not None   # perceiving comes first
        camera = CameraModel.from_info(g.frame.info, self.table)
        expected_px = None
        if g.expected_table is not None:
            names = list(g.expected_table)
            pixels = camera.table_to_pixel(np.array([g.expected_table[n] for n in names]))
            expected_px = dict(zip(names, pixels))
        try:
            observation = match_outline(g.outline, {g.category: g.model}, self.perception.config, expected_px)
        except PerceptionError as exc:
            raise StepFailed(f"matching: {exc}") from exc
        g.timings["match"] = g.timings.get("match", 0.0) + observation.timings_s["match"]
        names = list(observation.landmarks)
        table_xy = camera.pixel_to_table(np.array([observation.landmarks[n] for n in names], dtype=float))
        report = PerceptionReport(g.category, fold_index - 1, g.frame, observation,
                                  {n: (float(x), float(y)) for n, (x, y) in zip(names, table_xy)}, purpose)
        g.observation = report
        self.events.perceived(report)
        return report

    def _plan(self, g: GarmentContext, fold_index: int) -> None:
        q = self.controller.joint_state().positions
        t0 = time.perf_counter()
        try:
            plan = self.planner.plan_fold(g.category, fold_index - 1, g.observation.landmarks_table, q)
        except Unreachable as exc:
            raise StepFailed(f"unreachable: {exc}", retryable=False) from exc
        except PlanningInputError as exc:  # the recipe does not fit what was seen: a retry sees the same
            raise StepFailed(f"planning: {exc}", retryable=False) from exc
        except PlanningError as exc:
            raise StepFailed(f"planning: {exc}") from exc
        g.timings["plan"] = g.timings.get("plan", 0.0) + time.perf_counter() - t0
        g.plan = plan
        g.steps_done = set()
        self.events.planned(plan)

    def _execute(self, g: GarmentContext, grasp_phase: bool) -> None:
        """Grasp phase: the plan's steps up to the last gripper close; fold phase: the rest.

        Steps already done are skipped, so a phase redone after an e-stop goes on where it stopped;
        a trajectory cut short is rejoined from wherever the robot stands.
        """
        steps = list(g.plan.steps)
        last_close = max((i for i, s in enumerate(steps) if isinstance(s, GripperAction) and s.action == "close"),
                         default=-1)
        indices = range(0, last_close + 1) if grasp_phase else range(last_close + 1, len(steps))
        g.fresh = False
        t0 = time.perf_counter()
        for index in indices:
            if index in g.steps_done:
                continue
            step = steps[index]
            self._check_still(grasp_phase)
            if isinstance(step, GripperAction):
                try:
                    self.controller.grip(step.arm, step.action == "close")
                except ControllerError as exc:
                    self._motion_failed(f"gripper {step.arm} {step.action}: {exc}", exc)
            else:
                self._rejoin(step)
                self._run_trajectory(step)
            g.steps_done.add(index)
        g.timings["execute"] = g.timings.get("execute", 0.0) + time.perf_counter() - t0

    def _rejoin(self, trajectory: PlannedTrajectory) -> None:
        """Move to the trajectory's first point if the robot is not there (it stopped under a motion)."""
        start = np.asarray(trajectory.positions[0], dtype=float)
        here = self.controller.joint_state().positions
        if float(np.max(np.abs(here - start))) <= self.config.rejoin_tolerance_rad:
            return
        log.info("rejoining %s: the robot is %.3f rad away from its start", trajectory.label,
                 float(np.max(np.abs(here - start))))
        try:
            handle = self.controller.move_to(start)
        except ControllerError as exc:
            self._motion_failed(f"rejoin {trajectory.label}: {exc}", exc)
        if handle.wait(self.config.motion_timeout_margin_s * 4) != MotionStatus.SUCCEEDED:
            self._motion_failed(f"rejoin {trajectory.label} did not finish")

    def _check_still(self, grasp_phase: bool) -> None:
        with self.lock:
            expected = "grasping" if grasp_phase else "folding"
            if self.machine.state != expected:
                raise StepInterrupted()

    def _run_trajectory(self, trajectory: PlannedTrajectory) -> None:
        try:
            handle = self.controller.execute(trajectory)
        except ControllerError as exc:
            self._motion_failed(f"trajectory {trajectory.label or ''} rejected: {exc}", exc)
        scale = max(self.time_scale(), 1e-6)
        timeout = (trajectory.duration / scale * self.config.motion_timeout_factor
                   + self.config.motion_timeout_margin_s)
        status = handle.wait(timeout)
        if status == MotionStatus.SUCCEEDED:
            # a gripper acts next: be sure the feedback is at the end point, not only the controller's word
            end = np.asarray(trajectory.positions[-1], dtype=float)
            deadline = time.monotonic() + self.config.motion_timeout_margin_s
            tolerance = self.config.rejoin_tolerance_rad
            while float(np.max(np.abs(self.controller.joint_state().positions - end))) > tolerance:
                if time.monotonic() > deadline:
                    self._motion_failed(f"motion {trajectory.label} reported done away from its end point")
                time.sleep(0.005)
            garment = self.garment
            if garment is not None:
                garment.robot_time += trajectory.duration
            return
        if status == MotionStatus.RUNNING:
            handle.cancel()
            self._motion_failed(f"motion {trajectory.label} did not finish within {timeout:.1f} s")
        self._motion_failed(f"motion {trajectory.label} {status.value}")

    def _motion_failed(self, reason: str, error: ControllerError | None = None) -> None:
        """A motion ended badly: an e-stop pauses the cell, an alarm faults it, else the step fails."""
        try:
            status = self.controller.status()
        except ControllerError:
            status = None
        with self.lock:
            if self.machine.state not in WORK_STATES:
                raise StepInterrupted()
        if isinstance(error, (ControllerGone, ControllerTimeout)):
            # the controller is not answering: a fault, not a step to retry (its token may not be gone yet)
            self.fault(f"controller: {error}")
            raise StepInterrupted()
        # the reply may say e-stop before the status stream does
        stopped_by = {Subcode.NOT_READY_ESTOP: "e-stop", Subcode.NOT_READY_HOLD: "hold"}.get(
            getattr(error, "subcode", 0), "")
        if status is not None and (status.e_stopped or status.held):
            stopped_by = "e-stop" if status.e_stopped else "hold"
        if stopped_by:
            self.interrupt(stopped_by)
            raise StepInterrupted()
        if status is not None and status.in_error:
            self.fault(f"controller alarm {status.error_code}: {status.alarm_text}")
            raise StepInterrupted()
        raise StepFailed(reason)

    def _verify(self, g: GarmentContext, fold_index: int) -> float:
        plan, before = g.plan, g.observation
        camera = CameraModel.from_info(before.frame.info, self.table)
        grasp_px = camera.table_to_pixel(np.array(plan.grasp_points[:1]))[0]
        place_px = camera.table_to_pixel(np.array(plan.place_points[:1]))[0]
        model_order = [before.landmarks_px[n] for n in g.model.names]
        try:
            folded = derive_folded_model(g.model, np.array(model_order), (grasp_px, place_px), fold_index,
                                         self.perception.config.merge_fraction)
        except PerceptionError as exc:
            raise StepFailed(f"folded model: {exc}") from exc
        g.previous_model, g.model = g.model, folded
        before_px = np.array(model_order)
        perimeter = float(polygon_edge_lengths(before_px).sum())
        try:
            exp_poly, exp_names = folded_polygon(before_px, list(g.previous_model.names),
                                                 grasp_px, place_px, fold_index,
                                                 self.perception.config.merge_fraction * perimeter)
            g.expected_table = dict(zip(exp_names, camera.pixel_to_table(np.asarray(exp_poly, float))))
        except PerceptionError:
            g.expected_table = None
        before_table = camera.pixel_to_table(g.outline.contour.astype(float))
        self._perceive(g, fold_index + 1)
        g.fresh = False
        report = self._match(g, fold_index + 1, purpose="verify")
        after_camera = CameraModel.from_info(report.frame.info, self.table)
        after_table = after_camera.pixel_to_table(g.outline.contour.astype(float))
        iou = folded_outline_iou(before_table, after_table, np.asarray(plan.fold_line.point),
                                 np.asarray(plan.fold_line.normal), self.config.verify_resolution_m)
        if iou < self.config.verify_min_iou:
            unchanged = polygon_iou(before_table, after_table, self.config.verify_resolution_m)
            if unchanged >= self.config.unchanged_min_iou:
                # nothing moved (a grasp that took no cloth): the same fold can simply be tried again
                raise StepFailed(f"fold {fold_index} did not take: the outline is unchanged "
                                 f"(IoU {unchanged:.2f} with the one before)")
            # the cloth moved, not as planned; it cannot be unfolded, so go on from what is seen
            log.warning("fold %d differs from the planned fold (outline IoU %.2f < %.2f); going on from the "
                        "garment as it lies", fold_index, iou, self.config.verify_min_iou)
        g.fresh = True  # the next fold plans from this image
        g.previous_model = None
        log.info("fold %d checked: IoU %.3f, matched cost %.1f", fold_index, iou, report.cost)
        return iou
