"""`MotorosController`: the cell's `Controller` interface over MotoROS 1, to a real DX100 or the
emulator's MotoROS server (`foldcell controller serve --motoros`).

- The state port gives the joint state (JOINT_FEEDBACK per group, or the fork's aggregated one) and
  ROBOT_STATUS, mapped onto `JointFeedback` and `ControllerStatus` (MotoROS stamps no time: the stamp
  is wall seconds since `connect`, and it reports no queue count, alarm text or hold).
- A trajectory is streamed point by point on the motion port: the start point (sequence 0), then each
  point, resent every `_RETRY_S` while the answer is BUSY (as the ROS client does). Upstream sends one
  MOTO_JOINT_TRAJ_PT_FULL_EX with every group; the fork one 13-slot JOINT_TRAJ_PT_FULL. `execute`
  returns once the start point and the points that fit the queue are accepted; a thread sends the rest.
- MotoROS has no lease: `acquire_lease` only checks the link (the controller's own rules decide who
  commands; the emulator gives its lease to the client host). It never enables the robot by itself:
  START_TRAJ_MODE (and START_SERVOS after an e-stop) are explicit `command`s.
- The grippers are output bits written on the motion port (`gripper_outputs`, config/motoros.yaml).
- With `tls` (the cell's `--security`) both connections are TLS: the client shows its role's
  certificate and accepts only a server certificate of the cell's CA valid for `host`.
"""

from __future__ import annotations

import logging
import socket
import ssl
import threading
import time
from collections.abc import Callable, Sequence

import numpy as np

from drivers.controller.codes import Command, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig, default_controller_config
from drivers.controller.errors import (
    ControllerError,
    ControllerGone,
    ControllerTimeout,
    InvalidArgument,
    TrajectoryRejected,
    raise_for_reply,
)
from drivers.controller.interface import (
    POLL_S,
    Controller,
    ControllerStatus,
    GroupStatus,
    JointFeedback,
    MotionStatus,
    PolledMotionHandle,
)
from drivers.controller.motion import Axes, move_trajectory
from drivers.controller.trajectory import FloatArray, JointTrajectory, sample
from drivers.motoros import messages as sm
from drivers.motoros.config import MotorosConfig, load_motoros_config
from drivers.robot.config import RobotConfig, default_robot_config

log = logging.getLogger(__name__)

_RETRY_S = 0.005  # the ROS client resends a BUSY point every ~5 ms (section 7)
# MotoROS truncates a point's time to whole ms (section 7), so a segment of a few ms between points
# planned at other times accelerates past the limits (an alarm); points go out at whole ms (`_whole_ms`)
# with this margin against float32 rounding (a float32 k ms may read as k - 1; good up to ~1000 s)
_TIME_MARGIN_S = 1e-4
_REST_VELOCITY = 1e-6  # rad/s (float32 feedback)
# The state port is another connection than the motion port: the burst read right after a point's reply
# may have been built before the point was queued; the second one after it was built after.
_FRESH_BURSTS = 2
# the commands MOTO_MOTION_CTRL carries (section 5)
_MOTION_CTRL = frozenset({Command.CHECK_MOTION_READY, Command.CHECK_QUEUE_CNT, Command.STOP_MOTION,
                          Command.START_SERVOS, Command.STOP_SERVOS, Command.RESET_ALARM,
                          Command.START_TRAJ_MODE, Command.STOP_TRAJ_MODE})
_FULL_VALID = sm.ValidFields.TIME | sm.ValidFields.POSITION | sm.ValidFields.VELOCITY


class MotorosMotionHandle(PolledMotionHandle):
    """A streamed trajectory: over when every point is sent, the robot idle and at the goal."""

    def __init__(self, owner: MotorosController, goal: FloatArray):
        super().__init__(owner.stop, 0, goal)
        self._owner = owner
        self.sent = threading.Event()  # every point accepted
        self.sent_burst = 0  # the owner's state burst count when the last point was accepted
        self.error: ControllerError | None = None  # the streaming thread's
        self.streaming_cancelled = threading.Event()

    def mark_sent(self) -> None:
        """Every point is accepted: the motion's end is judged on the state bursts from now on."""
        with self._owner._lock:
            self.sent_burst = self._owner._bursts
        self.sent.set()

    def cancel_streaming(self) -> None:
        """Send no more points (what was sent still runs unless the motion is stopped too)."""
        self.streaming_cancelled.set()

    def _poll(self) -> MotionStatus | None:
        if self._result is not None:
            return self._result
        owner = self._owner
        with owner._lock:
            status, feedback, bursts = owner._status, owner._feedback, owner._bursts
        if status is None or feedback is None:
            return None
        ended = MotionStatus.CANCELLED if self._cancelled else MotionStatus.ABORTED
        if self.error is not None or status.e_stopped or status.in_error:
            self._result = ended
        elif self.sent.is_set() and bursts < self.sent_burst + _FRESH_BURSTS:
            return None  # the status may predate the last point: a queue just filled is not seen yet
        elif self.sent.is_set() and not status.in_motion:
            at_goal = (np.abs(feedback.positions - self.goal) <= owner.config.goal_tolerance).all() and \
                (np.abs(feedback.velocities) <= _REST_VELOCITY).all()
            self._result = MotionStatus.SUCCEEDED if at_goal and not self._cancelled else ended
        elif self._cancelled and not status.in_motion:
            self._result = ended
        return self._result


class MotorosController(Controller):
    """A MotoROS controller at `host`: motion port `port`, state port `port` + 1; over TLS with `tls`."""

    def __init__(self, host: str, port: int | None = None, dialect: str | None = None,
                 config: ControllerConfig | None = None, robot_config: RobotConfig | None = None,
                 motoros_config: MotorosConfig | None = None, tls: ssl.SSLContext | None = None):
        super().__init__()
        self.motoros_config = motoros_config or load_motoros_config()
        self.host = host
        self.tls = tls
        self.port = port or self.motoros_config.port
        self.dialect = sm.DIALECTS[dialect or self.motoros_config.dialect]
        self.config = config or default_controller_config()
        self.robot_config = robot_config or default_robot_config()
        names = self.robot_config.joint_names
        self.group_columns = [np.array([names.index(j) for j in g.joints], dtype=int)
                              for g in self.robot_config.groups]
        self.gripper_outputs = dict(self.motoros_config.gripper_outputs)
        self._lock = threading.Lock()
        self._request_lock = threading.Lock()  # one request at a time, each answered before the next
        self._status: ControllerStatus | None = None
        self._feedback: JointFeedback | None = None
        self._positions = np.zeros(len(names))
        self._velocities = np.zeros(len(names))
        self._motion: socket.socket | None = None
        self._state: socket.socket | None = None
        self._started = 0.0
        self._streaming: MotorosMotionHandle | None = None
        self._bursts = 0  # state bursts received (each closed by a ROBOT_STATUS)
        self._state_listeners: list[Callable[[ControllerStatus, JointFeedback], None]] = []
        self._loss_listeners: list[Callable[[str], None]] = []

    def add_state_listener(self, listener: Callable[[ControllerStatus, JointFeedback], None]) -> None:
        """Call `listener(status, joint state)` at the end of every state burst (on the state thread)."""
        self._state_listeners.append(listener)

    def add_loss_listener(self, listener: Callable[[str], None]) -> None:
        """Call `listener(reason)` when the state stream of a connected controller ends (not on
        `disconnect`): the controller is gone."""
        self._loss_listeners.append(listener)

    # ------------------------------------------------------------------ life cycle
    def connect(self, timeout: float | None = None) -> None:
        """Open the motion and state connections and wait for the first state burst."""
        if self._connected:
            return
        wait = timeout if timeout is not None else self.config.reply_timeout
        try:
            self._motion = self._open(self.port, wait)
            self._state = self._open(self.port + 1, wait)
        except OSError as exc:  # ssl.SSLError too: the server's certificate not the CA's, or not for host
            self._close_sockets()
            raise ControllerGone(f"MotoROS at {self.host}:{self.port}: {exc}") from exc
        for sock in (self._motion, self._state):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._motion.settimeout(self.config.reply_timeout)
        self._state.settimeout(None)
        self._started = time.monotonic()
        threading.Thread(target=self._read_state, args=(self._state,), daemon=True,
                         name="motoros-state").start()
        deadline = time.monotonic() + wait
        while time.monotonic() < deadline:
            with self._lock:
                if self._status is not None and self._feedback is not None:
                    self._connected = True
                    return
            if self._state is None:  # the state thread saw it end (a server refusing our certificate)
                raise ControllerGone(f"MotoROS at {self.host}:{self.port}: the controller closed the "
                                     "connection before the first state")
            time.sleep(POLL_S)
        self._close_sockets()
        raise ControllerGone(f"MotoROS at {self.host}:{self.port}: no state within {wait:g} s")

    def _open(self, port: int, timeout: float) -> socket.socket:
        sock = socket.create_connection((self.host, port), timeout=timeout)
        if self.tls is None:
            return sock
        return self.tls.wrap_socket(sock, server_hostname=self.host)  # closes the socket on failure

    def disconnect(self) -> None:
        """Closing the motion connection stops the robot (MotoROS drops the increments)."""
        if not self._connected:
            return
        self._connected = False
        if self._streaming is not None:
            self._streaming.cancel_streaming()
        self._close_sockets()

    def _close_sockets(self) -> None:
        for sock in (self._motion, self._state):
            if sock is not None:
                sock.close()
        self._motion = self._state = None

    # ------------------------------------------------------------------ state port
    def _read_state(self, sock: socket.socket) -> None:
        framer = sm.Framer(self.dialect)
        try:
            while True:
                data = sock.recv(65536)
                if not data:
                    break
                for frame in framer.frames(data):
                    self._on_state(sm.decode(frame, self.dialect))
            reason = "the state connection was closed"
        except (OSError, sm.MotorosError) as exc:
            reason = f"the state stream ended: {exc}"
        with self._lock:
            self._status = None  # stale from now on
            ours = self._state is not sock  # `disconnect` closed it
        if ours:
            return
        was_connected, self._connected = self._connected, False
        log.warning("MotoROS at %s:%d: %s", self.host, self.port, reason)
        self._close_sockets()  # a later `connect` opens both again
        if was_connected:
            for listener in list(self._loss_listeners):
                listener(f"MotoROS at {self.host}:{self.port}: {reason}")

    def _on_state(self, message: sm.Message) -> None:
        body = message.body
        if isinstance(body, sm.JointFeedback):
            columns = np.concatenate(self.group_columns) if self.dialect.name == "clopema" else \
                self.group_columns[body.group] if 0 <= body.group < len(self.group_columns) else None
            if columns is None:
                return
            with self._lock:
                self._positions[columns] = body.positions[:len(columns)]
                self._velocities[columns] = body.velocities[:len(columns)]
        elif isinstance(body, sm.RobotStatus):
            stamp = time.monotonic() - self._started
            groups = tuple(GroupStatus(
                name=g.name, controller=g.controller, drives_powered=body.drives_powered == 1,
                e_stopped=body.e_stopped == 1, in_error=body.in_error == 1, error_code=body.error_code,
                alarm_text="", in_motion=body.in_motion == 1, mode=body.mode,
                motion_possible=body.motion_possible == 1, held=False, queue_count=0,
                trajectory_mode=body.motion_possible == 1) for g in self.robot_config.groups)
            status = ControllerStatus(stamp, groups)
            with self._lock:
                # the status closes a burst: the feedback before it is one sample
                feedback = JointFeedback(stamp, self.robot_config.joint_names, self._positions.copy(),
                                         self._velocities.copy(), np.zeros_like(self._positions),
                                         np.zeros_like(self._positions))
                self._feedback, self._status = feedback, status
                self._bursts += 1
            self._status_received(status)
            for listener in list(self._state_listeners):
                listener(status, feedback)

    # ------------------------------------------------------------------ motion port
    def _request(self, body: sm.Body) -> sm.Message:
        """Send one message and read its reply (section 6: one write, then wait for the answer)."""
        self._check()
        with self._request_lock:
            sock = self._motion
            if sock is None:
                raise ControllerGone(f"MotoROS at {self.host}:{self.port}: the motion connection is closed")
            try:
                sock.sendall(sm.encode(body, self.dialect))
                framer = sm.Framer(self.dialect)
                while (frames := framer.frames(b"")) == []:
                    data = sock.recv(65536)
                    if not data:
                        raise ControllerGone(f"MotoROS at {self.host}:{self.port}: motion connection closed")
                    framer.feed(data)
            except TimeoutError as exc:
                raise ControllerTimeout(f"MotoROS at {self.host}:{self.port}: no reply within "
                                        f"{self.config.reply_timeout:g} s") from exc
            except (OSError, sm.MotorosError) as exc:
                raise ControllerGone(f"MotoROS at {self.host}:{self.port}, motion connection: {exc}") from exc
        return sm.decode(frames[0], self.dialect)

    def _reply(self, body: sm.Body, what: str) -> Reply:
        message = self._request(body)
        if not isinstance(message.body, sm.MotionReply):
            raise ControllerError(f"{what}: MotoROS answered a {sm.MsgType(message.msg_type).name}")
        reply = message.body
        return Reply(reply.result, reply.subcode, f"{what}: " + Reply(reply.result, reply.subcode).describe())

    def _ctrl(self, command: Command) -> Reply:
        return self._reply(sm.MotionCtrl(0, 0, int(command), ()), command.name)

    # ------------------------------------------------------------------ the interface
    def acquire_lease(self) -> None:
        self._check()

    def release_lease(self) -> None:
        self.stop()

    def stop(self) -> None:
        self._check()
        if self._streaming is not None:
            self._streaming.cancel_streaming()
        raise_for_reply(self._ctrl(Command.STOP_MOTION))

    def command(self, code: int, arm: str = "", values: Sequence[float] = (), joint: str = "") -> None:
        self._check()
        if code in (Command.GRIP_OPEN, Command.GRIP_CLOSE):
            self.grip(arm, code == Command.GRIP_CLOSE)
            return
        if code not in _MOTION_CTRL:
            raise InvalidArgument(f"command {code}: MotoROS has no such command", Result.INVALID,
                                  Subcode.INVALID_COMMAND)
        reply = self._ctrl(Command(code))
        if code == Command.CHECK_MOTION_READY and reply.result == Result.FAILURE:
            reply = Reply(Result.NOT_READY, reply.subcode, reply.text)  # FALSE: not ready, and why
        raise_for_reply(reply)

    def grip(self, arm: str, closed: bool) -> None:
        self._check()
        if arm not in self.gripper_outputs:
            raise InvalidArgument(f"grip: arm must be one of {', '.join(self.gripper_outputs)}, got {arm!r}")
        output = sm.IoWrite(sm.MsgType.MOTO_WRITE_IO_BIT, self.gripper_outputs[arm], int(closed))
        message = self._request(output)
        if not isinstance(message.body, sm.IoWriteReply) or message.body.result_code != sm.IoResult.OK:
            raise ControllerError(f"grip {arm}: the output write was refused ({message.body})")

    def gripper_states(self) -> dict[str, bool]:
        """Each gripper's output bit, read back (MotoROS' state stream reports no I/O)."""
        self._check()
        states = {}
        for arm, address in self.gripper_outputs.items():
            message = self._request(sm.IoAddress(sm.MsgType.MOTO_READ_IO_BIT, address))
            if not isinstance(message.body, sm.IoReadReply) or message.body.result_code != sm.IoResult.OK:
                raise ControllerError(f"gripper {arm}: the output read was refused ({message.body})")
            states[arm] = bool(message.body.value)
        return states

    def status(self) -> ControllerStatus:
        return self._latest()[0]

    def joint_state(self) -> JointFeedback:
        return self._latest()[1]

    def _latest(self) -> tuple[ControllerStatus, JointFeedback]:
        self._check()
        with self._lock:
            if self._status is None or self._feedback is None:
                raise ControllerGone(f"MotoROS at {self.host}:{self.port}: the state stream ended")
            return self._status, self._feedback

    def move_to(self, q: FloatArray) -> MotorosMotionHandle:
        self._check()
        axes = Axes.of(self.robot_config, self.robot_config.joint_names)
        planned = move_trajectory(Command.MOVE_TO, axes, self.joint_state().positions, q, "",
                                  Reply(Result.SUCCESS), self.config)
        if isinstance(planned, Reply):
            raise_for_reply(planned)
            handle = MotorosMotionHandle(self, np.asarray(q, dtype=float))
            handle.mark_sent()  # already there
            return handle
        return self.execute(planned)

    def execute(self, trajectory: JointTrajectory) -> MotorosMotionHandle:
        """Stream `trajectory` (13 joints, project order) resampled at whole ms (`_whole_ms`: error
        messages number those points); raises on the start point's refusal and on the refusal of any point
        sent before returning."""
        self._check()
        names = self.robot_config.joint_names
        if tuple(trajectory.joint_names) != names:
            raise TrajectoryRejected(f"joint names: must be {', '.join(names)}", Result.INVALID,
                                     Subcode.INVALID_DATA)
        times, positions, velocities = _whole_ms(np.asarray(trajectory.times, dtype=float),
                                                 np.asarray(trajectory.positions, dtype=float),
                                                 trajectory.point_velocities)
        bodies = [self._point(k, times[k] + _TIME_MARGIN_S, positions[k], velocities[k])
                  for k in range(len(times))]
        handle = MotorosMotionHandle(self, positions[-1])
        next_point = self._send_until_busy(bodies, 0)
        self._streaming = handle
        if next_point == len(bodies):
            handle.mark_sent()
        else:
            threading.Thread(target=self._stream, args=(handle, bodies, next_point), daemon=True,
                             name="motoros-stream").start()
        return handle

    def _point(self, sequence: int, time_s: float, positions: FloatArray, velocities: FloatArray) -> sm.Body:
        if self.dialect.name == "clopema":
            return sm.JointTrajPtFull(0, sequence, _FULL_VALID, float(time_s), tuple(positions),
                                      tuple(velocities), ())
        blocks = tuple(sm.JointFeedback(k, _FULL_VALID, float(time_s), tuple(positions[columns]),
                                        tuple(velocities[columns]), ())
                       for k, columns in enumerate(self.group_columns))
        return sm.JointTrajPtFullEx(sequence, blocks)

    def _send_point(self, body: sm.Body, index: int) -> bool:
        """True when accepted, False on BUSY; raises the typed error of a refusal."""
        reply = self._reply(body, f"point {index}")
        if reply.result == Result.BUSY:
            return False
        raise_for_reply(Reply(reply.result, reply.subcode, reply.text, point=index))
        return True

    def _send_until_busy(self, bodies: list[sm.Body], start: int) -> int:
        index = start
        while index < len(bodies) and self._send_point(bodies[index], index):
            index += 1
        return index

    def _stream(self, handle: MotorosMotionHandle, bodies: list[sm.Body], index: int) -> None:
        cancelled = handle.streaming_cancelled
        try:
            while index < len(bodies) and not cancelled.is_set():
                if self._send_point(bodies[index], index):
                    index += 1
                else:
                    time.sleep(_RETRY_S)
            if not cancelled.is_set():
                handle.mark_sent()
        except ControllerError as exc:
            log.warning("MotoROS streaming stopped at point %d: %s", index, exc)
            handle.error = exc


def _whole_ms(times: FloatArray, positions: FloatArray,
              velocities: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The trajectory's points moved to the nearest whole ms (the last one up to the next), positions and
    velocities taken on the same curve there; the first and last points stay as they are."""
    ms = np.unique(np.round(times[:-1] * 1000.0))
    end = np.ceil(times[-1] * 1000.0 - 1e-9)
    instants = np.append(ms[ms < end], end) / 1000.0
    new_positions, new_velocities, _ = sample(times, positions, velocities, instants)
    new_positions[0], new_velocities[0] = positions[0], velocities[0]
    new_positions[-1], new_velocities[-1] = positions[-1], velocities[-1]
    return instants, new_positions, new_velocities
