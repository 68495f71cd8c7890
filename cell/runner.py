"""The cell's work loop: the state machine's steps done with a camera, perception, planning and a controller.

No Zenoh here: the devices come in as the `Camera` and `Controller` interfaces and everything the
cell reports goes to a `CellEvents` sink, so the loop runs the same against the emulator over Zenoh
(the daemon), an in-process controller (tests) or real hardware. The motions and what their failures
mean are `cell.execution`'s; the check after each fold is `cell.fold_check`'s.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cell.config import CellConfig
from cell.errors import CameraFault, StepFailed, StepInterrupted
from cell.evaluation.fold_success import SuccessCriteria, load_success_criteria
from cell.execution import MotionExecutor
from cell.fold_check import FoldCheck, FoldToCheck, check_fold, expect_fold, measure_seen
from cell.jobfile import HOLDING_PHASES, HeldCloth, JobFile, JobRecord
from cell.perception.config import PerceptionConfig
from cell.perception.errors import PerceptionError
from cell.perception.models import PolygonalModel
from cell.perception.pipeline import Outline, extract_outline, match_outline
from cell.perception.table_model import TableModel
from cell.planning.errors import PlanningError, PlanningInputError, Unreachable
from cell.planning.folds import FoldPlan, FoldPlanner, GripperAction, PullPlan
from cell.planning.release import Carry, carry_of, plan_release
from cell.reports import CellEvents, FoldReport, PerceptionReport
from cell.viewing import TableViewer
from cell.wrist import WristCamera
from drivers.camera.base import Camera, Frame
from drivers.camera.model import CameraModel
from drivers.common.configfile import ConfigError
from drivers.common.landmarks import IMAGE, TABLE, Landmarks
from drivers.common.outcomes import FoldOutcome
from drivers.controller.errors import ControllerError
from drivers.controller.interface import Controller
from drivers.controller.trajectory import JointTrajectory
from drivers.robot.table import TableConfig
from statemachine.machine import WORK_STATES, CellMachine, InvalidCommand, TransitionRecord

log = logging.getLogger(__name__)

COMMANDS = ("fold", "pause", "resume", "abort", "status", "reset")


@dataclass(frozen=True)
class Checkpoint:
    """The garment after its last completed fold: what the job file keeps and a restarted cell resumes
    from (the folded model to match, where the fold left each landmark on the table)."""

    folds_done: int
    model: PolygonalModel
    expected_table: Landmarks | None


@dataclass
class GarmentContext:
    """The garment being folded, as the steps leave it for the next."""

    category: str
    model: PolygonalModel                     # the model to match next (folded after each fold)
    observation: PerceptionReport | None = None
    frame: Frame | None = None                # the last image taken,
    camera: CameraModel | None = None         # the camera as it was for it,
    outline: Outline | None = None            # and the garment's outline in it
    plan: FoldPlan | None = None
    pull: PullPlan | None = None              # the garment to drag into reach before the fold
    pulls: int = 0                            # pulls made for the fold in work
    fresh: bool = False                       # the observation was taken since the last motion
    timings: dict[str, float] = field(default_factory=dict)
    robot_time: float = 0.0
    previous_model: PolygonalModel | None = None
    expected_table: Landmarks | None = None  # each landmark's place after the last fold (table)
    steps_done: set[int] = field(default_factory=set)  # indices of the plan's steps already executed
    checkpoint: Checkpoint | None = None      # None: no fold done yet, the model as given
    held: dict[str, HeldCloth] = field(default_factory=dict)  # the grippers closed on the cloth, by arm
    to_check: FoldToCheck | None = None       # the fold in work, once its grippers closed on the cloth

    def __post_init__(self) -> None:
        if self.checkpoint is None:
            self.checkpoint = Checkpoint(0, self.model, None)

    def add_time(self, stage: str, seconds: float) -> None:
        self.timings[stage] = self.timings.get(stage, 0.0) + seconds


@dataclass(frozen=True)
class Perception:
    """What perception needs, loaded once."""

    config: PerceptionConfig
    table_model: TableModel
    models: dict[str, PolygonalModel]


class CellRunner:
    """Runs the state machine's steps. Thread-safe: commands come from other threads."""

    def __init__(self, camera: Camera, controller: Controller, planner: FoldPlanner, perception: Perception,
                 config: CellConfig, events: CellEvents, table: TableConfig, time_scale: Callable[[], float],
                 wrist: WristCamera | None = None, jobs: JobFile | None = None,
                 criteria: SuccessCriteria | None = None):
        self.controller = controller
        self.planner = planner
        self.perception = perception
        self.config = config
        self.events = events
        self.table = table
        self.jobs = jobs  # None: the job is not persisted
        self.criteria = criteria or load_success_criteria()  # the fold check's limits
        self.machine = CellMachine(config.max_attempts)
        self.machine.listeners.append(self._on_transition)
        self.lock = threading.RLock()
        self.wake = threading.Condition(self.lock)
        self.garment: GarmentContext | None = None
        self.stepping = False  # the worker is inside a step (a stopped one may not have ended yet)
        self.viewer = TableViewer(camera, config, wrist, lambda: self.controller.joint_state().positions)
        self.motion = MotionExecutor(controller, config, time_scale, fault=self.fault,
                                     interrupt=self.interrupt, working=self._working)

    # ---------------------------------------------------------------- commands (any thread)
    def command(self, command: str, argument: str = "") -> tuple[bool, str]:
        """Run an operator command; returns (accepted, text)."""
        handlers: dict[str, Callable[[str], str]] = {
            "fold": self._fold, "pause": lambda _: self.machine.request_pause(), "resume": self._resume,
            "abort": self._abort, "reset": self._reset, "status": lambda _: self.describe(),
        }
        if command not in handlers:
            return False, f"unknown command {command!r} (commands: {', '.join(COMMANDS)})"
        with self.lock:
            try:
                return True, handlers[command](argument)
            except (InvalidCommand, ControllerError) as exc:
                return False, str(exc)

    def _fold(self, category: str) -> str:
        self.motion.prepare()
        if category not in self.perception.models:
            raise InvalidCommand(f"fold: unknown garment category {category!r} "
                                 f"(known: {', '.join(sorted(self.perception.models))})")
        recipe = self.planner.recipe(category)
        self.garment = GarmentContext(category, self.perception.models[category])
        self.machine.start_job(category, len(recipe.folds))
        self.wake.notify_all()
        return f"folding {category}: {len(recipe.folds)} fold(s)"

    def _resume(self, _argument: str) -> str:
        state = self.machine.state
        if state not in ("paused", "fault") or self.garment is None:
            self.machine.resume_job()  # refused, naming why
        # the step a fault or an e-stop stopped must have ended before it is redone
        if not self.wake.wait_for(lambda: not self.stepping, self.config.reply_timeout_s):
            raise InvalidCommand(f"resume: the cell is still ending the stopped {self.machine.resume_state} "
                                 "step; try again")
        cleared = ""
        if state == "fault":
            # the lost process is back (the operator's word): clear what its loss left on the controller
            cleared = f" ({self.motion.clear_controller()})"
        self.motion.prepare()
        self.machine.resume_job()
        self.wake.notify_all()
        return f"resumed: {self.machine.state}{cleared}"

    def _abort(self, _argument: str) -> str:
        self.machine.abort_job()
        self.stop_robot()
        return "aborted; the robot stops"

    def _reset(self, _argument: str) -> str:
        if self.machine.state == "paused":  # paused by an e-stop or an alarm: clear it, `resume` goes on
            held = set(self.garment.held) if self.garment is not None else set()
            return self.motion.reset() + self._open_grippers(held)
        if self.machine.is_active:
            self.machine.reset_cell()  # refused, naming what is allowed
        # from idle, done, failed or fault: clear the controller too, so the next fold can start
        try:
            cleared = self.motion.clear_controller() + self._open_grippers(set())
        except (ControllerError, InvalidCommand) as exc:
            cleared = f"the controller was not reset: {exc.text if isinstance(exc, ControllerError) else exc}"
        if self.machine.state != "idle":
            self.machine.reset_cell()
        self.garment = None
        return f"reset: idle; {cleared}"

    def _open_grippers(self, held: set[str]) -> str:
        """Open the grippers the controller reports closed, but those `held` on the job's cloth (the
        resume lays it down where its fold puts it, or where it is, and lets go); what was done."""
        closed = [arm for arm, is_closed in self.controller.gripper_states().items() if is_closed]
        said = ""
        for arm in closed:
            if arm in held:
                said += f"; gripper {arm} holds the cloth: resume lays it down and lets go"
            else:
                self.controller.grip(arm, False)
                said += f"; gripper {arm} opened"
        return said

    def restore_job(self) -> str:
        """Take up the job a previous run of the cell left in the job file: `paused`, and `resume` goes on
        after its last completed fold. A file that cannot be used is refused (logged, naming the file and
        the field) and the cell stays idle. Returns what happened."""
        if self.jobs is None:
            return "no job file"
        recipes = {category: len(self.planner.recipe(category).folds) for category in self.perception.models}
        try:
            record = self.jobs.load_fitting(recipes)
            if record is None:
                return f"no job in {self.jobs.path}"
        except ConfigError as exc:
            log.error("job file refused, the cell starts idle: %s", exc)
            return f"job file refused: {exc}"
        recorded = record.expected_landmarks
        expected = None if recorded is None else Landmarks.of(TABLE, recorded)
        checkpoint = Checkpoint(record.folds_done, record.model, expected)
        with self.lock:
            self.garment = GarmentContext(record.category, record.model, expected_table=expected,
                                          checkpoint=checkpoint, held={h.arm: h for h in record.held},
                                          to_check=record.to_check)
            held = "".join(f"; gripper {h.arm} held the cloth ({h.phase} fold {h.fold})" for h in record.held)
            # a fold whose grippers closed may have happened: the camera decides, after they let go
            then = (f"checks fold {record.folds_done + 1}" if record.to_check is not None
                    else f"goes on with fold {record.folds_done + 1}")
            reason = f"restored job: {record.describe()} (the cell was {record.state}{held}); resume {then}"
            try:
                self.machine.restore_job(record.category, record.fold_count, record.folds_done,
                                         record.attempt, reason,
                                         "verifying" if record.to_check is not None else "perceiving")
            except InvalidCommand as exc:
                self.garment = None
                log.error("job in %s not taken up: %s", self.jobs.path, exc)
                return f"job not taken up: {exc}"
        log.warning("%s", reason)
        return reason

    def _save_job(self) -> None:
        """The job as it stands to the job file; a job that ended (done, failed, reset) clears it."""
        if self.jobs is not None:
            self.jobs.keep(self._job_record())

    def _job_record(self) -> JobRecord | None:
        """The job to take up after a restart: None when there is none (idle, ended, every fold done)."""
        job, g = self.machine.job, self.garment
        checkpoint = g.checkpoint if g is not None else None
        if (self.machine.state in ("idle", "done", "failed") or job is None or g is None
                or checkpoint is None or checkpoint.folds_done >= job.fold_count):
            return None
        expected = None if checkpoint.expected_table is None else dict(checkpoint.expected_table)
        attempt = job.attempt if job.fold_index > checkpoint.folds_done else 1
        return JobRecord(job.category, job.fold_count, checkpoint.folds_done, self.machine.state, attempt,
                         checkpoint.model, expected, tuple(g.held.values()), g.to_check)

    def fault(self, reason: str) -> None:
        """A needed process vanished, an alarm, a camera timeout: stop and keep the reason."""
        with self.lock:
            if self.machine.state in ("fault", "done", "failed"):
                return  # already stopped for a reason worth keeping
            reason = self.events.fault_cause(reason)
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

    def stop_robot(self) -> None:
        self.motion.stop()

    def _working(self) -> bool:
        with self.lock:
            return self.machine.state in WORK_STATES

    def _on_transition(self, record: TransitionRecord) -> None:
        log.info("%s: %s -> %s%s", record.trigger, record.source, record.dest,
                 f" ({record.reason})" if record.reason else "")
        g = self.garment
        if g is not None and record.dest in HOLDING_PHASES:
            g.held = {arm: dataclasses.replace(h, phase=record.dest) for arm, h in g.held.items()}
        self._save_job()  # first: whoever sees the new state may rely on the job file holding it
        self.events.state_changed(record)

    # ---------------------------------------------------------------- the work loop (its own thread)
    def run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            with self.lock:
                state, garment, job = self.machine.state, self.garment, self.machine.job
                if state not in WORK_STATES or garment is None or job is None:
                    self.wake.wait(0.1)
                    continue
                fold_index = job.fold_index
                self.stepping = True
            try:
                self._do_step(garment, state, fold_index)
            except StepInterrupted:
                pass
            except CameraFault as exc:
                self.fault(f"camera: {exc}")
            except StepFailed as exc:
                self._fail_step(state, exc)
            except Exception as exc:  # a bug must leave the cell in a known state, not a dead thread
                log.exception("step %s crashed", state)
                self.fault(f"internal error in {state}: {type(exc).__name__}: {exc}")
            finally:
                with self.lock:
                    self.stepping = False
                    self.wake.notify_all()

    def _do_step(self, g: GarmentContext, state: str, fold_index: int) -> None:
        """One step on the garment `g` (a reference taken under the lock: a reset may drop it meanwhile)."""
        if state == "perceiving":
            self._perceive(g)
            self._advance(state, "perceived")
        elif state == "matching":
            report = self._match(g, fold_index, purpose="perceive")
            self._advance(state, "matched", f"cost {report.cost:.1f}")
        elif state == "planning":
            plan = self._plan(g, fold_index)
            if isinstance(plan, PullPlan):
                self._advance(state, "out_of_reach", f"{plan.why}: pulling it {plan.distance:.2f} m nearer")
            else:
                self._advance(state, "planned", f"{plan.fold_name}: {plan.robot_time:.1f} s of motion")
        elif state == "pulling":
            distance = self._pull(g)
            self._advance(state, "pulled", f"dragged {distance:.2f} m towards the robot")
        elif state in ("grasping", "folding"):
            self._execute(g, grasp_phase=state == "grasping")
            self._advance(state, "grasped" if state == "grasping" else "folded")
        elif state == "verifying":
            check = self._verify(g, fold_index)
            g.checkpoint = Checkpoint(fold_index, g.model, g.expected_table)  # before `verified` saves it
            g.to_check = None
            self.events.fold_finished(self._fold_report(g, check.verdict, check.cause, check.iou))
            g.timings = {}
            g.robot_time = 0.0
            g.pulls = 0
            self._advance(state, "verified", f"fold {fold_index}: outline IoU {check.iou:.3f}")

    def _advance(self, state: str, trigger: str, reason: str = "") -> None:
        with self.lock:
            if self.machine.state == state:
                self.machine.step_done(trigger, reason)

    def _fail_step(self, state: str, exc: StepFailed) -> None:
        with self.lock:
            if self.machine.state != state:
                return  # aborted or faulted meanwhile
            log.warning("%s failed: %s", state, exc.reason)
            record = self.machine.step_failed(exc.reason, exc.retryable)
            g = self.garment
            if g is None:
                return
            if record.dest == "failed":
                self.events.fold_finished(self._fold_report(g, FoldOutcome.FAILED, exc.reason, 0.0))
            g.fresh = False
            # the retry plans the fold afresh from what is seen: cloth still held is lowered where it is
            g.to_check = None
            g.held = {arm: dataclasses.replace(h, carry=None) for arm, h in g.held.items()}
            if g.previous_model is not None and state == "verifying":
                # the fold did not take (a missed grasp leaves the garment as it was): redo it
                g.model = g.previous_model
                g.expected_table = None

    def _fold_report(self, g: GarmentContext, outcome: FoldOutcome, cause: str, iou: float) -> FoldReport:
        job = self.machine.job
        fold_index, attempt = (job.fold_index, job.attempt) if job is not None else (0, 0)
        return FoldReport(g.category, fold_index, attempt, outcome, cause, iou, dict(g.timings), g.robot_time)

    # ---------------------------------------------------------------- steps
    def _perceive(self, g: GarmentContext) -> None:
        if g.fresh and g.observation is not None:
            return  # the verification image of the last fold shows the garment as it is now
        frame = self.viewer.look(lambda goal, label: self._to_perceiving_configuration(g, goal, label))
        try:
            outline = extract_outline(frame.image, self.perception.table_model, self.perception.config,
                                      [g.model])
        except PerceptionError as exc:
            raise StepFailed(f"perception: {exc}") from exc
        g.frame, g.camera, g.outline = frame, CameraModel.from_info(frame.info, self.table), outline
        for stage, seconds in outline.timings_s.items():
            g.add_time(stage, seconds)

    def _to_perceiving_configuration(self, g: GarmentContext, goal: np.ndarray | None = None,
                                     label: str = "perceive") -> None:
        """Arms clear of the table and the fixed camera's view, or at `goal` (a wrist camera's view)."""
        motion = self.planner.motion
        here = self.controller.joint_state().positions
        if goal is None:
            goal = motion.perceive.copy()
            goal[motion.ext_index] = here[motion.ext_index]
        closed = self._closed_grippers()
        if closed:
            self._let_go(g, here, closed)
            here = self.controller.joint_state().positions
        if float(np.max(np.abs(here - goal))) <= self.config.rejoin_tolerance_rad:
            return
        if not motion.valid(here):
            # a fold stopped half way (fingers on the cloth, the grippers open): lift before moving away
            try:
                lift = motion.lift_move(here)
            except PlanningError as exc:
                raise StepFailed(f"no way out of the fold that stopped: {exc}", retryable=False) from exc
            self._move(g, lift)
            here = self.controller.joint_state().positions
        try:
            trajectories = self._free_moves(here, goal, label)
        except PlanningError as exc:
            raise StepFailed(f"no way to the perceiving configuration ({label}): {exc}",
                             retryable=False) from exc
        for trajectory in trajectories:
            self._move(g, trajectory)

    def _closed_grippers(self) -> list[str]:
        """The arms whose gripper the controller reports closed."""
        try:
            states = self.controller.gripper_states()
        except ControllerError as exc:
            self.motion.failed(f"gripper states: {exc.text}", exc)
        return [arm for arm, closed in states.items() if closed]

    def _let_go(self, g: GarmentContext, here: np.ndarray, closed: list[str]) -> None:
        """Grippers found closed before the arms move away (a restarted cell, a step that failed with
        the cloth in hand): each held cloth carried where its plan took it, else lowered where it is,
        then let go of, and the arms backed out."""
        with self.lock:
            g.held = {arm: h for arm, h in g.held.items() if arm in closed}   # the controller's word
            carries = {arm: g.held[arm].carry if arm in g.held else None for arm in closed}
        try:
            release = plan_release(self.planner.motion, here, carries, self.table.height)
        except PlanningError as exc:
            raise StepFailed(f"no way to let go of the cloth in gripper {', '.join(closed)}: {exc}",
                             retryable=False) from exc
        log.warning("letting go: %s", release.how)
        for step in release.steps:
            if isinstance(step, GripperAction):
                self.motion.grip(step.arm, False)
                self._set_held(g, step.arm, None)
            else:
                self._move(g, step)

    def _set_held(self, g: GarmentContext, arm: str, held: HeldCloth | None) -> None:
        """What gripper `arm` holds, to the job file at once: a restarted cell must know it."""
        with self.lock:
            g.held = {**{a: h for a, h in g.held.items() if a != arm}, **({arm: held} if held else {})}
            self._save_job()

    def _free_moves(self, here: np.ndarray, goal: np.ndarray, label: str) -> list[JointTrajectory]:
        """A free move to `goal`; for a wrist camera's view, failing that, one by way of the arms-clear
        configuration: between the views the forearm passes close to the fixed camera's housing,
        where RRT-Connect sometimes finds no path, and from the arms clear every view is easy."""
        motion = self.planner.motion
        try:
            return [motion.free_move(here, goal, label)]
        except PlanningError:
            if self.viewer.wrist is None:
                raise
        log.info("%s: no direct free move, going by the perceiving configuration", label)
        clear = motion.perceive.copy()
        clear[motion.ext_index] = here[motion.ext_index]
        return [motion.free_move(here, clear, "perceive"), motion.free_move(clear, goal, label)]

    def _match(self, g: GarmentContext, fold_index: int, purpose: str) -> PerceptionReport:
        if g.fresh and g.observation is not None:
            g.fresh = False
            return g.observation
        if g.frame is None or g.camera is None or g.outline is None:
            raise StepFailed("matching: no image perceived yet")
        expected_px = None
        if g.expected_table is not None:
            expected = g.expected_table
            expected_px = Landmarks(IMAGE, expected.names, g.camera.table_to_pixel(expected.array()))
        try:
            observation = match_outline(g.outline, {g.category: g.model}, self.perception.config, expected_px)
        except PerceptionError as exc:
            raise StepFailed(f"matching: {exc}") from exc
        g.add_time("match", observation.timings_s["match"])
        seen = observation.landmarks
        landmarks_table = Landmarks(TABLE, seen.names, g.camera.pixel_to_table(seen.array()))
        report = PerceptionReport(g.category, fold_index - 1, g.frame, g.camera, observation, landmarks_table,
                                  purpose)
        g.observation = report
        self.events.perceived(report)
        return report

    def _plan(self, g: GarmentContext, fold_index: int) -> FoldPlan | PullPlan:
        """The fold, or first a pull of the garment towards the robot (`FoldPlanner.plan_fold_or_pull`:
        up to `max_pulls` per fold; the fold is planned again from what is seen after it)."""
        if g.observation is None:
            raise StepFailed("planning: no garment matched yet")
        q = self.controller.joint_state().positions
        start = time.perf_counter()
        try:
            plan = self.planner.plan_fold_or_pull(g.category, fold_index - 1, g.observation.landmarks_table,
                                                  q, g.pulls)
        except Unreachable as exc:
            raise StepFailed(f"unreachable: {exc}", retryable=False) from exc
        except PlanningInputError as exc:  # the recipe does not fit what was seen: a retry sees the same
            raise StepFailed(f"planning: {exc}", retryable=False) from exc
        except PlanningError as exc:
            raise StepFailed(f"planning: {exc}") from exc
        g.add_time("plan", time.perf_counter() - start)
        if isinstance(plan, PullPlan):
            g.pull, g.pulls, g.steps_done = plan, g.pulls + 1, set()
            log.info("fold %d: pulling the garment %.2f m towards the robot (%s)", fold_index, plan.distance,
                     plan.why)
            return plan
        g.plan, g.to_check = plan, None
        g.steps_done = set()
        self.events.planned(plan)
        return plan

    def _execute(self, g: GarmentContext, grasp_phase: bool) -> None:
        """Grasp phase: the plan's steps up to the last gripper close; fold phase: the rest.

        Steps already done are skipped, so a phase redone after an e-stop goes on where it stopped;
        a trajectory cut short is rejoined from wherever the robot stands.
        """
        if g.plan is None:
            raise StepFailed("execution: no fold planned")
        steps = list(g.plan.steps)
        closes = [i for i, s in enumerate(steps) if isinstance(s, GripperAction) and s.action == "close"]
        last_close = max(closes, default=-1)
        indices = range(last_close + 1) if grasp_phase else range(last_close + 1, len(steps))
        self._run_steps(g, g.plan, indices, "grasping" if grasp_phase else "folding")

    def _pull(self, g: GarmentContext) -> float:
        """Drag the garment as planned; the landmarks are expected where the pull leaves them. Returns
        the distance (m)."""
        if g.pull is None or g.observation is None:
            raise StepFailed("pulling: no pull planned")
        pull = g.pull
        self._run_steps(g, pull, range(len(pull.steps)), "pulling")
        seen = g.observation.landmarks_table
        g.expected_table = Landmarks(TABLE, seen.names, seen.array() + np.asarray(pull.offset))
        g.pull = None
        return pull.distance

    def _run_steps(self, g: GarmentContext, plan: FoldPlan | PullPlan, indices: range, phase: str) -> None:
        g.fresh = False
        start = time.perf_counter()
        for index in indices:
            if index in g.steps_done:
                continue
            with self.lock:
                if self.machine.state != phase:
                    raise StepInterrupted()
                fold_index = self.machine.job.fold_index if self.machine.job is not None else 0
            step = plan.steps[index]
            if isinstance(step, GripperAction) and step.action == "close":
                if isinstance(plan, FoldPlan) and g.to_check is None:
                    g.to_check = self._fold_to_check(g, plan, fold_index)
                # written before the close: a cell killed under it finds the gripper's carry on restart
                held = HeldCloth(step.arm, fold_index, phase, self._carry(plan, step.arm))
                self._set_held(g, step.arm, held)
                self.motion.grip(step.arm, True)
            elif isinstance(step, GripperAction):
                self.motion.grip(step.arm, False)
                self._set_held(g, step.arm, None)
            else:
                self.motion.rejoin(step)
                self._move(g, step)
            g.steps_done.add(index)
        g.add_time("execute", time.perf_counter() - start)

    def _carry(self, plan: FoldPlan | PullPlan, arm: str) -> Carry | None:
        try:
            return carry_of(plan, arm, self.planner.motion)
        except PlanningError as exc:   # the cloth is then lowered where it is, should the cell stop
            log.warning("no carry for gripper %s: %s", arm, exc)
            return None

    def _fold_to_check(self, g: GarmentContext, plan: FoldPlan, fold_index: int) -> FoldToCheck:
        """What the check of the fold about to be made needs, from the garment as matched before it."""
        before = g.observation
        if before is None or g.outline is None:
            raise StepFailed("grasping: no garment matched before the fold")
        assert g.checkpoint is not None  # set when the garment was taken up
        try:
            expectation = expect_fold(g.checkpoint.model, before, plan, fold_index,
                                      self.perception.config.merge_fraction)
        except PerceptionError as exc:
            raise StepFailed(f"folded model: {exc}") from exc
        before_table = before.camera.pixel_to_table(g.outline.contour.astype(float))
        return FoldToCheck(expectation, before_table, dict(before.landmarks_table), plan.fold_line)

    def _move(self, g: GarmentContext, trajectory: JointTrajectory) -> None:
        g.robot_time += self.motion.run(trajectory)

    def _verify(self, g: GarmentContext, fold_index: int) -> FoldCheck:
        fold = g.to_check
        if fold is None:
            raise StepFailed("verification: no fold to check")
        assert g.checkpoint is not None  # set when the garment was taken up
        # the garment before this fold, also when a fault cut a check short
        g.previous_model, g.model = g.checkpoint.model, fold.expectation.model
        g.expected_table = fold.expectation.landmarks_table
        self._perceive(g)
        g.fresh = False
        after = self._match(g, fold_index + 1, purpose="verify")
        assert g.outline is not None  # perceived just now
        after_table = after.camera.pixel_to_table(g.outline.contour.astype(float))
        measure = measure_seen(fold_index, fold.before_landmarks, g.expected_table, after, after_table,
                               fold.line, self.criteria)
        check = check_fold(fold.before_outline, after_table, fold.line, self.config, measure)
        if check.verdict is FoldOutcome.DID_NOT_TAKE:
            # nothing moved (a grasp that took no cloth): the same fold can simply be tried again
            raise StepFailed(f"fold {fold_index} did not take: the outline is unchanged "
                             f"(IoU {check.unchanged_iou:.2f} with the one before)")
        if check.verdict is FoldOutcome.IMPERFECT:
            # the cloth moved, not as planned; it cannot be unfolded, so go on from what is seen
            log.warning("fold %d differs from the planned fold (outline IoU %.2f < %.2f); going on from the "
                        "garment as it lies", fold_index, check.iou, self.config.verify_min_iou)
        if measure is not None:
            log.log(logging.INFO if measure.success else logging.WARNING,
                    "fold %d by the fold-success measure on the landmarks seen: %s%s (largest %.1f cm, "
                    "drift %.1f cm, area %.2f of the expected)", fold_index,
                    "success" if measure.success else f"miss, {measure.cause}: ", "" if measure.success
                    else measure.detail, measure.max_error_m * 100, measure.max_drift_m * 100,
                    measure.area_ratio)
        g.fresh = True  # the next fold plans from this image
        g.previous_model = None
        log.info("fold %d checked: IoU %.3f, matched cost %.1f", fold_index, check.iou, after.cost)
        return check
