"""MotoROS 1 "simple message" frames: pure encode and decode, and a stream framer (no sockets).

Layouts, sizes and codes: `shared/facts/motoros-simple-message.md`. A frame is an int32 `length` prefix
(the bytes after it), a 12-byte header (`msg_type`, `comm_type`, `reply_code`) and a body of 4-byte
fields (int32, uint32 for IO, IEEE float32), packed, in the controller's byte order.

Two dialects: upstream MotoROS 1 on a DX100 (little-endian, 10 joint slots per group) and CloPeMa's
dual-arm fork (13 joint slots, only the messages the fork knows).
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import IntEnum

PREFIX_SIZE = 4
HEADER_SIZE = 12
MIN_FRAME = PREFIX_SIZE + HEADER_SIZE
MAX_GROUPS = 4  # MOT_MAX_GR: groups in an _EX message
REP_JOINTS = 10  # JOINT_POSITION and JOINT_TRAJ_PT are REP messages with 10 joints in every dialect
DH_LINKS = 8  # MOTO_GET_DH_PARAMETERS: links per group, each (theta, d, a, alpha)


class MsgType(IntEnum):
    PING = 1
    JOINT_POSITION = 10
    JOINT_TRAJ_PT = 11
    ROBOT_STATUS = 13
    JOINT_TRAJ_PT_FULL = 14
    JOINT_FEEDBACK = 15
    MOTO_MOTION_CTRL = 2001
    MOTO_MOTION_REPLY = 2002
    MOTO_READ_IO_BIT = 2003
    MOTO_READ_IO_BIT_REPLY = 2004
    MOTO_WRITE_IO_BIT = 2005
    MOTO_WRITE_IO_BIT_REPLY = 2006
    MOTO_READ_IO_GROUP = 2007
    MOTO_READ_IO_GROUP_REPLY = 2008
    MOTO_WRITE_IO_GROUP = 2009
    MOTO_WRITE_IO_GROUP_REPLY = 2010
    MOTO_IOCTRL_REPLY = 2011
    MOTO_READ_MREGISTER = 2012
    MOTO_READ_MREGISTER_REPLY = 2013
    # 2014 and 2015 lie beyond the facts' table (2003-2013); MotoROS' SimpleMessage.h defines them as
    # the write of the M-register pair, which the grippers' I/O mapping needs
    MOTO_WRITE_MREGISTER = 2014
    MOTO_WRITE_MREGISTER_REPLY = 2015
    MOTO_JOINT_TRAJ_PT_FULL_EX = 2016
    MOTO_JOINT_FEEDBACK_EX = 2017
    MOTO_SELECT_TOOL = 2018
    MOTO_GET_DH_PARAMETERS = 2020


class CommType(IntEnum):
    INVALID = 0
    TOPIC = 1
    SERVICE_REQUEST = 2
    SERVICE_REPLY = 3


class ReplyCode(IntEnum):
    UNUSED = 0
    SUCCESS = 1
    FAILURE = 2


class IoResult(IntEnum):
    """IO reply result codes (not in the facts; MotoROS' SimpleMessage.h `IoResultCodes`)."""

    OK = 0
    READ_ADDRESS_INVALID = 1001
    WRITE_ADDRESS_INVALID = 1002
    WRITE_VALUE_INVALID = 1003
    READ_API_ERROR = 1004
    WRITE_API_ERROR = 1005


class ValidFields(IntEnum):
    TIME = 1
    POSITION = 2
    VELOCITY = 4
    ACCELERATION = 8


class MotorosError(ValueError):
    """A frame that cannot be decoded: the field, the reason, and the INVALID subcode MotoROS answers
    with (3001 MSGSIZE, 3003 MSGTYPE, 3004 GROUPNO)."""

    def __init__(self, field_name: str, reason: str, subcode: int):
        super().__init__(f"{field_name}: {reason}")
        self.field = field_name
        self.reason = reason
        self.subcode = subcode


_MSGSIZE, _MSGTYPE, _GROUPNO = 3001, 3003, 3004


@dataclass(frozen=True)
class Dialect:
    """What one MotoROS build speaks: joint slots per group, byte order, the message types it knows."""

    name: str
    joint_slots: int
    byte_order: str  # struct prefix: '<' little-endian (DX100, DX200, YRC1000), '>' big-endian (FS100)
    types: frozenset[int]


UPSTREAM = Dialect("upstream", 10, "<", frozenset(MsgType))
# the fork: ROS_MAX_JOINT = 13, one controller, no IO port, no _EX messages
CLOPEMA = Dialect("clopema", 13, "<", frozenset({
    MsgType.ROBOT_STATUS, MsgType.JOINT_TRAJ_PT_FULL, MsgType.JOINT_FEEDBACK, MsgType.MOTO_MOTION_CTRL,
    MsgType.MOTO_MOTION_REPLY}))
DIALECTS = {d.name: d for d in (UPSTREAM, CLOPEMA)}

Floats = tuple[float, ...]


# ---------------------------------------------------------------- bodies
@dataclass(frozen=True)
class Ping:
    """Header only; the reply is a PING with comm 3."""


@dataclass(frozen=True)
class JointPosition:
    """REP message 10 (unknown to MotoROS 1)."""

    sequence: int
    joints: Floats = (0.0,) * REP_JOINTS


@dataclass(frozen=True)
class JointTrajPt:
    """REP message 11 (unknown to MotoROS 1)."""

    sequence: int
    joints: Floats = (0.0,) * REP_JOINTS
    velocity: float = 0.0
    duration: float = 0.0


@dataclass(frozen=True)
class RobotStatus:
    """Tri-states -1/0/1; mode 1 TEACH, 2 PLAY."""

    drives_powered: int
    e_stopped: int
    error_code: int
    in_error: int
    in_motion: int
    mode: int
    motion_possible: int


@dataclass(frozen=True)
class JointTrajPtFull:
    """Message 14: one group's trajectory point. `time`: s since the trajectory start."""

    group: int
    sequence: int
    valid_fields: int
    time: float
    positions: Floats
    velocities: Floats
    accelerations: Floats


@dataclass(frozen=True)
class JointFeedback:
    """Message 15, and the 132-byte block of the _EX messages (the same layout)."""

    group: int
    valid_fields: int
    time: float
    positions: Floats
    velocities: Floats
    accelerations: Floats


@dataclass(frozen=True)
class MotionCtrl:
    group: int
    sequence: int
    command: int
    data: Floats


@dataclass(frozen=True)
class MotionReply:
    """`command` echoes the command code, or the msg_type of a point (14, 2016) or tool selection."""

    group: int
    sequence: int
    command: int
    result: int
    subcode: int
    data: Floats


@dataclass(frozen=True)
class JointTrajPtFullEx:
    """Message 2016: one point for n = 1..4 groups; only the n blocks are sent."""

    sequence: int
    points: tuple[JointFeedback, ...]


@dataclass(frozen=True)
class JointFeedbackEx:
    """Message 2017: n valid groups, always 4 blocks on the wire (unused ones zero)."""

    groups: tuple[JointFeedback, ...]


@dataclass(frozen=True)
class SelectTool:
    group: int
    tool: int
    sequence: int


@dataclass(frozen=True)
class IoAddress:
    """2003 READ_IO_BIT, 2007 READ_IO_GROUP (address), 2012 READ_MREGISTER (register number)."""

    msg_type: int
    address: int


@dataclass(frozen=True)
class IoWrite:
    """2005 WRITE_IO_BIT, 2009 WRITE_IO_GROUP, 2014 WRITE_MREGISTER: address (or register), value."""

    msg_type: int
    address: int
    value: int


@dataclass(frozen=True)
class IoReadReply:
    """2004, 2008, 2013: value and IO result code (0 OK, 1001.. errors)."""

    msg_type: int
    value: int
    result_code: int


@dataclass(frozen=True)
class IoWriteReply:
    """2006, 2010, 2015: IO result code."""

    msg_type: int
    result_code: int


@dataclass(frozen=True)
class IoCtrlReply:
    """2011: result and subcode of an IO request MotoROS refused."""

    result: int
    subcode: int


@dataclass(frozen=True)
class DhParameters:
    """2020: the request has no body; the reply has 4 groups x 8 links x (theta, d, a, alpha)."""

    values: Floats = ()


Body = (Ping | JointPosition | JointTrajPt | RobotStatus | JointTrajPtFull | JointFeedback | MotionCtrl
        | MotionReply | JointTrajPtFullEx | JointFeedbackEx | SelectTool | IoAddress | IoWrite | IoReadReply
        | IoWriteReply | IoCtrlReply | DhParameters)


@dataclass(frozen=True)
class Message:
    msg_type: int
    comm_type: int
    reply_code: int
    body: Body = field(default_factory=Ping)


IO_ADDRESS_TYPES = (MsgType.MOTO_READ_IO_BIT, MsgType.MOTO_READ_IO_GROUP, MsgType.MOTO_READ_MREGISTER)
IO_WRITE_TYPES = (MsgType.MOTO_WRITE_IO_BIT, MsgType.MOTO_WRITE_IO_GROUP, MsgType.MOTO_WRITE_MREGISTER)
IO_READ_REPLY_TYPES = (MsgType.MOTO_READ_IO_BIT_REPLY, MsgType.MOTO_READ_IO_GROUP_REPLY,
                       MsgType.MOTO_READ_MREGISTER_REPLY)
IO_WRITE_REPLY_TYPES = (MsgType.MOTO_WRITE_IO_BIT_REPLY, MsgType.MOTO_WRITE_IO_GROUP_REPLY,
                        MsgType.MOTO_WRITE_MREGISTER_REPLY)


# ---------------------------------------------------------------- sizes
def block_size(dialect: Dialect) -> int:
    """A group's block (JOINT_FEEDBACK body, _EX block): group, valid, time, pos/vel/acc slots."""
    return 12 + 12 * dialect.joint_slots


def body_size(msg_type: int, dialect: Dialect, comm_type: int = CommType.SERVICE_REQUEST,
              groups: int = 1) -> int:
    """Body bytes of a message type (`groups`: n of a 2016; `comm_type` tells a 2020 reply)."""
    slots = dialect.joint_slots
    sizes = {
        MsgType.PING: 0,
        MsgType.JOINT_POSITION: 4 + 4 * REP_JOINTS,
        MsgType.JOINT_TRAJ_PT: 12 + 4 * REP_JOINTS,
        MsgType.ROBOT_STATUS: 28,
        MsgType.JOINT_TRAJ_PT_FULL: 16 + 12 * slots,
        MsgType.JOINT_FEEDBACK: block_size(dialect),
        MsgType.MOTO_MOTION_CTRL: 12 + 4 * slots,
        MsgType.MOTO_MOTION_REPLY: 20 + 4 * slots,
        MsgType.MOTO_IOCTRL_REPLY: 8,
        MsgType.MOTO_JOINT_TRAJ_PT_FULL_EX: 8 + block_size(dialect) * groups,
        MsgType.MOTO_JOINT_FEEDBACK_EX: 4 + block_size(dialect) * MAX_GROUPS,
        MsgType.MOTO_SELECT_TOOL: 12,
        MsgType.MOTO_GET_DH_PARAMETERS: 16 * DH_LINKS * MAX_GROUPS if comm_type == CommType.SERVICE_REPLY
        else 0,
    }
    sizes.update(dict.fromkeys(IO_ADDRESS_TYPES + IO_WRITE_REPLY_TYPES, 4))
    sizes.update(dict.fromkeys(IO_WRITE_TYPES + IO_READ_REPLY_TYPES, 8))
    return sizes[MsgType(msg_type)]


def frame_size(msg_type: int, dialect: Dialect, comm_type: int = CommType.SERVICE_REQUEST,
               groups: int = 1) -> int:
    """Bytes on the wire, the length prefix included."""
    return MIN_FRAME + body_size(msg_type, dialect, comm_type, groups)


# ---------------------------------------------------------------- encode
def _type_of(body: Body) -> int:
    if isinstance(body, (IoAddress, IoWrite, IoReadReply, IoWriteReply)):
        return body.msg_type
    return _BODY_TYPES[type(body)]


_BODY_TYPES: dict[type, int] = {
    Ping: MsgType.PING, JointPosition: MsgType.JOINT_POSITION, JointTrajPt: MsgType.JOINT_TRAJ_PT,
    RobotStatus: MsgType.ROBOT_STATUS, JointTrajPtFull: MsgType.JOINT_TRAJ_PT_FULL,
    JointFeedback: MsgType.JOINT_FEEDBACK, MotionCtrl: MsgType.MOTO_MOTION_CTRL,
    MotionReply: MsgType.MOTO_MOTION_REPLY, JointTrajPtFullEx: MsgType.MOTO_JOINT_TRAJ_PT_FULL_EX,
    JointFeedbackEx: MsgType.MOTO_JOINT_FEEDBACK_EX, SelectTool: MsgType.MOTO_SELECT_TOOL,
    IoCtrlReply: MsgType.MOTO_IOCTRL_REPLY, DhParameters: MsgType.MOTO_GET_DH_PARAMETERS,
}


def _slots(values: Floats, count: int, name: str) -> Floats:
    """Pad to `count` slots with zeros (unused slots are 0); more values than slots is an error."""
    if len(values) > count:
        raise MotorosError(name, f"{len(values)} values, the dialect has {count} slots", _MSGSIZE)
    return tuple(float(v) for v in values) + (0.0,) * (count - len(values))


def _block(point: JointFeedback, dialect: Dialect) -> bytes:
    n = dialect.joint_slots
    return struct.pack(f"{dialect.byte_order}iif{3 * n}f", point.group, point.valid_fields, point.time,
                       *_slots(point.positions, n, "positions"), *_slots(point.velocities, n, "velocities"),
                       *_slots(point.accelerations, n, "accelerations"))


def encode_body(body: Body, dialect: Dialect) -> bytes:
    o, n = dialect.byte_order, dialect.joint_slots
    if isinstance(body, Ping):
        return b""
    if isinstance(body, JointPosition):
        return struct.pack(f"{o}i{REP_JOINTS}f", body.sequence, *_slots(body.joints, REP_JOINTS, "joints"))
    if isinstance(body, JointTrajPt):
        return struct.pack(f"{o}i{REP_JOINTS}fff", body.sequence, *_slots(body.joints, REP_JOINTS, "joints"),
                           body.velocity, body.duration)
    if isinstance(body, RobotStatus):
        return struct.pack(f"{o}7i", body.drives_powered, body.e_stopped, body.error_code, body.in_error,
                           body.in_motion, body.mode, body.motion_possible)
    if isinstance(body, JointTrajPtFull):
        return struct.pack(f"{o}iiif{3 * n}f", body.group, body.sequence, body.valid_fields, body.time,
                           *_slots(body.positions, n, "positions"), *_slots(body.velocities, n, "velocities"),
                           *_slots(body.accelerations, n, "accelerations"))
    if isinstance(body, JointFeedback):
        return _block(body, dialect)
    if isinstance(body, MotionCtrl):
        return struct.pack(f"{o}iii{n}f", body.group, body.sequence, body.command,
                           *_slots(body.data, n, "data"))
    if isinstance(body, MotionReply):
        return struct.pack(f"{o}iiiii{n}f", body.group, body.sequence, body.command, body.result,
                           body.subcode, *_slots(body.data, n, "data"))
    if isinstance(body, JointTrajPtFullEx):
        if not 1 <= len(body.points) <= MAX_GROUPS:
            raise MotorosError("numberOfValidGroups", f"{len(body.points)} groups, must be 1..{MAX_GROUPS}",
                               _GROUPNO)
        return struct.pack(f"{o}ii", len(body.points), body.sequence) + b"".join(
            _block(p, dialect) for p in body.points)
    if isinstance(body, JointFeedbackEx):
        if len(body.groups) > MAX_GROUPS:
            raise MotorosError("numberOfValidGroups", f"{len(body.groups)} groups, at most {MAX_GROUPS}",
                               _GROUPNO)
        unused = JointFeedback(0, 0, 0.0, (), (), ())
        blocks = list(body.groups) + [unused] * (MAX_GROUPS - len(body.groups))
        return struct.pack(f"{o}i", len(body.groups)) + b"".join(_block(b, dialect) for b in blocks)
    if isinstance(body, SelectTool):
        return struct.pack(f"{o}iii", body.group, body.tool, body.sequence)
    if isinstance(body, IoAddress):
        return struct.pack(f"{o}I", body.address)
    if isinstance(body, IoWrite):
        return struct.pack(f"{o}II", body.address, body.value)
    if isinstance(body, IoReadReply):
        return struct.pack(f"{o}Ii", body.value, body.result_code)
    if isinstance(body, IoWriteReply):
        return struct.pack(f"{o}i", body.result_code)
    if isinstance(body, IoCtrlReply):
        return struct.pack(f"{o}ii", body.result, body.subcode)
    if isinstance(body, DhParameters):
        if body.values and len(body.values) != 4 * DH_LINKS * MAX_GROUPS:
            raise MotorosError("dhParameters", f"{len(body.values)} values, must be 0 or "
                               f"{4 * DH_LINKS * MAX_GROUPS}", _MSGSIZE)
        return struct.pack(f"{o}{len(body.values)}f", *body.values)
    raise TypeError(f"not a simple-message body: {type(body).__name__}")


def encode(body: Body, dialect: Dialect = UPSTREAM, comm_type: int = CommType.SERVICE_REQUEST,
           reply_code: int = ReplyCode.UNUSED) -> bytes:
    """One whole frame: prefix, header, body."""
    msg_type = _type_of(body)
    if msg_type not in dialect.types:
        raise MotorosError("msg_type", f"{msg_type} is not a {dialect.name} message", _MSGTYPE)
    payload = encode_body(body, dialect)
    return struct.pack(f"{dialect.byte_order}iiii", HEADER_SIZE + len(payload), msg_type, comm_type,
                       reply_code) + payload


def reply_frame(body: Body, dialect: Dialect = UPSTREAM) -> bytes:
    """Every MotoROS reply has comm 3 and reply 1, even for errors (the body's result says)."""
    return encode(body, dialect, CommType.SERVICE_REPLY, ReplyCode.SUCCESS)


def topic_frame(body: Body, dialect: Dialect = UPSTREAM) -> bytes:
    """State messages: comm 1, reply 0."""
    return encode(body, dialect, CommType.TOPIC, ReplyCode.UNUSED)


# ---------------------------------------------------------------- decode
class _Reader:
    """Reads the 4-byte fields of a body in order; running out names the field."""

    def __init__(self, data: bytes, dialect: Dialect, msg_name: str):
        self.data, self.offset, self.order, self.msg_name = data, 0, dialect.byte_order, msg_name

    def take(self, fmt: str, count: int, name: str) -> tuple:
        size = 4 * count
        if self.offset + size > len(self.data):
            raise MotorosError(name, f"{self.msg_name} body ends at byte {len(self.data)}, the field needs "
                               f"bytes {self.offset}..{self.offset + size}", _MSGSIZE)
        out = struct.unpack_from(f"{self.order}{count}{fmt}", self.data, self.offset)
        self.offset += size
        return out

    def i32(self, name: str) -> int:
        return int(self.take("i", 1, name)[0])

    def u32(self, name: str) -> int:
        return int(self.take("I", 1, name)[0])

    def f32(self, name: str) -> float:
        return float(self.take("f", 1, name)[0])

    def f32s(self, count: int, name: str) -> Floats:
        return tuple(float(v) for v in self.take("f", count, name))


def _read_block(r: _Reader, slots: int, where: str = "") -> JointFeedback:
    return JointFeedback(r.i32(f"{where}group"), r.i32(f"{where}valid_fields"), r.f32(f"{where}time"),
                         r.f32s(slots, f"{where}pos"), r.f32s(slots, f"{where}vel"),
                         r.f32s(slots, f"{where}acc"))


def _group_count(r: _Reader, low: int) -> int:
    n = r.i32("numberOfValidGroups")
    if not low <= n <= MAX_GROUPS:
        raise MotorosError("numberOfValidGroups", f"{n}, must be {low}..{MAX_GROUPS}", _GROUPNO)
    return n


def _decode_body(msg_type: int, comm_type: int, r: _Reader, dialect: Dialect) -> Body:
    n = dialect.joint_slots
    readers: dict[int, Callable[[], Body]] = {
        MsgType.PING: Ping,
        MsgType.JOINT_POSITION: lambda: JointPosition(r.i32("sequence"), r.f32s(REP_JOINTS, "joints")),
        MsgType.JOINT_TRAJ_PT: lambda: JointTrajPt(r.i32("sequence"), r.f32s(REP_JOINTS, "joints"),
                                                   r.f32("velocity"), r.f32("duration")),
        MsgType.ROBOT_STATUS: lambda: RobotStatus(*(r.i32(f) for f in (
            "drives_powered", "e_stopped", "error_code", "in_error", "in_motion", "mode",
            "motion_possible"))),
        MsgType.JOINT_TRAJ_PT_FULL: lambda: JointTrajPtFull(
            r.i32("robot_id"), r.i32("sequence"), r.i32("valid_fields"), r.f32("time"), r.f32s(n, "pos"),
            r.f32s(n, "vel"), r.f32s(n, "acc")),
        MsgType.JOINT_FEEDBACK: lambda: _read_block(r, n),
        MsgType.MOTO_MOTION_CTRL: lambda: MotionCtrl(r.i32("group"), r.i32("sequence"), r.i32("command"),
                                                     r.f32s(n, "data")),
        MsgType.MOTO_MOTION_REPLY: lambda: MotionReply(r.i32("group"), r.i32("sequence"), r.i32("command"),
                                                       r.i32("result"), r.i32("subcode"),
                                                       r.f32s(n, "data")),
        MsgType.MOTO_SELECT_TOOL: lambda: SelectTool(r.i32("group"), r.i32("tool"), r.i32("sequence")),
        MsgType.MOTO_IOCTRL_REPLY: lambda: IoCtrlReply(r.i32("result"), r.i32("subcode")),
    }
    if msg_type in readers:
        return readers[msg_type]()
    if msg_type == MsgType.MOTO_JOINT_TRAJ_PT_FULL_EX:
        count = _group_count(r, 1)
        sequence = r.i32("sequence")
        return JointTrajPtFullEx(sequence, tuple(_read_block(r, n, f"block {k} ") for k in range(count)))
    if msg_type == MsgType.MOTO_JOINT_FEEDBACK_EX:
        count = _group_count(r, 0)
        blocks = tuple(_read_block(r, n, f"block {k} ") for k in range(MAX_GROUPS))
        return JointFeedbackEx(blocks[:count])
    if msg_type == MsgType.MOTO_GET_DH_PARAMETERS:
        count = 4 * DH_LINKS * MAX_GROUPS if comm_type == CommType.SERVICE_REPLY else 0
        return DhParameters(r.f32s(count, "dhParameters"))
    if msg_type in IO_ADDRESS_TYPES:
        return IoAddress(msg_type, r.u32("ioAddress"))
    if msg_type in IO_WRITE_TYPES:
        return IoWrite(msg_type, r.u32("ioAddress"), r.u32("ioValue"))
    if msg_type in IO_READ_REPLY_TYPES:
        return IoReadReply(msg_type, r.u32("value"), r.i32("resultCode"))
    return IoWriteReply(msg_type, r.i32("resultCode"))


def read_header(frame: bytes, dialect: Dialect = UPSTREAM) -> tuple[int, int, int, int]:
    """(length, msg_type, comm_type, reply_code) of a frame's first 16 bytes."""
    if len(frame) < MIN_FRAME:
        raise MotorosError("header", f"{len(frame)} bytes, a frame has at least {MIN_FRAME}", _MSGSIZE)
    length, msg_type, comm_type, reply_code = struct.unpack_from(f"{dialect.byte_order}iiii", frame)
    return length, msg_type, comm_type, reply_code


def expected_frame_size(frame: bytes, dialect: Dialect) -> int | None:
    """The size the frame's type (and, for 2016, its group count) gives; None while the group count is
    not in yet. Raises on an unknown type or a group count out of range."""
    _, msg_type, comm_type, _ = read_header(frame, dialect)
    if msg_type not in dialect.types:
        raise MotorosError("msg_type", f"{msg_type} is not a {dialect.name} message type", _MSGTYPE)
    groups = 1
    if msg_type == MsgType.MOTO_JOINT_TRAJ_PT_FULL_EX:
        if len(frame) < MIN_FRAME + 4:
            return None
        groups = _group_count(_Reader(frame[MIN_FRAME:], dialect, "MOTO_JOINT_TRAJ_PT_FULL_EX"), 1)
    return frame_size(msg_type, dialect, comm_type, groups)


def decode(frame: bytes, dialect: Dialect = UPSTREAM) -> Message:
    """One whole frame; the prefix must match the type's size and nothing may trail the body."""
    length, msg_type, comm_type, reply_code = read_header(frame, dialect)
    expected = expected_frame_size(frame, dialect)
    if expected is None:
        raise MotorosError("numberOfValidGroups", "missing: the frame ends after the header", _MSGSIZE)
    name = MsgType(msg_type).name
    if length != expected - PREFIX_SIZE:
        raise MotorosError("length", f"prefix says {length} bytes, a {name} has {expected - PREFIX_SIZE}",
                           _MSGSIZE)
    reader = _Reader(frame[MIN_FRAME:], dialect, name)
    body = _decode_body(msg_type, comm_type, reader, dialect)
    if len(frame) != expected:
        raise MotorosError("length", f"{len(frame)} bytes, a {name} frame has {expected}", _MSGSIZE)
    return Message(msg_type, comm_type, reply_code, body)


class Framer:
    """Splits a TCP byte stream into whole frames, across partial reads.

    Sizes come from the message type (as MotoROS infers them); the length prefix must agree. After a
    `MotorosError` the stream is out of step: the caller drops the buffer (`clear`).
    """

    def __init__(self, dialect: Dialect = UPSTREAM):
        self.dialect = dialect
        self._buffer = bytearray()

    def feed(self, data: bytes) -> None:
        self._buffer += data

    @property
    def pending(self) -> int:
        """Bytes held of a frame not complete yet."""
        return len(self._buffer)

    def clear(self) -> None:
        self._buffer.clear()

    def peek_type(self) -> int:
        """The msg_type of the buffered frame's header, 0 while the header is not in."""
        if len(self._buffer) < MIN_FRAME:
            return 0
        return read_header(bytes(self._buffer[:MIN_FRAME]), self.dialect)[1]

    def next_frame(self) -> bytes | None:
        """The next whole frame, or None until more bytes arrive."""
        buf = self._buffer
        if len(buf) < MIN_FRAME:
            return None
        expected = expected_frame_size(bytes(buf[:MIN_FRAME + 4]), self.dialect)
        if expected is None:
            return None
        length, msg_type = read_header(bytes(buf[:MIN_FRAME]), self.dialect)[:2]
        if length != expected - PREFIX_SIZE:
            name = MsgType(msg_type).name
            raise MotorosError("length", f"prefix says {length} bytes, a {name} has {expected - PREFIX_SIZE}",
                               _MSGSIZE)
        if len(buf) < expected:
            return None
        frame = bytes(buf[:expected])
        del buf[:expected]
        return frame

    def frames(self, data: bytes = b"") -> list[bytes]:
        """Feed `data`, then every whole frame now available."""
        self.feed(data)
        out = []
        while (frame := self.next_frame()) is not None:
            out.append(frame)
        return out
