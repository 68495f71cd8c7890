"""The controller a cell drives (two DX100s with MotoROS, or foldcell's emulator): the interface.

Units and frames: joint positions in rad, velocities in rad/s, accelerations in rad/s^2, times in s of
*robot time* (the controller's clock; the emulator may run it faster than wall time), TCP poses in the
`world` frame (on the floor at the turn-table axis, z up). Joint order is the project order of
`config/robot/joints.yaml` unless a field says otherwise. The errors the methods raise are in
`drivers.controller.errors`, the trajectory in `drivers.controller.trajectory`.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from enum import Enum
from types import TracebackType

import numpy as np

from drivers.controller.errors import NotConnected
from drivers.controller.trajectory import FloatArray, JointTrajectory

log = logging.getLogger(__name__)


# The processes a controller on Zenoh announces (`alive/<name>`) per role: one for both groups, or a
# master and a slave (design.md).
PROCESS_NAMES = {"both": "controller", "master": "controller-master", "slave": "controller-slave"}


# ---------------------------------------------------------------- status
@dataclass(frozen=True)
class GroupStatus:
    """MotoROS `ROBOT_STATUS` of one control group (`-1` would mean unknown; foldcell always knows)."""

    name: str
    controller: str  # master | slave
    drives_powered: bool
    e_stopped: bool
    in_error: bool
    error_code: int
    alarm_text: str
    in_motion: bool
    mode: int  # 1 MANUAL/TEACH, 2 AUTO/PLAY
    motion_possible: bool
    held: bool
    queue_count: int
    trajectory_mode: bool = False  # MotoROS trajectory mode started


@dataclass(frozen=True)
class ControllerStatus:
    """The combined status of all groups (any error/e-stop/motion, all powered/possible)."""

    stamp: float  # robot time, s (on the wire stamps are wall time: drivers/wire/timebase.py)
    groups: tuple[GroupStatus, ...]
    lease_holder: str = ""  # session id holding the control lease, '' if none
    faults: tuple[str, ...] = ()  # names of the active fault injections
    time_scale: float = 1.0  # robot seconds per wall second (1 on real hardware; the emulator may run faster)
    lease_note: str = ""  # why the controller last took a lease away ('' since one was granted)
    loop_stalls: int = 0  # times the emulator's loop could not run on time (a DX100's never stalls)

    @property
    def drives_powered(self) -> bool:
        return all(g.drives_powered for g in self.groups)

    @property
    def e_stopped(self) -> bool:
        return any(g.e_stopped for g in self.groups)

    @property
    def in_error(self) -> bool:
        return any(g.in_error for g in self.groups)

    @property
    def error_code(self) -> int:
        return next((g.error_code for g in self.groups if g.error_code), 0)

    @property
    def alarm_text(self) -> str:
        return next((g.alarm_text for g in self.groups if g.error_code), "")

    @property
    def in_motion(self) -> bool:
        return any(g.in_motion for g in self.groups)

    @property
    def mode(self) -> int:
        return min((g.mode for g in self.groups), default=-1)

    @property
    def motion_possible(self) -> bool:
        return bool(self.groups) and all(g.motion_possible for g in self.groups)

    @property
    def held(self) -> bool:
        return any(g.held for g in self.groups)

    @property
    def trajectory_mode(self) -> bool:
        return bool(self.groups) and all(g.trajectory_mode for g in self.groups)

    @property
    def queue_count(self) -> int:
        return max((g.queue_count for g in self.groups), default=0)

    def group(self, name: str) -> GroupStatus:
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(name)


@dataclass(frozen=True)
class JointFeedback:
    """One joint state sample (`sensor_msgs/JointState`): commanded = actual in the emulator."""

    stamp: float  # robot time, s (on the wire stamps are wall time: drivers/wire/timebase.py)
    joint_names: tuple[str, ...]
    positions: FloatArray  # rad
    velocities: FloatArray  # rad/s
    accelerations: FloatArray  # rad/s^2 (not on the wire; for checks and logs)
    efforts: FloatArray  # N m; the emulator reports 0


class MotionStatus(Enum):
    """How a motion handle's wait ended."""

    SUCCEEDED = "succeeded"  # feedback within goal tolerance of the last point, at rest
    RUNNING = "running"  # the timeout passed first
    CANCELLED = "cancelled"
    ABORTED = "aborted"  # alarm, e-stop, stop or lost link ended it


class MotionHandle(ABC):
    """A trajectory accepted by the controller."""

    @abstractmethod
    def wait(self, timeout: float | None = None) -> MotionStatus:
        """Block until the motion ends or `timeout` (wall s) passes; never raises on timeout."""

    @abstractmethod
    def cancel(self) -> None:
        """Stop this motion smoothly (STOP_MOTION) and drop the queue."""

    @property
    @abstractmethod
    def done(self) -> bool:
        """True once the motion has ended in any way."""


POLL_S = 0.01  # wall s between two polls of a motion's end (feedback comes every 4 ms)


class PolledMotionHandle(MotionHandle):
    """A motion whose end is found by polling the controller's state: `_poll` gives None while it
    runs, then its final status (kept)."""

    def __init__(self, stop: Callable[[], None], trajectory_id: int, goal: FloatArray):
        self._stop = stop
        self.trajectory_id = trajectory_id
        self.goal = np.asarray(goal, dtype=float)
        self._result: MotionStatus | None = None
        self._cancelled = False

    @abstractmethod
    def _poll(self) -> MotionStatus | None:
        """None while the motion runs; its final status once it has ended."""

    @property
    def done(self) -> bool:
        return self._poll() is not None

    def cancel(self) -> None:
        self._cancelled = True
        self._stop()

    def wait(self, timeout: float | None = None) -> MotionStatus:
        end = None if timeout is None else time.monotonic() + timeout
        while (result := self._poll()) is None:
            if end is not None and time.monotonic() >= end:
                return MotionStatus.RUNNING
            self._pause()
        return result

    def _pause(self) -> None:
        """Between two polls: a short sleep, or until the link has news."""
        time.sleep(POLL_S)


# ---------------------------------------------------------------- the interface
class Controller(ABC):
    """A cell controller reached over some link; life cycle connect -> use -> disconnect.

    Methods other than `connect` raise `NotConnected` when not connected. Motion methods need the
    control lease (`acquire_lease`) and raise `LeaseHeld` otherwise.
    """

    def __init__(self) -> None:
        self._connected = False
        self._status_listeners: list[Callable[[ControllerStatus], None]] = []
        self._lease_listeners: list[Callable[[str], None]] = []
        self._statuses = threading.Condition()
        self._status_count = 0   # statuses reported so far

    def add_status_listener(self, listener: Callable[[ControllerStatus], None]) -> None:
        """Call `listener` with every status the controller reports from now on (on the link's thread;
        keep it short). A controller without a status stream never calls it."""
        self._status_listeners.append(listener)

    def _status_received(self, status: ControllerStatus) -> None:
        with self._statuses:
            self._status_count += 1
            self._statuses.notify_all()
        for listener in list(self._status_listeners):
            listener(status)

    def fresh_status(self, timeout: float) -> ControllerStatus:
        """The status as the controller reports it after this call, not one stream period (or a busy
        moment) ago: the next status to arrive; `status()` if none comes within `timeout`. Decide on
        this what an operator's command must act on (an e-stop released on the pendant just before)."""
        with self._statuses:
            seen = self._status_count
            self._statuses.wait_for(lambda: self._status_count > seen, timeout)
        return self.status()

    def add_lease_listener(self, listener: Callable[[str], None]) -> None:
        """Call `listener(reason)` when the controller takes this client's lease away (its robot has
        stopped; on the link's thread, keep it short). The reason is the controller's, in words."""
        self._lease_listeners.append(listener)

    @property
    def holds_lease(self) -> bool:
        """Whether this client holds the control lease as far as it knows (a controller without a lease
        of its own to lose, or one lost with its connection: True while connected)."""
        return self._connected

    def _lease_taken(self, reason: str) -> None:
        log.warning("the controller took the control lease away: %s", reason)
        for listener in list(self._lease_listeners):
            listener(reason)

    @abstractmethod
    def connect(self) -> None:
        """Open the link; raises `ControllerGone` when the controller is not there."""

    @abstractmethod
    def disconnect(self) -> None:
        """Release the lease (the robot stops) and close the link; idempotent."""

    @property
    def is_connected(self) -> bool:
        return self._connected

    def _check(self) -> None:
        if not self._connected:
            raise NotConnected("the controller is not connected: call connect() first")

    def __enter__(self) -> Controller:
        self.connect()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.disconnect()

    @abstractmethod
    def acquire_lease(self) -> None:
        """Become the one commander; raises `LeaseHeld` if another session holds it."""

    @abstractmethod
    def release_lease(self) -> None:
        """Give the lease up (motion stops)."""

    @abstractmethod
    def execute(self, trajectory: JointTrajectory) -> MotionHandle:
        """Submit a trajectory (all 13 joints, project order); returns once accepted.

        Raises `TrajectoryRejected` (INVALID, with point and joint), `NotReady`, `LeaseHeld`,
        `ControllerTimeout` (no reply within the reply timeout) or `ControllerGone`.
        """

    @abstractmethod
    def stop(self) -> None:
        """Decelerate every axis within its limits and drop the queue."""

    @abstractmethod
    def status(self) -> ControllerStatus:
        """The latest combined status (robot time stamp)."""

    @abstractmethod
    def joint_state(self) -> JointFeedback:
        """The latest joint state sample."""

    @abstractmethod
    def command(self, code: int, arm: str = "", values: Sequence[float] = (), joint: str = "") -> None:
        """Send a `drivers.controller.codes.Command` (`arm` for grippers, `joint` + `values` for a jog,
        `values` for move-to and fault parameters); raises the typed error matching a failure reply."""

    @abstractmethod
    def grip(self, arm: str, closed: bool) -> None:
        """Close (True) or open (False) the gripper of arm `r1` or `r2`."""

    @abstractmethod
    def gripper_states(self) -> dict[str, bool]:
        """Arm -> whether its gripper is closed, as the controller reports it now."""

    @abstractmethod
    def move_to(self, q: FloatArray) -> MotionHandle:
        """Move to joint positions `q` (13, rad) along a jerk-limited, synchronised motion."""
