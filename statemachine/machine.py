"""The cell's state machine: perceive -> match -> plan -> grasp -> fold -> verify, per fold of a recipe
(plan -> pull -> perceive again when the fold lies out of the arms' reach).

Pure sequencing (no Zenoh, no robot): the cell daemon does the work of each state and reports the
outcome with a trigger; the machine decides what comes next. Pause takes effect at the next step
boundary, abort and fault at once. Transitions are data (`TRANSITIONS`) so the monitor and the
docs show the same table the machine runs.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from transitions import Machine, MachineError

WORK_STATES = ("perceiving", "matching", "planning", "pulling", "grasping", "folding", "verifying")
STATES = ("idle", *WORK_STATES, "done", "paused", "failed", "fault")
ACTIVE_STATES = (*WORK_STATES, "paused")
HISTORY_LENGTH = 50


@dataclass(frozen=True)
class TransitionSpec:
    trigger: str
    source: tuple[str, ...]
    dest: str
    conditions: tuple[str, ...] = ()
    unless: tuple[str, ...] = ()
    description: str = ""


def _step(trigger: str, source: str, dest: str, description: str) -> list[TransitionSpec]:
    """A step's completion: to the next state, or to `paused` when a pause was asked for."""
    return [
        TransitionSpec(trigger, (source,), "paused", ("pause_requested",), (), f"{description}; pause asked"),
        TransitionSpec(trigger, (source,), dest, (), ("pause_requested",), description),
    ]


TRANSITIONS: tuple[TransitionSpec, ...] = (
    TransitionSpec("start", ("idle", "done"), "perceiving", description="fold a garment of a category"),
    *_step("perceived", "perceiving", "matching", "garment segmented and contour simplified"),
    *_step("matched", "matching", "planning", "polygonal model matched"),
    *_step("planned", "planning", "grasping", "fold planned"),
    *_step("out_of_reach", "planning", "pulling", "fold out of the arms' reach: pull the garment nearer"),
    *_step("pulled", "pulling", "perceiving", "garment dragged towards the robot: perceive it again"),
    *_step("grasped", "grasping", "folding", "both grasps closed on the cloth"),
    *_step("folded", "folding", "verifying", "fold laid down and grippers retreated"),
    TransitionSpec("verified", ("verifying",), "done", ("last_fold",), (),
                   "last fold checked: garment done"),
    TransitionSpec("verified", ("verifying",), "paused", ("pause_requested",), ("last_fold",),
                   "fold checked; pause asked"),
    TransitionSpec("verified", ("verifying",), "perceiving", (), ("last_fold", "pause_requested"),
                   "fold checked: next fold"),
    TransitionSpec("retry", WORK_STATES, "paused", ("attempts_left", "pause_requested"), (),
                   "a step failed; retry after the pause"),
    TransitionSpec("retry", WORK_STATES, "perceiving", ("attempts_left",), ("pause_requested",),
                   "a step failed: re-perceive, re-plan, re-fold"),
    TransitionSpec("retry", WORK_STATES, "failed", (), ("attempts_left",),
                   "a step failed and no attempt is left"),
    TransitionSpec("give_up", WORK_STATES, "failed",
                   description="a step failed in a way a retry cannot mend"),
    *(TransitionSpec("resume", ("paused", "fault"), state, (f"resume_to_{state}",), (),
                     f"continue with {state} (after a fault: once the lost process is back)")
      for state in WORK_STATES),
    TransitionSpec("interrupt", WORK_STATES, "paused",
                   description="e-stop or hold: the step is redone on resume"),
    TransitionSpec("abort", ACTIVE_STATES, "failed",
                   description="stopped by the operator; the robot stops"),
    TransitionSpec("fault", (*STATES[:-1],), "fault",
                   description="controller alarm, e-stop, lost process, camera timeout"),
    TransitionSpec("reset", ("done", "failed", "fault"), "idle",
                   description="clear the garment and any reason"),
    TransitionSpec("restore", ("idle",), "paused",
                   description="a restarted cell takes up its persisted job; resume goes on after the "
                               "last completed fold, or checks the fold its grippers were making"),
)


# Where a step-completion trigger leads when no pause is in the way (for resuming after a pause).
_NEXT_STATE = {(t.trigger, t.source[0]): t.dest for t in TRANSITIONS
               if len(t.source) == 1 and t.dest not in ("paused", "failed") and not t.conditions}


@dataclass(frozen=True)
class TransitionRecord:
    stamp_ns: int
    trigger: str
    source: str
    dest: str
    reason: str


@dataclass
class FoldJob:
    category: str
    fold_count: int
    max_attempts: int
    fold_index: int = 1           # the fold being worked on, 1-based
    attempt: int = 1
    folds_done: int = 0


class InvalidCommand(Exception):
    """A trigger that the current state does not allow; the message says which ones it does."""


class CellMachine:
    """The sequencing of one cell. Call the triggers; read `state`, `job`, `reason`, `history`."""

    # set by `transitions.Machine` on its model
    state: str
    trigger: Callable[..., bool]

    def __init__(self, max_attempts: int = 3, clock_ns=time.time_ns):
        if max_attempts < 1:
            raise ValueError(f"max_attempts: must be >= 1, got {max_attempts}")
        self.max_attempts = max_attempts
        self.clock_ns = clock_ns
        self.job: FoldJob | None = None
        self.reason = ""
        self.pause_requested = False
        self.history: deque[TransitionRecord] = deque(maxlen=HISTORY_LENGTH)
        self.listeners: list = []
        self.machine = Machine(model=self, states=list(STATES), initial="idle", auto_transitions=False,
                               send_event=True, after_state_change="_record", queued=False)
        for spec in TRANSITIONS:
            self.machine.add_transition(spec.trigger, list(spec.source), spec.dest,
                                        conditions=list(spec.conditions), unless=list(spec.unless))
        self._trigger_reason = ""
        self.resume_state = "perceiving"
        for state in WORK_STATES:
            setattr(self, f"resume_to_{state}", lambda _e=None, state=state: self.resume_state == state)

    # conditions
    def attempts_left(self, _event=None) -> bool:
        return self.job is not None and self.job.attempt < self.max_attempts

    def last_fold(self, _event=None) -> bool:
        return self.job is not None and self.job.fold_index >= self.job.fold_count

    def _record(self, event) -> None:
        source = event.transition.source
        if event.transition.dest == "paused":
            # a step boundary resumes with the step that was next; an interruption redoes its step
            name = event.event.name
            self.resume_state = (source if name == "interrupt"
                                 else _NEXT_STATE.get((name, source), "perceiving"))
        elif event.transition.dest == "fault" and source != "paused":
            # a fault under a step redoes that step; one with no garment in work leaves nothing to resume
            self.resume_state = source if source in WORK_STATES else ""
        self._advance_job(event.event.name, event.transition.dest)
        record = TransitionRecord(self.clock_ns(), event.event.name, event.transition.source,
                                  event.transition.dest, self._trigger_reason)
        self.history.append(record)
        for listener in list(self.listeners):
            listener(record)

    def _advance_job(self, trigger: str, dest: str) -> None:
        """The job moves on with its transition, before the listeners hear of it: they see the fold and
        attempt the new state works on (`perceiving` after a checked fold is the next fold's)."""
        if self.job is None:
            return
        if trigger == "verified":
            self.job.folds_done = self.job.fold_index
            if dest != "done":
                self.job.fold_index += 1
                self.job.attempt = 1
        elif trigger == "retry" and dest in ("perceiving", "paused"):
            self.job.attempt += 1

    def fire(self, name: str, reason: str = "") -> TransitionRecord:
        """Run `trigger`; raise InvalidCommand naming the allowed triggers when it does not apply."""
        self._trigger_reason = reason
        try:
            if name not in self.machine.events:
                raise InvalidCommand(f"unknown trigger {name!r}")
            if not self.trigger(name):
                raise InvalidCommand(f"{name}: no transition applies in state {self.state}")
        except MachineError as exc:
            allowed = ", ".join(self.allowed_triggers()) or "none"
            raise InvalidCommand(f"{name} is not allowed in state {self.state} (allowed: {allowed})") from exc
        return self.history[-1]

    # operator commands
    def start_job(self, category: str, fold_count: int) -> TransitionRecord:
        if fold_count < 1:
            raise InvalidCommand(f"{category}: the recipe has no folds")
        if self.state not in ("idle", "done"):
            raise InvalidCommand(
                f"fold is not allowed in state {self.state}: reset or wait for the garment to finish")
        self.job = FoldJob(category, fold_count, self.max_attempts)
        self.reason = ""
        self.pause_requested = False
        return self.fire("start", f"fold {category}: {fold_count} fold(s)")

    def restore_job(self, category: str, fold_count: int, folds_done: int, attempt: int,
                    reason: str, resume_with: str = "perceiving") -> TransitionRecord:
        """Take up a job a previous run of the cell left after `folds_done` completed folds: `paused`,
        and `resume` goes on with the next fold, perceiving the garment as it lies (`resume_with`
        `verifying`: checking the fold the previous run's grippers were making)."""
        if resume_with not in ("perceiving", "verifying"):
            raise InvalidCommand(f"restore: resume_with must be perceiving or verifying, got {resume_with!r}")
        if self.state != "idle":
            raise InvalidCommand(f"restore is not allowed in state {self.state}")
        if not 0 <= folds_done < fold_count:
            raise InvalidCommand(f"{category}: {folds_done} of {fold_count} fold(s) done: nothing to resume")
        if attempt < 1:
            raise InvalidCommand(f"{category}: attempt must be >= 1, got {attempt}")
        self.job = FoldJob(category, fold_count, self.max_attempts, fold_index=folds_done + 1,
                           attempt=min(attempt, self.max_attempts), folds_done=folds_done)
        self.pause_requested = False
        try:
            record = self._fire_with_reason("restore", reason)
        except InvalidCommand:
            self.job = None
            raise
        self.resume_state = resume_with
        return record

    def request_pause(self) -> str:
        """Pause at the next step boundary (now, if already between steps)."""
        if self.state not in WORK_STATES:
            raise InvalidCommand(f"pause is not allowed in state {self.state}")
        self.pause_requested = True
        return f"pausing after {self.state}"

    def resume_job(self) -> TransitionRecord:
        """Go on from `paused`, or from a `fault` that stopped a garment (the step it stopped is redone)."""
        if self.state not in ("paused", "fault"):
            raise InvalidCommand(f"resume is not allowed in state {self.state}")
        if self.job is None or self.resume_state not in WORK_STATES:
            raise InvalidCommand(f"resume: no garment to go on with in state {self.state} (allowed: reset)")
        self.pause_requested = False
        self.reason = ""
        return self.fire("resume", "resumed")

    def abort_job(self, reason: str = "aborted by the operator") -> TransitionRecord:
        return self._fire_with_reason("abort", reason)

    def raise_fault(self, reason: str) -> TransitionRecord:
        return self._fire_with_reason("fault", reason)

    def reset_cell(self) -> TransitionRecord:
        if "reset" not in self.allowed_triggers():
            return self.fire("reset", "reset")  # raises, naming what is allowed
        self.job = None
        self.pause_requested = False
        return self._fire_with_reason("reset", "")

    def _fire_with_reason(self, trigger: str, reason: str) -> TransitionRecord:
        """Fire with `reason` in place while listeners see the new state; keep the old one on refusal."""
        previous, self.reason = self.reason, reason
        try:
            return self.fire(trigger, reason or trigger)
        except InvalidCommand:
            self.reason = previous
            raise

    # step outcomes (called by the daemon)
    def step_done(self, trigger: str, reason: str = "") -> TransitionRecord:
        record = self.fire(trigger, reason)
        if record.dest == "paused":
            self.reason = reason or "paused by the operator"
        return record

    def interrupt_step(self, reason: str) -> TransitionRecord:
        """The robot was stopped under a step (e-stop, hold): pause; resume redoes that step."""
        self.reason = reason
        return self.fire("interrupt", reason)

    def step_failed(self, reason: str, retryable: bool = True) -> TransitionRecord:
        self.reason = reason
        if not retryable:
            return self.fire("give_up", reason)
        return self.fire("retry", reason)

    def allowed_triggers(self) -> list[str]:
        return sorted(set(self.machine.get_triggers(self.state)))

    @property
    def is_active(self) -> bool:
        return self.state in ACTIVE_STATES


__all__ = [
    "ACTIVE_STATES",
    "STATES",
    "TRANSITIONS",
    "WORK_STATES",
    "CellMachine",
    "FoldJob",
    "InvalidCommand",
    "TransitionRecord",
    "TransitionSpec",
]
