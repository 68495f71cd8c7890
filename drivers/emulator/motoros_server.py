"""`MotorosServer`: the emulator speaks MotoROS 1 over TCP, in front of the same `ControllerCore` its
Zenoh side drives (one robot, one source of truth).

Protocol facts: `shared/facts/motoros-simple-message.md` (section numbers below refer to it).
- Motion port PORT (1 connection) and state port PORT+1 (4 connections), TCP_NODELAY and SO_KEEPALIVE.
- Points are streamed one by one (messages 14 and 2016). Each point after the start point (sequence 0)
  makes a cubic Hermite segment from the previous one, cut into one increment per interpolation tick
  into a per-group queue of `queue_increments`; while a point's segment does not fit yet, the next
  point gets BUSY and the client resends it. The core executes one increment per tick (`on_tick`,
  called after every `core.step()`), so the Zenoh side sees the same motion; its status shows the
  queued increments as one trajectory in motion (`core.outside_motion`).
- The state port sends, every `state_period`, JOINT_FEEDBACK per group, the _EX message (two groups
  or more) and ROBOT_STATUS (CloPeMa: one 13-slot JOINT_FEEDBACK and ROBOT_STATUS).
- The IO port PORT+2 (upstream only; IO messages are also taken on the motion port): each arm's gripper
  is an output bit (`gripper_outputs` in config/motoros.yaml), other addresses an in-memory table.
- The control lease covers both sides: a client host takes it when its motion or IO connection first
  needs it (if free) and loses it when its last one closes. A motion connection that closes stops the
  motion it streamed.
- With `tls` (the cell's `--security`), every port speaks simple message inside TLS: a client shows a
  certificate of the cell's CA whose role (its common name) may command the controller, or it is
  closed, logged, before it takes a slot. Its lease is its role's at its host (`motoros:cell@HOST`).
  The handshake runs on the connection's own thread: a client that stalls in it holds up nobody.

Where the emulator departs from MotoROS (each on purpose):
- Servos never come back after an e-stop unless a START_SERVOS (or a servo on from the Zenoh side) asks
  for it: START_TRAJ_MODE, which switches servos on by itself in MotoROS (section 8), answers
  NOT_READY/SERVO_OFF after an e-stop. The automatic re-enable moved robots after an e-stop (motoman#154).
- A disconnect drops the queued increments (MotoROS leaves them to run on the next connection).
- A frame split by TCP is reassembled; one still incomplete after `partial_frame_timeout` gets
  INVALID/3001 (MotoROS answers every short recv() chunk so). The length prefix, which MotoROS never
  reads, must match the type's size: a wrong prefix gets INVALID/3001 and the bytes are dropped.
- A point with sequence > 0 before any start point gets INVALID/3005 (MotoROS interpolates from
  whatever it last had).
- Another commander holding the lease (the Zenoh side) makes points NOT_READY/5000 (unspecified).
- An unknown MOTION_CTRL command gets INVALID/3006 (MotoROS resends its previous reply).
- MOTO_GET_DH_PARAMETERS answers zeros (the emulator has no DH table); IO addresses are not checked.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import ssl
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.controller.codes import Command, Mode, Result, Subcode
from drivers.controller.trajectory import FloatArray, hermite
from drivers.emulator.core import ControllerCore
from drivers.motoros import messages as sm
from drivers.motoros.config import MotorosConfig

log = logging.getLogger(__name__)

# upstream closes the motion connection, without a reply, on a message only a controller sends (section 6)
_CLOSING_TYPES = frozenset({sm.MsgType.ROBOT_STATUS, sm.MsgType.JOINT_FEEDBACK, sm.MsgType.MOTO_MOTION_REPLY,
                            sm.MsgType.MOTO_JOINT_FEEDBACK_EX})
# REP messages MotoROS 1 does not know (section 3)
_UNKNOWN_TYPES = frozenset({sm.MsgType.JOINT_POSITION, sm.MsgType.JOINT_TRAJ_PT})
_IO_TYPES = frozenset(sm.IO_ADDRESS_TYPES + sm.IO_WRITE_TYPES)
_FULL_VALID = sm.ValidFields.TIME | sm.ValidFields.POSITION | sm.ValidFields.VELOCITY
_FEEDBACK_VALID = {"upstream": sm.ValidFields.POSITION | sm.ValidFields.VELOCITY,
                   "clopema": sm.ValidFields.POSITION}  # section 11: the fork sends no speed
# the lease's session id of a MotoROS client: motoros@HOST, over TLS motoros:ROLE@HOST (`_session`)
_SESSION_PREFIXES = ("motoros@", "motoros:")
_POLL_S = 0.5  # how often idle connection threads look whether the server is closing
_HANDSHAKE_TIMEOUT_S = 10.0  # a TLS client that has not finished its handshake by then is closed
_BIND_ATTEMPTS = 20  # an ephemeral motion port whose next port is taken: try another pair


@dataclass(frozen=True)
class _Point:
    time_ms: int
    positions: FloatArray
    velocities: FloatArray


@dataclass
class _Segment:
    start: _Point
    end: _Point
    next_ms: int  # trajectory time of the next increment


@dataclass
class _Group:
    """One control group: its joints (columns of the core), queue, and the point being converted."""

    index: int
    name: str
    columns: NDArray[np.int_]
    max_velocity: FloatArray
    is_robot: bool
    increments: deque[tuple[FloatArray, FloatArray, FloatArray]] = field(default_factory=deque)
    pending: _Segment | None = None  # MotoROS' one-point slot
    last: _Point | None = None  # the previous accepted point: the next segment starts here

    def clear(self) -> None:
        self.increments.clear()
        self.pending = None

    def fill(self, capacity: int, period_ms: int) -> None:
        """Cut the pending segment into increments while the queue has room; the last increment of a
        segment ends on its point (shorter than a period when the time is not a whole number of ticks)."""
        while self.pending is not None and len(self.increments) < capacity:
            seg = self.pending
            t = min(seg.next_ms, seg.end.time_ms)
            duration = (seg.end.time_ms - seg.start.time_ms) / 1000.0
            tau = (t - seg.start.time_ms) / 1000.0
            p, v, a = hermite(seg.start.positions, seg.start.velocities, seg.end.positions,
                              seg.end.velocities, duration, tau)
            self.increments.append((p, v, a))
            if t >= seg.end.time_ms:
                self.pending = None
            else:
                seg.next_ms = t + period_ms


@dataclass(frozen=True)
class ServerTls:
    """TLS on every port: the server's context (its certificate; client certificates of the cell's CA
    required) and the roles, client certificates' common names, admitted."""

    context: ssl.SSLContext
    roles: frozenset[str]


@dataclass
class _Connection:
    sock: socket.socket
    kind: str  # motion, state, io
    name: str  # for the logs: kind, number, peer address
    session: str  # the lease's: one per client host (and role), so its motion and IO connections share it
    closed: threading.Event = field(default_factory=threading.Event)

    def close(self) -> None:
        self.closed.set()
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        self.sock.close()


class MotorosServer:
    """MotoROS motion, state (and, upstream, IO) ports over `core`. Every use of the core holds `lock`
    (the node's).

    `heard(session)` is told, every tick, that the motion client is still connected (the node's lease
    watchdog). `port` 0 picks free consecutive ports (motion, state, IO); `ports` says which. `tls`:
    every port over TLS, for the admitted roles only (module doc).
    """

    def __init__(self, core: ControllerCore, lock: threading.RLock, config: MotorosConfig,
                 host: str = "127.0.0.1", port: int | None = None, dialect: str | None = None,
                 heard: Callable[[str], None] | None = None, tls: ServerTls | None = None):
        self.core = core
        self.tls = tls
        self.lock = lock
        self.config = config
        self.host = host
        self.requested_port = config.port if port is None else port
        self.dialect = sm.DIALECTS[dialect or config.dialect]
        self.heard = heard
        self.start_tolerance = config.start_tolerance(self.dialect.name)
        self.period_ms = round(core.period * 1000)
        robots = {arm.group for arm in core.arms}
        self.groups: list[_Group] = []
        for index, group in enumerate(core.groups):
            columns = np.array([core.joint_names.index(j) for j in group.joints], dtype=int)
            self.groups.append(_Group(index, group.name, columns, core.axes.max_velocity[columns],
                                      group.name in robots))
        slots = sum(len(g.columns) for g in self.groups) if self.dialect.name == "clopema" else \
            max(len(g.columns) for g in self.groups)
        if slots > self.dialect.joint_slots:
            raise ValueError(f"groups: {slots} joints do not fit {self.dialect.name}'s "
                             f"{self.dialect.joint_slots} slots")
        self.io: dict[tuple[int, int], int] = {}  # (read type, address) -> value
        self._owner: _Connection | None = None  # the connection whose points fill the queues
        self._estops_cleared = 0  # the core's e-stop count the servos were last switched on after
        # the fork has no IO port (section 1)
        self.kinds = ("motion", "state") if self.dialect.name == "clopema" else ("motion", "state", "io")
        self._connections: dict[str, list[_Connection]] = {kind: [] for kind in self.kinds}
        self.grippers = {address: arm for arm, address in config.gripper_outputs if arm in core.grippers}
        self._listeners: list[socket.socket] = []
        self._threads: list[threading.Thread] = []
        self._closing = threading.Event()
        self._next_client = 1
        self.ports: tuple[int, ...] = ()

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        self._listeners = self._bind()
        self.ports = tuple(listener.getsockname()[1] for listener in self._listeners)
        with self.lock:
            self.core.outside_motion = self._queued  # the Zenoh side's status shows the streamed motion
        for listener, kind in zip(self._listeners, self.kinds, strict=True):
            self._spawn(self._accept_loop, listener, kind)
        log.info("MotoROS %s server on %s%s: %s", self.dialect.name, self.host,
                 f" over TLS for {', '.join(sorted(self.tls.roles))}" if self.tls else "",
                 ", ".join(f"{kind} port {port}" for kind, port in zip(self.kinds, self.ports, strict=True)))

    def _bind(self) -> list[socket.socket]:
        """One listener per kind on consecutive ports from the motion port."""
        for _ in range(_BIND_ATTEMPTS):
            bound = [_listener(self.host, self.requested_port)]
            try:
                for offset in range(1, len(self.kinds)):
                    bound.append(_listener(self.host, bound[0].getsockname()[1] + offset))
                return bound
            except OSError:
                for listener in bound:
                    listener.close()
                if self.requested_port:
                    raise
        raise OSError(f"no {len(self.kinds)} free consecutive ports on {self.host}")

    def close(self) -> None:
        self._closing.set()
        for listener in self._listeners:
            with contextlib.suppress(OSError):
                listener.shutdown(socket.SHUT_RDWR)  # wakes the accept() (a close alone does not, on Linux)
            listener.close()
        for conns in self._connections.values():
            for conn in list(conns):
                conn.close()
        for thread in self._threads:
            thread.join(timeout=2.0)
        with self.lock:
            self._stop_streaming()
            self.core.outside_motion = lambda: False

    def _spawn(self, target: Callable[..., None], *args: Any) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True, name=f"motoros-{target.__name__}")
        self._threads = [t for t in self._threads if t.is_alive()] + [thread]
        thread.start()

    def _accept_loop(self, listener: socket.socket, kind: str) -> None:
        while not self._closing.is_set():
            try:
                sock, address = listener.accept()
            except OSError:
                return  # the listener was closed
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
            self._spawn(self._serve, sock, address, kind)

    def _serve(self, sock: socket.socket, address: tuple[str, int], kind: str) -> None:
        """One connection, on its own thread: authenticated (with `tls`), admitted, served."""
        role = ""
        if self.tls is not None:
            authenticated = self._authenticate(sock, f"{kind} connection from {address[0]}:{address[1]}")
            if authenticated is None:
                return
            sock, role = authenticated
        with self.lock:
            name = f"{kind}-{self._next_client}@{address[0]}:{address[1]}" + (f" ({role})" if role else "")
            conn = _Connection(sock, kind, name, _session(address[0], role))
            self._next_client += 1
            if not self._admit(conn):
                return
        if kind == "state":
            self._serve_state(conn)
        else:
            self._serve_motion(conn)

    def _authenticate(self, sock: socket.socket, where: str) -> tuple[ssl.SSLSocket, str] | None:
        """The TLS handshake and the role of the client's certificate; None (closed, logged) when the
        handshake fails or the role may not command."""
        assert self.tls is not None
        sock.settimeout(_HANDSHAKE_TIMEOUT_S)
        try:
            secured = self.tls.context.wrap_socket(sock, server_side=True)  # closes the socket on failure
        except ssl.SSLEOFError:
            log.info("MotoROS %s closed before its TLS handshake", where)  # a probe whether the port is up
            return None
        except OSError as exc:  # ssl.SSLError, a timeout, a reset
            log.warning("MotoROS %s refused: TLS handshake failed: %s", where, exc)
            return None
        role = _common_name(secured.getpeercert())
        if role not in self.tls.roles:
            log.warning("MotoROS %s refused: its certificate's role %r may not command the controller "
                        "(roles that may: %s)", where, role, ", ".join(sorted(self.tls.roles)))
            secured.close()
            return None
        secured.settimeout(None)
        return secured, role

    def _admit(self, conn: _Connection) -> bool:
        """Section 1: beyond the slots, upstream drops the old connection for the newcomer unless
        increments are queued (then the newcomer is closed); the fork always closes the newcomer."""
        if self._closing.is_set():  # authenticated while the server closed
            conn.close()
            return False
        conns = self._connections[conn.kind]
        slots = {"motion": self.config.motion_slots, "state": self.config.state_slots,
                 "io": self.config.io_slots}[conn.kind]
        if len(conns) >= slots:
            if self.dialect.name == "clopema" or self._queued():
                log.warning("MotoROS %s connection refused: all %d slots taken", conn.kind, slots)
                conn.close()
                return False
            old = conns.pop(0)
            log.warning("MotoROS %s connection %s dropped for a newcomer", conn.kind, old.name)
            old.close()
        conns.append(conn)
        log.info("MotoROS connection %s", conn.name)
        return True

    # ------------------------------------------------------------------ the core's tick
    def needs_ticks(self) -> bool:
        """Increments are queued: the node must step every tick (`drivers.emulator.node.TickListener`)."""
        return self._queued()

    def on_tick(self) -> None:
        """After every `core.step()`, holding the lock: execute one increment per group, refill."""
        core = self.core
        if not self._queued():
            self._tell_heard()
            return
        not_ready = self._not_ready(self._owner_session)
        if not_ready is not None:
            # section 8: faults clear the queues; the fork keeps them through an alarm (section 11)
            if self.dialect.name == "upstream" or not_ready != Subcode.NOT_READY_ALARM:
                log.warning("MotoROS: not ready (%s): queued increments dropped", Subcode(not_ready).name)
                self._stop_streaming()
            return
        if core.queue_count:
            return  # the Zenoh side's trajectory runs: points were refused meanwhile
        if any(g.increments for g in self.groups):
            position, velocity, acceleration = core.q.copy(), np.zeros_like(core.q), np.zeros_like(core.q)
            for group in self.groups:
                if group.increments:
                    p, v, a = group.increments.popleft()
                    position[group.columns], velocity[group.columns], acceleration[group.columns] = p, v, a
            core.follow(position, velocity, acceleration)
        for group in self.groups:
            group.fill(self.config.queue_increments, self.period_ms)
        self._tell_heard()

    def _tell_heard(self) -> None:
        if self.heard is not None:
            for conn in self._connections["motion"] + self._connections.get("io", []):
                self.heard(conn.session)

    @property
    def _owner_session(self) -> str:
        return self._owner.session if self._owner is not None else ""

    def _queued(self) -> bool:
        return any(g.increments or g.pending is not None for g in self.groups)

    def _stop_streaming(self) -> None:
        for group in self.groups:
            group.clear()

    # ------------------------------------------------------------------ readiness and the lease
    def _not_ready(self, session: str) -> int | None:
        """The NOT_READY subcode, the first that applies in MotoROS' order (section 5), or None."""
        core = self.core
        checks = ((core.alarm_code != 0, Subcode.NOT_READY_ALARM),
                  (core.e_stopped, Subcode.NOT_READY_ESTOP),
                  (core.mode != Mode.AUTO, Subcode.NOT_READY_NOT_PLAY),
                  (not core.remote, Subcode.NOT_READY_NOT_REMOTE),
                  (not core.servo_on, Subcode.NOT_READY_SERVO_OFF),
                  (core.held, Subcode.NOT_READY_HOLD),
                  (not core.traj_mode, Subcode.NOT_READY_NOT_STARTED),
                  (not self._may_command(session), Subcode.NOT_READY_UNSPECIFIED))
        return next((int(sub) for failed, sub in checks if failed), None)

    def _may_command(self, session: str) -> bool:
        holder = self.core.lease_holder
        return not self.core.config.lease_required or holder in ("", session)

    def _after_estop(self) -> bool:
        """An e-stop happened and the servos were not switched on explicitly since."""
        core = self.core
        if core.servo_on:  # switched on explicitly (START_SERVOS, or the Zenoh side's servo on)
            self._estops_cleared = core.estop_count
        return core.estop_count != self._estops_cleared

    def _claim(self, session: str) -> bool:
        """Take the control lease for `session` if it is free; False if another commander holds it."""
        core = self.core
        if not core.config.lease_required or core.lease_holder == session:
            return True
        if core.lease_holder:
            return False
        return core.command(Command.LEASE_ACQUIRE, session).ok

    def _core_command(self, command: Command, session: str) -> bool:
        return self._claim(session) and self.core.command(command, session).ok

    # ------------------------------------------------------------------ motion port
    def _serve_motion(self, conn: _Connection) -> None:
        framer = sm.Framer(self.dialect)
        try:
            while not conn.closed.is_set():
                try:
                    conn.sock.settimeout(self.config.partial_frame_timeout if framer.pending else _POLL_S)
                    data = conn.sock.recv(65536)
                except TimeoutError:
                    if framer.pending:
                        msg_type = framer.peek_type()
                        framer.clear()
                        self._send(conn, self._framing_error(sm.MotorosError(
                            "length", "the frame's bytes stopped arriving", 3001), msg_type))
                    continue
                except OSError:
                    return
                if not data:
                    return
                framer.feed(data)
                if not self._process(conn, framer):
                    return
        finally:
            self._motion_closed(conn)

    def _process(self, conn: _Connection, framer: sm.Framer) -> bool:
        """Handle every whole frame buffered; False when the connection is to close."""
        while True:
            try:
                frame = framer.next_frame()
            except sm.MotorosError as exc:
                msg_type = framer.peek_type()
                framer.clear()  # the rest of the chunk is dropped (section 6)
                log.info("MotoROS %s: %s", conn.name, exc)
                self._send(conn, self._framing_error(exc, msg_type))
                continue
            if frame is None:
                return True
            try:
                message = sm.decode(frame, self.dialect)
            except sm.MotorosError as exc:
                self._send(conn, self._framing_error(exc, sm.read_header(frame, self.dialect)[1]))
                continue
            if message.msg_type in _CLOSING_TYPES and self.dialect.name == "upstream":
                log.warning("MotoROS %s sent a %s, a controller's message: closing", conn.name,
                            sm.MsgType(message.msg_type).name)
                return False
            with self.lock:
                try:
                    reply, keep = self._handle(conn, message)
                except Exception:  # a bug must not take the server down: logged, answered, served on
                    log.exception("MotoROS %s: handling message %d failed", conn.name, message.msg_type)
                    reply, keep = self._reply(-1, -1, message.msg_type, Result.INVALID,
                                              Subcode.INVALID_UNSPECIFIED), True
            # upstream sends no reply to a message that is itself a reply (comm 3); the fork does
            silent = message.comm_type == sm.CommType.SERVICE_REPLY and self.dialect.name == "upstream"
            if reply is not None and not silent:
                self._send(conn, reply)
            if not keep:
                return False

    def _framing_error(self, exc: sm.MotorosError, msg_type: int) -> bytes:
        subcode = exc.subcode
        if self.dialect.name == "clopema" and subcode == Subcode.INVALID_MSGSIZE:
            subcode = 0  # section 11: the fork answers a size error with subcode 0
        return self._reply(-1, -1, msg_type, Result.INVALID, subcode)

    def _reply(self, group: int, sequence: int, command: int, result: int, subcode: int = 0) -> bytes:
        return sm.reply_frame(sm.MotionReply(group, sequence, command, int(result), int(subcode), ()),
                              self.dialect)

    def _send(self, conn: _Connection, frame: bytes) -> None:
        try:
            conn.sock.sendall(frame)
        except OSError:
            conn.close()

    def _handle(self, conn: _Connection, message: sm.Message) -> tuple[bytes | None, bool]:
        """(reply, keep the connection) for one decoded message, holding the lock."""
        body = message.body
        if conn.kind == "io" and message.msg_type not in _IO_TYPES:
            return self._reply(-1, -1, message.msg_type, Result.INVALID, Subcode.INVALID_MSGTYPE), True
        accepted = {sm.MsgType.JOINT_TRAJ_PT_FULL, sm.MsgType.MOTO_MOTION_CTRL}
        if message.msg_type in _UNKNOWN_TYPES or (self.dialect.name == "clopema" and message.msg_type
                                                  not in accepted):
            return self._reply(-1, -1, message.msg_type, Result.INVALID, Subcode.INVALID_MSGTYPE), True
        if isinstance(body, sm.Ping):
            return sm.reply_frame(sm.Ping(), self.dialect), True
        if isinstance(body, sm.MotionCtrl):
            return self._motion_ctrl(conn, body)
        if isinstance(body, sm.JointTrajPtFull):
            return self._point(conn, body), True
        if isinstance(body, sm.JointTrajPtFullEx):
            return self._point_ex(conn, body), True
        if isinstance(body, sm.SelectTool):
            return self._select_tool(body), True
        if isinstance(body, sm.DhParameters):
            zeros = (0.0,) * (4 * sm.DH_LINKS * sm.MAX_GROUPS)
            return sm.reply_frame(sm.DhParameters(zeros), self.dialect), True
        if isinstance(body, sm.IoAddress):
            return sm.reply_frame(self._io_read(body), self.dialect), True
        if isinstance(body, sm.IoWrite):
            result = self._io_write(conn, body)
            return sm.reply_frame(sm.IoWriteReply(body.msg_type + 1, result), self.dialect), True
        return self._reply(-1, -1, message.msg_type, Result.INVALID, Subcode.INVALID_MSGTYPE), True

    # ------------------------------------------------------------------ IO
    def _io_read(self, body: sm.IoAddress) -> sm.IoReadReply:
        if body.msg_type == sm.MsgType.MOTO_READ_IO_BIT and body.address in self.grippers:
            closed = self.core.grippers[self.grippers[body.address]]
            return sm.IoReadReply(body.msg_type + 1, int(closed), sm.IoResult.OK)
        value = self.io.get((body.msg_type, body.address), 0)
        return sm.IoReadReply(body.msg_type + 1, value, sm.IoResult.OK)

    def _io_write(self, conn: _Connection, body: sm.IoWrite) -> int:
        """A gripper's output bit closes (1) or opens (0) it; other addresses are kept for reading back."""
        if body.msg_type == sm.MsgType.MOTO_WRITE_IO_BIT and body.address in self.grippers:
            if body.value not in (0, 1):
                return sm.IoResult.WRITE_VALUE_INVALID
            grip = Command.GRIP_CLOSE if body.value else Command.GRIP_OPEN
            arm = self.grippers[body.address]
            done = self._claim(conn.session) and self.core.command(grip, conn.session, arm).ok
            return sm.IoResult.OK if done else sm.IoResult.WRITE_API_ERROR
        self.io[(body.msg_type - 2, body.address)] = body.value  # where the matching read looks
        return sm.IoResult.OK

    # ------------------------------------------------------------------ MOTO_MOTION_CTRL (section 6)
    def _motion_ctrl(self, conn: _Connection, body: sm.MotionCtrl) -> tuple[bytes | None, bool]:
        group, sequence, command = body.group, body.sequence, body.command
        session = conn.session

        def reply(result: int, subcode: int = 0) -> bytes:
            return self._reply(group, sequence, command, result, subcode)

        fork = self.dialect.name == "clopema"
        if command == Command.CHECK_MOTION_READY:
            sub = self._not_ready(session)
            if sub is None:
                return reply(Result.SUCCESS), True
            return reply(Result.FAILURE, 0 if fork else sub), True  # FALSE; the fork gives no subcode
        if command == Command.CHECK_QUEUE_CNT:
            if not 0 <= group < len(self.groups):
                return reply(Result.FAILURE, -1), True
            return reply(Result.SUCCESS, len(self.groups[group].increments)), True
        if command == Command.STOP_MOTION:
            self._stop_streaming()
            self.core.stop_motion()
            return reply(Result.SUCCESS), True
        if command == Command.START_TRAJ_MODE:
            result, sub = self._start_traj_mode(session)
            return reply(result, sub), True
        if command in (Command.STOP_TRAJ_MODE, Command.DISCONNECT):
            done = not self._queued() and (self.core.traj_mode is False or
                                           self._core_command(Command.STOP_TRAJ_MODE, session))
            answer = reply(Result.SUCCESS if done else Result.FAILURE)
            if command == Command.STOP_TRAJ_MODE:
                return answer, True
            return (answer if fork else None), False  # upstream closes without a reply
        if not fork and command == Command.START_SERVOS:
            ok = self._core_command(Command.START_SERVOS, session)
            if ok:
                self._estops_cleared = self.core.estop_count
            return reply(Result.SUCCESS if ok else Result.FAILURE), True
        if not fork and command == Command.STOP_SERVOS:
            self._stop_streaming()
            ok = self._core_command(Command.STOP_SERVOS, session)
            return reply(Result.SUCCESS if ok else Result.FAILURE), True
        if not fork and command == Command.RESET_ALARM:
            ok = self._core_command(Command.RESET_ALARM, session)
            return reply(Result.SUCCESS if ok else Result.FAILURE), True
        return reply(Result.INVALID, Subcode.INVALID_COMMAND), True

    def _start_traj_mode(self, session: str) -> tuple[int, int]:
        """Section 8: SUCCESS at once if ready; refused on e-stop, HOLD, TEACH or not REMOTE; otherwise
        reset the alarms, servos on, clear the queues."""
        core = self.core
        if self._not_ready(session) is None:
            return Result.SUCCESS, 0
        refusals = ((not self._may_command(session), Subcode.NOT_READY_UNSPECIFIED),
                    (core.e_stopped, Subcode.NOT_READY_ESTOP),
                    (core.held, Subcode.NOT_READY_HOLD),
                    (core.mode != Mode.AUTO, Subcode.NOT_READY_NOT_PLAY),
                    (not core.remote, Subcode.NOT_READY_NOT_REMOTE),
                    # after an e-stop only an explicit START_SERVOS switches the servos on (module doc)
                    (self._after_estop(), Subcode.NOT_READY_SERVO_OFF))
        for refused, sub in refusals:
            if refused:
                return Result.NOT_READY, int(sub)
        if not self._claim(session):
            return Result.NOT_READY, int(Subcode.NOT_READY_UNSPECIFIED)
        core.command(Command.RESET_ALARM, session)
        started = core.command(Command.START_TRAJ_MODE, session)
        if not started.ok:
            return Result.NOT_READY, started.subcode
        self._stop_streaming()
        return Result.SUCCESS, 0

    # ------------------------------------------------------------------ points (sections 6, 7)
    def _point(self, conn: _Connection, body: sm.JointTrajPtFull) -> bytes:
        command = sm.MsgType.JOINT_TRAJ_PT_FULL

        def reply(result: int, subcode: int = 0) -> bytes:
            return self._reply(body.group, body.sequence, command, result, subcode)

        sub = self._not_ready(conn.session)
        if sub is not None:
            return reply(Result.NOT_READY, sub)
        if self.dialect.name == "clopema":
            groups = self.groups  # the fork: one 13-slot point, split over the groups; robot_id ignored
        elif 0 <= body.group < len(self.groups):
            groups = [self.groups[body.group]]
        else:
            return reply(Result.INVALID, Subcode.INVALID_GROUPNO)
        if body.valid_fields & _FULL_VALID != _FULL_VALID:
            return reply(Result.INVALID, Subcode.INVALID_DATA_INSUFFICIENT)
        if body.time >= self.config.max_point_time:
            return reply(Result.INVALID, Subcode.INVALID_DATA_TIME)
        # upstream: the group's axes from slot 0; the fork: the groups' axes one after another
        offsets = np.cumsum([0] + [len(g.columns) for g in groups])
        points = [(g, body.positions[offsets[k]:offsets[k + 1]], body.velocities[offsets[k]:offsets[k + 1]])
                  for k, g in enumerate(groups)]
        result, sub = self._add_point(conn, points, body.sequence, body.time)
        return reply(result, sub)

    def _point_ex(self, conn: _Connection, body: sm.JointTrajPtFullEx) -> bytes:
        """Section 6, 2016: pre-check every group (bad group, busy, missing fields: nothing is taken),
        then add them in order; a failure at one keeps those before it. The reply names the last group
        handled. No 14400 s check."""
        command = sm.MsgType.MOTO_JOINT_TRAJ_PT_FULL_EX
        first = body.points[0].group
        sub = self._not_ready(conn.session)
        if sub is not None:
            return self._reply(first, body.sequence, command, Result.NOT_READY, sub)
        for block in body.points:
            if not 0 <= block.group < len(self.groups):
                return self._reply(block.group, body.sequence, command, Result.INVALID,
                                   Subcode.INVALID_GROUPNO)
            if body.sequence > 0 and (self.groups[block.group].pending is not None or self.core.queue_count):
                return self._reply(block.group, body.sequence, command, Result.BUSY)
            if block.valid_fields & _FULL_VALID != _FULL_VALID:
                return self._reply(block.group, body.sequence, command, Result.INVALID,
                                   Subcode.INVALID_DATA_INSUFFICIENT)
        result: int = Result.SUCCESS
        sub = 0
        for block in body.points:
            group = self.groups[block.group]
            result, sub = self._add_point(conn, [(group, block.positions[:len(group.columns)],
                                                          block.velocities[:len(group.columns)])],
                                          body.sequence, block.time)
            if result != Result.SUCCESS:
                return self._reply(block.group, body.sequence, command, result, sub)
        return self._reply(body.points[-1].group, body.sequence, command, result, sub)

    def _add_point(self, conn: _Connection, points: list[tuple[_Group, sm.Floats, sm.Floats]], sequence: int,
                   time_s: float) -> tuple[int, int]:
        """One point for the `points`' groups together: the start point, or the next segment of each."""
        time_ms = int(time_s * 1000.0)  # section 7: time is truncated to whole ms
        arrays = [(g, np.array(p, dtype=float), np.array(v, dtype=float)) for g, p, v in points]
        if sequence < 0:
            return Result.INVALID, Subcode.INVALID_SEQUENCE
        if sequence > 0 and (any(g.pending is not None for g, _, _ in arrays) or self.core.queue_count):
            return Result.BUSY, 0
        for group, _, velocities in arrays:
            if (np.abs(velocities) > group.max_velocity).any():
                return Result.INVALID, Subcode.INVALID_DATA_SPEED
        if sequence == 0:
            for group, positions, _ in arrays:
                commanded = self.core.q[group.columns]
                if (np.abs(positions - commanded) > self.start_tolerance).any():
                    return Result.INVALID, Subcode.INVALID_DATA_START_POS
        elif any(g.last is None for g, _, _ in arrays):
            return Result.INVALID, Subcode.INVALID_SEQUENCE  # no start point yet (module doc)
        if not self._claim(conn.session):
            return Result.NOT_READY, Subcode.NOT_READY_UNSPECIFIED
        self._owner = conn
        for group, positions, velocities in arrays:
            point = _Point(time_ms, positions, velocities)
            previous = group.last
            group.last = point  # the start point only resets the interpolation start; queues nothing
            if sequence > 0 and previous is not None and time_ms > previous.time_ms:  # T <= 0: skipped
                group.pending = _Segment(previous, point, previous.time_ms + self.period_ms)
                group.fill(self.config.queue_increments, self.period_ms)
        return Result.SUCCESS, 0

    def _select_tool(self, body: sm.SelectTool) -> bytes:
        command = sm.MsgType.MOTO_SELECT_TOOL
        if not (0 <= body.group < len(self.groups) and self.groups[body.group].is_robot):
            return self._reply(body.group, body.sequence, command, Result.INVALID, Subcode.INVALID_GROUPNO)
        if not 0 <= body.tool < self.config.tool_count:
            return self._reply(body.group, body.sequence, command, Result.INVALID,
                               Subcode.INVALID_DATA_TOOLNO)
        return self._reply(body.group, body.sequence, command, Result.SUCCESS)

    def _motion_closed(self, conn: _Connection) -> None:
        """A motion (or IO) client went: its increments are dropped and the robot stops; the lease is
        free once the host has no motion or IO connection left."""
        conn.close()
        with self.lock:
            if conn in self._connections[conn.kind]:
                self._connections[conn.kind].remove(conn)
            if self._owner is conn:
                if self._queued():
                    log.warning("MotoROS motion client %s disconnected during motion: stopping", conn.name)
                self._stop_streaming()
                self._owner = None
            others = [c for kind in ("motion", "io") for c in self._connections.get(kind, [])
                      if c.session == conn.session]
            if not others:
                self.core.lease_lost(conn.session, why=f"its MotoROS connections from {conn.name} closed")
        log.info("MotoROS connection %s closed", conn.name)

    # ------------------------------------------------------------------ state port (section 9)
    def _serve_state(self, conn: _Connection) -> None:
        try:
            while not conn.closed.is_set() and not self._closing.is_set():
                with self.lock:
                    frames = self.state_frames()
                conn.sock.sendall(frames)
                conn.closed.wait(self.config.state_period)
        except OSError:
            pass  # the client went; input on the state port is never read
        finally:
            conn.close()
            with self.lock:
                if conn in self._connections["state"]:
                    self._connections["state"].remove(conn)
            log.info("MotoROS connection %s closed", conn.name)

    def state_frames(self) -> bytes:
        """One state burst (holding the lock)."""
        core = self.core
        valid = _FEEDBACK_VALID[self.dialect.name]
        speed = valid & sm.ValidFields.VELOCITY
        if self.dialect.name == "clopema":
            columns = np.concatenate([g.columns for g in self.groups])
            velocities = core.v[columns] if speed else np.zeros(len(columns))
            aggregated = sm.JointFeedback(0, valid, 0.0, tuple(core.q[columns]), tuple(velocities), ())
            out = [sm.topic_frame(aggregated, self.dialect)]
        else:
            blocks = [sm.JointFeedback(g.index, valid, 0.0, tuple(core.q[g.columns]),
                                       tuple(core.v[g.columns]), ()) for g in self.groups]
            out = [sm.topic_frame(block, self.dialect) for block in blocks]
            if len(blocks) >= 2:
                out.append(sm.topic_frame(sm.JointFeedbackEx(tuple(blocks)), self.dialect))
        out.append(sm.topic_frame(self.robot_status(), self.dialect))
        return b"".join(out)

    def robot_status(self) -> sm.RobotStatus:
        """Section 9; the emulator's command and feedback never differ, so in_motion is the queues (and
        the Zenoh side's motion, which `core.status()` shows with these queues: one status both sides)."""
        core = self.core
        moving = self._queued() or core.in_motion
        if self.dialect.name == "clopema":
            moving = self._queued()  # the fork: queue only
        return sm.RobotStatus(drives_powered=int(core.servo_on), e_stopped=int(core.e_stopped),
                              error_code=int(core.alarm_code), in_error=int(core.alarm_code != 0),
                              in_motion=int(moving), mode=2 if core.mode == Mode.AUTO else 1,
                              motion_possible=int(self._not_ready(self._status_session()) is None))

    def _status_session(self) -> str:
        """Whom ROBOT_STATUS speaks to: the MotoROS client holding the lease, else a newcomer."""
        holder = self.core.lease_holder
        return holder if holder.startswith(_SESSION_PREFIXES) else ""


def _session(host: str, role: str) -> str:
    """The lease's session id of a MotoROS client at `host`, authenticated as `role` over TLS."""
    return f"motoros:{role}@{host}" if role else f"motoros@{host}"


def _common_name(certificate: dict[str, Any] | None) -> str:
    """The subject's common name of a certificate as `SSLSocket.getpeercert()` gives it."""
    for attribute in (certificate or {}).get("subject", ()):
        for key, value in attribute:
            if key == "commonName":
                return str(value)
    return ""


def _listener(host: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen()
    except OSError:
        sock.close()
        raise
    return sock
