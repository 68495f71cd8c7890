"""`ZenohController`: the `drivers.controller.interface.Controller` interface over Zenoh, to the DX100 master
(the emulator's `foldcell controller serve`, or a real adapter speaking the same keys).

Trajectories go to `controller/trajectory` and commands to `controller/command` with this process's
credential as the query attachment: its liveliness token name `alive/<process>` and a signature of the
request by a per-session key (`drivers.controller.credential`, no secret travels). The controller grants
the control lease to that name with that key, and drops it (and stops) when the token vanishes or the
renewals stop. While it holds the lease the client counts only the replies of the Zenoh session that
granted it: another session serving the controller's keys (a stranger, on an open cell) is ignored, and
logged once.
Completion is judged from the feedback: the joint state within the goal tolerance of the last point and
a status, newer than the acceptance, that shows the controller idle. Timeouts are wall seconds. The
controller stamps in wall time; this client turns every stamp into robot time by the time base its
latest status states (`drivers.wire.timebase`), so the interface's stamps are robot time.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from drivers.common.scheduling import histogram
from drivers.controller import codec
from drivers.controller.codes import Command, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig, default_controller_config
from drivers.controller.credential import Signer
from drivers.controller.errors import (
    ControllerError,
    ControllerGone,
    ControllerTimeout,
    InvalidArgument,
    LeaseHeld,
    TrajectoryRejected,
    raise_for_reply,
)
from drivers.controller.interface import (
    Controller,
    ControllerStatus,
    JointFeedback,
    MotionStatus,
    PolledMotionHandle,
)
from drivers.controller.trajectory import FloatArray, JointTrajectory
from drivers.robot.config import RobotConfig, default_robot_config
from drivers.wire import messages
from drivers.wire.messages import ErrorReply, NoReply, WireError
from drivers.wire.timebase import WALL, TimeBase, timebase_of
from drivers.wire.transport import SampleBuffer, Wire, decode_sample

log = logging.getLogger(__name__)

_POLL_S = 0.01  # wall s between completion checks (the feedback arrives every 4 ms)
_REST_VELOCITY = 1e-9  # rad/s: a joint state velocity below this counts as at rest


class ZenohMotionHandle(PolledMotionHandle):
    """An accepted trajectory; `wait` watches the feedback and status for its end."""

    def __init__(self, owner: ZenohController, reply: Reply, goal: FloatArray, accepted_ns: int,
                 duration: float | None = None):
        super().__init__(owner.stop, reply.trajectory_id, goal)
        self._owner = owner
        self.reply = reply
        self.accepted_ns = accepted_ns  # robot time of the acceptance reply
        # robot time (ns) by which the motion is over, when the reply gives its start tick
        self.end_ns: int | None = None
        if reply.start_tick and duration is not None:
            period_ns = round(owner.config.interpolation_period * 1e9)
            self.end_ns = (reply.start_tick + int(np.ceil(duration * 1e9 / period_ns)) + 1) * period_ns

    def _poll(self) -> MotionStatus | None:
        if self._result is not None:
            return self._result
        o = self._owner
        with o._lock:
            status, status_ns, fb = o._status, o._status_ns, o._latest_feedback()
        if status is None or fb is None or status_ns <= self.accepted_ns:
            return None  # no status yet that knows about this trajectory
        at_goal = (np.abs(fb.positions - self.goal) <= o.config.goal_tolerance).all() and \
            (np.abs(fb.velocities) <= _REST_VELOCITY).all()
        idle = not status.in_motion and status.queue_count == 0
        past_end = self.end_ns is not None and status_ns > self.end_ns and not self._cancelled
        if status.e_stopped or status.in_error:
            self._result = MotionStatus.CANCELLED if self._cancelled else MotionStatus.ABORTED
        elif idle and at_goal:
            self._result = MotionStatus.SUCCEEDED
        elif past_end and not idle and not status.held:
            self._result = MotionStatus.SUCCEEDED  # ours is over; a later queued trajectory runs
        elif idle and fb.stamp * 1e9 >= status_ns:
            self._result = MotionStatus.CANCELLED if self._cancelled else MotionStatus.ABORTED
        return self._result

    def _pause(self) -> None:
        self._owner._changed.wait(_POLL_S)


class ZenohController(Controller):
    """The cell's controller over an open `Wire` (the caller owns the Wire and closes it)."""

    def __init__(self, wire: Wire, process_name: str | None = None, config: ControllerConfig | None = None,
                 robot_config: RobotConfig | None = None, cell: str | None = None):
        super().__init__()
        self.wire = wire
        self.client = f"alive/{process_name or wire.process}"
        self.signer = Signer(self.client)  # the lease is bound to its key, not the name
        self.config = config or default_controller_config()
        self.robot_config = robot_config or default_robot_config()
        self.cell = cell
        self._lock = threading.Lock()
        self._changed = threading.Event()
        self._status: ControllerStatus | None = None
        self._status_msg: Any = None
        self._status_ns = 0  # robot time of the latest status
        self._timebase: TimeBase | None = None
        self._feedback: JointFeedback | None = None
        self._samples: SampleBuffer | None = None   # the joint states, read when asked for
        self._grippers: dict[str, bool] = {}        # arm -> closed, as last heard
        self._subscribed = False
        self._holds_lease = False
        self._lease_since_ns = 0   # robot time of the grant of the lease held
        self._controller_id = ""   # the Zenoh session that granted the lease held
        self._grant = 0   # counts the grants: a renewal's refusal speaks for the grant it renewed only

    # ------------------------------------------------------------------ life cycle
    def connect(self, timeout: float | None = None) -> None:
        """Subscribe to the controller's streams and wait for its first status and joint state."""
        if self._connected:
            return
        if not self._subscribed:
            self.wire.subscribe("controller/status", self._on_status, cell=self.cell)
            # 250 a second: Zenoh keeps the newest and it is decoded only when the cell looks
            self._samples = self.wire.buffer("controller/joint_states", cell=self.cell)
            self.wire.subscribe("controller/gripper/*", self._on_gripper, cell=self.cell)
            self._subscribed = True
        deadline = time.monotonic() + (timeout if timeout is not None else self.config.reply_timeout)
        while time.monotonic() < deadline:
            with self._lock:
                if self._status is not None and self._latest_feedback() is not None:
                    self._connected = True
                    return
            time.sleep(0.01)
        raise ControllerGone("no controller status within "
                             f"{timeout if timeout is not None else self.config.reply_timeout:g} s: "
                             "is `foldcell controller serve` running on this cell?")

    def disconnect(self) -> None:
        if not self._connected:
            return
        if self._holds_lease:
            try:
                self._holds_lease = False
                self._send(Command.LEASE_RELEASE)
            except Exception as exc:  # disconnecting: the token's loss stops the robot anyway
                log.warning("lease release failed: %s", exc)
        self._connected = False

    # ------------------------------------------------------------------ streams
    def _on_status(self, key: str, msg: Any, raw: Any) -> None:
        status = codec.status_from_msg(msg)
        timebase = timebase_of(msg)
        with self._lock:
            self._status, self._status_msg, self._timebase = status, msg, timebase
            self._status_ns = timebase.robot_ns
            # a status from before the grant may still arrive after it: only a later one counts
            lost = self._holds_lease and timebase.robot_ns > self._lease_since_ns \
                and status.lease_holder != self.client
            if lost:
                self._holds_lease = False
        self._changed.set()
        self._changed.clear()
        if lost:
            self._lease_taken(status.lease_note or f"the controller's status names "
                                                   f"{status.lease_holder or 'no one'} as the lease holder")
        self._status_received(status)

    def _on_gripper(self, key: str, msg: Any, raw: Any) -> None:
        with self._lock:
            self._grippers[msg.arm] = bool(msg.closed)
        self._changed.set()
        self._changed.clear()

    def _latest_feedback(self) -> JointFeedback | None:
        """The newest joint state (decoded now if a new sample came), holding `_lock`."""
        raw = self._samples.latest() if self._samples is not None else None
        if raw is not None and not raw.is_delete and self._timebase is not None:
            # (before a status, a stamp means nothing: robot time is unknown)
            try:
                self._feedback = codec.feedback_from_msg(decode_sample(raw), self._timebase)
            except WireError as err:
                log.warning("dropped a bad joint state: %s", err)
        return self._feedback

    # ------------------------------------------------------------------ requests
    def _send(self, code: int, arm: str = "", values: Sequence[float] | FloatArray = (),
              joint: str = "") -> tuple[Reply, int]:
        """Run a command; the successful reply and its robot-time stamp (ns), or its typed error."""
        msg = codec.command_msg(code, self.client, arm, values, joint)
        answer, _ = self._request("controller/command", msg)
        return raise_for_reply(codec.reply_from_msg(answer)), self._robot_ns(answer)

    def _request(self, key: str, msg: Any) -> tuple[Any, str]:
        """The controller's answer, signed by this client, and the Zenoh session it came from."""
        try:
            return self.wire.request_from(key, msg, timeout=self.config.reply_timeout, cell=self.cell,
                                          sign=self.signer.attachment,
                                          replier=self._controller_id if self._holds_lease else "")
        except NoReply as exc:
            raise ControllerTimeout(f"{key}: no reply within {self.config.reply_timeout:g} s") from exc
        except ErrorReply as exc:
            # the controller's wire layer refused the request before its rules saw it (e.g. a NaN);
            # typed like the controller's own INVALID replies
            if key.endswith("trajectory"):
                raise TrajectoryRejected(str(exc), Result.INVALID, Subcode.INVALID_DATA) from exc
            raise InvalidArgument(str(exc), Result.INVALID, Subcode.INVALID_COMMAND) from exc
        except WireError as exc:  # nobody serves the key, or its reply is not a reply
            raise ControllerGone(str(exc)) from exc

    def acquire_lease(self) -> None:
        self._check()
        answer, controller = self._request("controller/command",
                                           codec.command_msg(Command.LEASE_ACQUIRE, self.client))
        raise_for_reply(codec.reply_from_msg(answer))
        granted_ns = self._robot_ns(answer)
        with self._lock:
            self._lease_since_ns = granted_ns
            self._controller_id = controller
            self._holds_lease = True
            self._grant += 1
            grant = self._grant
        threading.Thread(target=self._renew, args=(grant,), name="lease-renewal", daemon=True).start()

    @property
    def holds_lease(self) -> bool:
        return self._holds_lease

    def release_lease(self) -> None:
        self._check()
        self._holds_lease = False
        self._send(Command.LEASE_RELEASE)

    def _holds(self, grant: int) -> bool:
        """Whether the lease of `grant` is still the one held (a later grant supersedes it)."""
        return self._holds_lease and self._grant == grant

    def _renew(self, grant: int) -> None:
        """While the lease of `grant` is held: renew it every quarter of the controller's silence timeout
        (its watchdog on us), each renewal on its own thread so a slow answer never delays the next."""
        period = self.config.lease_silence_timeout / 4.0
        delay = histogram("lease renewal", "how late the renewal thread woke")
        due = time.monotonic()
        while self._holds(grant) and self._connected and not self.wire.closed:
            now = time.monotonic()
            delay.record(now - due)
            threading.Thread(target=self._renew_once, args=(grant,), name="lease-renewal-once",
                             daemon=True).start()
            due = max(due + period, now)   # after a long stall: renew now, not a burst of missed ones
            time.sleep(max(due - time.monotonic(), 0.0))

    def _renew_once(self, grant: int) -> None:
        try:
            self._send(Command.LEASE_RENEW)
        except LeaseHeld as exc:  # refused: the controller dropped the lease of this grant
            with self._lock:
                # a refusal that arrives after the lease was taken again speaks of the old grant
                current = self._holds(grant)
                if current:
                    self._holds_lease = False
            if current:
                note = self._status.lease_note if self._status is not None else ""
                self._lease_taken(note or exc.text)
        except ControllerError as exc:  # no answer now: the controller's watchdog decides
            log.debug("lease renewal: %s", exc)
        except Exception as exc:  # the session is closing under us
            log.debug("lease renewal: %s", exc)

    def execute(self, trajectory: JointTrajectory) -> ZenohMotionHandle:
        self._check()
        reply, stamp_ns = self._submit(trajectory)
        return ZenohMotionHandle(self, raise_for_reply(reply), np.asarray(trajectory.positions)[-1], stamp_ns,
                                 trajectory.duration)

    def submit(self, trajectory: JointTrajectory) -> Reply:
        """Submit and return the controller's reply as it is (no exception on rejection)."""
        self._check()
        return self._submit(trajectory)[0]

    def _submit(self, trajectory: JointTrajectory) -> tuple[Reply, int]:
        """The controller's reply to a trajectory and its robot-time stamp (ns)."""
        answer, _ = self._request("controller/trajectory", codec.trajectory_msg(trajectory))
        return codec.reply_from_msg(answer), self._robot_ns(answer)

    def _robot_ns(self, answer: Any) -> int:
        """Robot time (ns) of a reply's stamp."""
        with self._lock:
            timebase = self._timebase or WALL
        return timebase.robot(messages.stamp_to_ns(answer.header.stamp))

    def move_to(self, q: FloatArray) -> ZenohMotionHandle:
        self._check()
        goal = np.asarray(q, dtype=float)
        reply, stamp = self._send(Command.MOVE_TO, values=goal)
        return ZenohMotionHandle(self, reply, goal, stamp)

    def jog(self, joint: str, delta: float) -> ZenohMotionHandle:
        """Move one joint by `delta` rad from where the queue ends."""
        self._check()
        names = self.robot_config.joint_names
        if joint not in names:
            raise InvalidArgument(f"jog: joint must be one of {', '.join(names)}, got {joint!r}")
        base = self.joint_state().positions.copy()
        base[names.index(joint)] += delta
        reply, stamp = self._send(Command.JOG, joint=joint, values=(delta,))
        return ZenohMotionHandle(self, reply, base, stamp)

    def stop(self) -> None:
        self._check()
        self._send(Command.STOP_MOTION)

    def command(self, code: int, arm: str = "", values: Sequence[float] = (), joint: str = "") -> None:
        self._check()
        self._send(code, arm, values, joint)

    def grip(self, arm: str, closed: bool) -> None:
        self.command(Command.GRIP_CLOSE if closed else Command.GRIP_OPEN, arm=arm)

    # ------------------------------------------------------------------ state
    def status(self) -> ControllerStatus:
        self._check()
        with self._lock:
            assert self._status is not None
            return self._status

    def gripper_states(self) -> dict[str, bool]:
        """As the controller last published them (on each change, and now and then at rest: a client
        that came late hears every gripper within the reply timeout)."""
        self._check()
        arms = {arm.name for arm in self.robot_config.arms}
        end = time.monotonic() + self.config.reply_timeout
        while True:
            with self._lock:
                states = dict(self._grippers)
            if arms <= set(states):
                return states
            if time.monotonic() >= end:
                unheard = ", ".join(sorted(arms - set(states)))
                raise ControllerTimeout(f"controller/gripper: no state of gripper {unheard} within "
                                        f"{self.config.reply_timeout:g} s")
            self._changed.wait(_POLL_S)

    def status_message(self) -> Any:
        """The latest raw `ControllerStatus` message (with link_ok per group, time scale, faults)."""
        self._check()
        with self._lock:
            return self._status_msg

    def joint_state(self) -> JointFeedback:
        self._check()
        with self._lock:
            feedback = self._latest_feedback()
            assert feedback is not None
            return feedback

    def wait_status(self, predicate: Callable[[ControllerStatus], bool],
                    timeout: float) -> ControllerStatus | None:
        """The first status (received from now on, or the current one) satisfying `predicate`."""
        end = time.monotonic() + timeout
        while True:
            with self._lock:
                st = self._status
            if st is not None and predicate(st):
                return st
            if time.monotonic() >= end:
                return None
            self._changed.wait(_POLL_S)
