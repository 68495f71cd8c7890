"""The cell's hands: trajectories and grippers sent to the controller, and what a failure means.

A motion that ends badly is classified from the controller's own status: an e-stop or a hold pauses
the cell (the step is redone on resume), an alarm or a controller that does not answer faults it,
anything else fails the step (the state machine may retry the fold).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import NoReturn

import numpy as np

from cell.config import CellConfig
from cell.errors import StepFailed, StepInterrupted
from drivers.controller.codes import Command, Result, Subcode
from drivers.controller.errors import (
    ControllerError,
    ControllerGone,
    ControllerTimeout,
    InvalidArgument,
    LeaseHeld,
)
from drivers.controller.interface import Controller, ControllerStatus, MotionHandle, MotionStatus
from drivers.controller.trajectory import JointTrajectory
from statemachine.machine import InvalidCommand

log = logging.getLogger(__name__)

_FEEDBACK_POLL_S = 0.005  # the joint state arrives every 4 ms
_STATUS_POLL_S = 0.01


class MotionExecutor:
    """Runs motions for the cell. `fault(reason)` and `interrupt(reason)` tell the cell what a failure
    meant; `working()` says whether the cell still wants the motion (False once aborted or faulted)."""

    def __init__(self, controller: Controller, config: CellConfig, time_scale: Callable[[], float],
                 fault: Callable[[str], None], interrupt: Callable[[str], None], working: Callable[[], bool]):
        self.controller = controller
        self.config = config
        self.time_scale = time_scale
        self.fault = fault
        self.interrupt = interrupt
        self.working = working
        # An e-stop was seen since an operator last switched the servos on: the cell does not switch
        # them on by itself (a robot that moved after an e-stop's release was MotoROS's re-enable bug).
        self.enable_after_estop = False

    # ---------------------------------------------------------------- the controller's readiness
    def saw_status(self, status: ControllerStatus) -> None:
        """Every status the controller reports, the cell busy or not."""
        if status.e_stopped:
            self.enable_after_estop = True
        elif status.drives_powered:
            self.enable_after_estop = False   # somebody switched them on (`foldcell controller servo on`)

    def prepare(self) -> None:
        """Trajectory mode, unless an e-stop or an alarm needs the operator first, or the servos are off
        since an e-stop (only an operator's reset or servo on switches them on again)."""
        status = self.controller.status()
        if status.e_stopped:
            raise InvalidCommand("the e-stop is engaged: reset it first (cell command reset)")
        if status.in_error:
            raise InvalidCommand(f"controller alarm {status.error_code} ({status.alarm_text}): "
                                 "reset it first")
        if self.enable_after_estop and not status.drives_powered:
            raise InvalidCommand("the servos are off since an e-stop and the cell does not switch them on "
                                 "by itself: cell command reset, or `foldcell controller servo on`, first")
        if not status.motion_possible:
            self.controller.command(Command.START_TRAJ_MODE)

    def reset(self) -> str:
        """Clear an e-stop or an alarm that paused the cell (the cell holds the lease)."""
        return self.clear_controller() + "; resume to continue"

    def clear_controller(self) -> str:
        """Reset the controller's e-stop and alarms (the cell holds the lease); what was done."""
        # an e-stop released on the pendant just before may not be in the last status yet
        status = self.controller.fresh_status(self.config.reply_timeout_s)
        done = []
        if status.e_stopped:
            self._clear(Command.ESTOP_RESET, "the e-stop")
            done.append("e-stop reset")
        if status.in_error:
            self._clear(Command.RESET_ALARM, f"alarm {status.error_code}")
            done.append("alarm reset")
        deadline = time.monotonic() + self.config.reply_timeout_s
        while done and time.monotonic() < deadline:  # the status stream catches up with the commands
            status = self.controller.status()
            if not status.e_stopped and not status.in_error:
                break
            time.sleep(_STATUS_POLL_S)
        if self.enable_after_estop and not status.drives_powered:
            self._servos_on()   # the operator's reset is the explicit enable
            self.enable_after_estop = False
            done.append("servos on")
        return ", ".join(done) or "nothing to reset on the controller"

    def _servos_on(self) -> None:
        """START_SERVOS, then trajectory mode (the CloPeMa build has no START_SERVOS: its START_TRAJ_MODE
        switches them on)."""
        try:
            self.controller.command(Command.START_SERVOS)
        except InvalidArgument as exc:
            if exc.subcode != Subcode.INVALID_COMMAND:
                raise
        self.controller.command(Command.START_TRAJ_MODE)

    def _clear(self, code: Command, what: str) -> None:
        """Send a reset the controller may not take remotely (MotoROS has no e-stop reset, the CloPeMa
        build no alarm reset either): then the operator is told where to clear it."""
        try:
            self.controller.command(code)
        except InvalidArgument as exc:
            if exc.subcode != Subcode.INVALID_COMMAND:
                raise
            raise InvalidCommand(f"{what} cannot be reset remotely on this controller ({exc.text}): "
                                 "clear it on the controller itself (pendant, e-stop button), then reset "
                                 "again") from exc

    def stop(self) -> None:
        """Stop every axis now (abort, fault); a controller that does not answer is only logged."""
        if not self.controller.holds_lease:
            return   # the controller took the lease away and stopped the robot itself
        try:
            self.controller.stop()
        except ControllerError as exc:
            log.warning("stop: %s", exc)

    # ---------------------------------------------------------------- motions
    def grip(self, arm: str, closed: bool) -> None:
        try:
            self.controller.grip(arm, closed)
        except ControllerError as exc:
            self.failed(f"gripper {arm} {'close' if closed else 'open'}: {exc.text}", exc)

    def run(self, trajectory: JointTrajectory) -> float:
        """Execute a trajectory to its end; returns its robot time (s)."""
        try:
            handle = self._while_busy(lambda: self.controller.execute(trajectory))
        except ControllerError as exc:
            self.failed(f"trajectory {trajectory.label} rejected: {exc.text}", exc)
        scale = max(self.time_scale(), 1e-6)
        timeout = (trajectory.duration / scale * self.config.motion_timeout_factor
                   + self.config.motion_timeout_margin_s)
        status = handle.wait(timeout)
        if status == MotionStatus.SUCCEEDED:
            self._wait_feedback_at(trajectory.positions[-1], trajectory.label)
            return trajectory.duration
        if status == MotionStatus.RUNNING:
            try:
                handle.cancel()
            except ControllerError as exc:   # a controller gone or silent: its fault, not the cell's
                self.failed(f"motion {trajectory.label} did not finish within {timeout:.1f} s and could not "
                            f"be stopped: {exc.text}", exc)
            self.failed(f"motion {trajectory.label} did not finish within {timeout:.1f} s")
        self.failed(f"motion {trajectory.label} {status.value}")

    def _while_busy(self, send: Callable[[], MotionHandle]) -> MotionHandle:
        """`send()`, sent again while the controller answers BUSY (MotoROS' retry rule: a stop is still
        braking, e.g. right after a resume), for up to the motion timeout margin."""
        deadline = time.monotonic() + self.config.motion_timeout_margin_s
        while True:
            try:
                return send()
            except ControllerError as exc:
                if exc.result != Result.BUSY or time.monotonic() > deadline:
                    raise
                log.info("controller busy (%s): sending again", exc.text)
                time.sleep(_STATUS_POLL_S)

    def _wait_feedback_at(self, end: np.ndarray, label: str) -> None:
        """A gripper may act next: the feedback must be at the end point, not only the controller's word."""
        end = np.asarray(end, dtype=float)
        deadline = time.monotonic() + self.config.motion_timeout_margin_s
        while self._distance_to(end) > self.config.rejoin_tolerance_rad:
            if time.monotonic() > deadline:
                self.failed(f"motion {label} reported done away from its end point")
            time.sleep(_FEEDBACK_POLL_S)

    def _distance_to(self, q: np.ndarray) -> float:
        return float(np.max(np.abs(self.controller.joint_state().positions - q)))

    def rejoin(self, trajectory: JointTrajectory) -> None:
        """Move to the trajectory's first point if the robot is not there (it stopped under a motion)."""
        start = np.asarray(trajectory.positions[0], dtype=float)
        distance = self._distance_to(start)
        if distance <= self.config.rejoin_tolerance_rad:
            return
        log.info("rejoining %s: the robot is %.3f rad away from its start", trajectory.label, distance)
        try:
            handle = self._while_busy(lambda: self.controller.move_to(start))
        except ControllerError as exc:
            self.failed(f"rejoin {trajectory.label}: {exc.text}", exc)
        if handle.wait(self.config.motion_timeout_margin_s * 4) != MotionStatus.SUCCEEDED:
            self.failed(f"rejoin {trajectory.label} did not finish")

    # ---------------------------------------------------------------- what a failure means
    def failed(self, reason: str, error: ControllerError | None = None) -> NoReturn:
        """A motion ended badly: pause on an e-stop or hold, fault on an alarm or a silent controller,
        else fail the step. Always raises (StepInterrupted or StepFailed)."""
        if error is not None:   # the controller's codes go to the log; the reason keeps its words
            log.info("%s (result %d, subcode %d)", reason, error.result, error.subcode)
        try:
            status: ControllerStatus | None = self.controller.status()
        except ControllerError:
            status = None
        if not self.working():
            raise StepInterrupted()
        if isinstance(error, (ControllerGone, ControllerTimeout)):
            # the controller is not answering: a fault, not a step to retry (its token may not be gone yet)
            self.fault(f"controller: {error.text}")
            raise StepInterrupted()
        if isinstance(error, LeaseHeld) or not self.controller.holds_lease:
            # the controller took the lease away (and stopped the robot): a retry would be refused again
            note = status.lease_note if status is not None else ""
            self.fault(f"lease lost: {note or (error.text if error is not None else reason)}")
            raise StepInterrupted()
        stopped_by = _stopped_by(status, error)
        if stopped_by:
            self.interrupt(stopped_by)
            raise StepInterrupted()
        if status is not None and status.in_error:
            self.fault(f"controller alarm {status.error_code}: {status.alarm_text}")
            raise StepInterrupted()
        raise StepFailed(reason)


def _stopped_by(status: ControllerStatus | None, error: ControllerError | None) -> str:
    """'e-stop' or 'hold' when the robot was stopped under the motion, '' otherwise."""
    if status is not None and (status.e_stopped or status.held):
        return "e-stop" if status.e_stopped else "hold"
    # the reply may say e-stop before the status stream does
    subcode = error.subcode if error is not None else Subcode.NONE
    return {int(Subcode.NOT_READY_ESTOP): "e-stop", int(Subcode.NOT_READY_HOLD): "hold"}.get(subcode, "")
