"""ROS 2 message types on the wire: the type store, CDR encode/decode, validation.

Every payload is a ROS 2 message in CDR. `rosbags` provides the ROS 2 Jazzy types, CDR and the
ros2msg definitions; the project's own types (`foldcell_msgs`) and `foxglove_msgs` (not in the
Jazzy store) are `.msg` files beside this module. Decoding validates and raises `WireError`
naming the key expression and the problem.
"""

from __future__ import annotations

import math
import struct
import time
from functools import cache, lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype

MSG_ROOT = Path(__file__).with_name("msgs")
CDR_HEADER_LE = b"\x00\x01\x00\x00"


class WireError(ValueError):
    """A payload on `key` could not be used; `problem` says why."""

    def __init__(self, key: str, problem: str):
        self.key = key
        self.problem = problem
        super().__init__(f"{key}: {problem}")


class NobodyServes(WireError):
    """A query found no queryable on its key (the serving process is not running or not connected)."""


class NoReply(WireError):
    """A queryable was there but gave no reply within the timeout."""


class ErrorReply(WireError):
    """The queryable answered with an error; `remote` is its text (what it refused and why)."""

    def __init__(self, key: str, remote: str):
        self.remote = remote
        super().__init__(key, f"error reply: {remote}")


@lru_cache(maxsize=1)
def typestore() -> Any:
    """ROS 2 Jazzy types plus foxglove_msgs and foldcell_msgs from the `.msg` files here."""
    store = get_typestore(Stores.ROS2_JAZZY)
    types: dict = {}
    for msg_file in sorted(MSG_ROOT.glob("*/msg/*.msg")):
        package = msg_file.parent.parent.name
        types.update(get_types_from_msg(msg_file.read_text(), f"{package}/msg/{msg_file.stem}"))
    store.register(types)
    return store


@cache
def msgdef(type_name: str) -> str:
    """The full ros2msg definition (dependencies appended) as rosbag2 and Foxglove expect it."""
    return typestore().generate_msgdef(type_name, ros_version=2)[0]


def full_type(type_name: str) -> str:
    """`pkg/Type` or `pkg/msg/Type` -> `pkg/msg/Type`."""
    if "/msg/" in type_name:
        return type_name
    pkg, _, name = type_name.partition("/")
    return f"{pkg}/msg/{name}"


_NUMPY_DTYPES = {
    "bool": np.bool_, "byte": np.uint8, "char": np.uint8, "int8": np.int8, "uint8": np.uint8,
    "int16": np.int16, "uint16": np.uint16, "int32": np.int32, "uint32": np.uint32,
    "int64": np.int64, "uint64": np.uint64, "float32": np.float32, "float64": np.float64,
}


def _default_base(base: str) -> Any:
    if base == "string":
        return ""
    if base == "bool":
        return False
    if base.startswith("float"):
        return 0.0
    return 0


def _default_field(desc: tuple) -> Any:
    kind, detail = desc
    if kind == Nodetype.BASE:
        return _default_base(detail[0])
    if kind == Nodetype.NAME:
        return new(detail)
    sub, count = detail
    if sub[0] == Nodetype.BASE and sub[1][0] in _NUMPY_DTYPES:
        return np.zeros(count if kind == Nodetype.ARRAY else 0, dtype=_NUMPY_DTYPES[sub[1][0]])
    if kind == Nodetype.ARRAY:
        return [_default_field(sub) for _ in range(count)]
    return []


def _coerce(desc: tuple, value: Any) -> Any:
    """Lists of numbers become the numpy arrays rosbags needs."""
    kind, detail = desc
    if kind in (Nodetype.SEQUENCE, Nodetype.ARRAY):
        sub = detail[0]
        if sub[0] == Nodetype.BASE and sub[1][0] in _NUMPY_DTYPES and not isinstance(value, np.ndarray):
            return np.asarray(value, dtype=_NUMPY_DTYPES[sub[1][0]])
    return value


def new(type_name: str, **fields: Any) -> Any:
    """A message of `type_name` with every field not given set to zero, empty or default."""
    store = typestore()
    type_name = full_type(type_name)
    try:
        cls = store.types[type_name]
        _, defs = store.fielddefs[type_name]
    except KeyError as exc:
        raise KeyError(f"unknown message type {type_name}") from exc
    if type_name == "geometry_msgs/msg/Quaternion":
        fields.setdefault("w", 1.0)  # the ROS 2 default is the identity rotation
    names = {name for name, _ in defs}
    unknown = set(fields) - names
    if unknown:
        raise TypeError(f"{type_name} has no field(s) {', '.join(sorted(unknown))}")
    values = {}
    for name, desc in defs:
        values[name] = _coerce(desc, fields[name]) if name in fields else _default_field(desc)
    return cls(**values)


def stamp_now() -> Any:
    return stamp_from_ns(time.time_ns())


def stamp_from_ns(ns: int) -> Any:
    sec, nanosec = divmod(int(ns), 1_000_000_000)
    return new("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a `builtin_interfaces/Time` or `Duration` (both are sec + nanosec)."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def duration_from_s(seconds: float) -> Any:
    """`builtin_interfaces/Duration` of `seconds`, rounded to the nanosecond."""
    sec, nanosec = divmod(round(seconds * 1e9), 1_000_000_000)
    return new("builtin_interfaces/msg/Duration", sec=sec, nanosec=nanosec)


def duration_to_s(duration: Any) -> float:
    return int(duration.sec) + int(duration.nanosec) * 1e-9


def header(stamp_ns: int | None = None, frame_id: str = "") -> Any:
    ns = time.time_ns() if stamp_ns is None else stamp_ns
    return new("std_msgs/msg/Header", stamp=stamp_from_ns(ns), frame_id=frame_id)


def message_stamp_ns(msg: Any) -> int | None:
    """The sender's stamp of a message, when its type carries one."""
    hdr = getattr(msg, "header", None)
    stamp = getattr(hdr, "stamp", None) if hdr is not None else getattr(msg, "stamp", None)
    if stamp is None or not hasattr(stamp, "nanosec"):
        return None
    return stamp_to_ns(stamp)


def encode(type_name: str, msg: Any, key: str = "") -> bytes:
    type_name = full_type(type_name)
    if getattr(msg, "__msgtype__", None) != type_name:
        got = getattr(msg, "__msgtype__", type(msg).__name__)
        raise WireError(key or type_name, f"expected a {type_name}, got {got}")
    try:
        return bytes(typestore().serialize_cdr(msg, type_name))
    except Exception as exc:  # rosbags raises several kinds for bad field values
        raise WireError(key or type_name, f"cannot encode {type_name}: {exc}") from exc


def decode(type_name: str, data: bytes | memoryview, key: str = "") -> Any:
    """CDR bytes -> message, validated (see `validate`)."""
    type_name = full_type(type_name)
    key = key or type_name
    raw = bytes(data)
    if len(raw) < 4:
        raise WireError(key, f"payload of {len(raw)} bytes is too short for CDR")
    if raw[:4] != CDR_HEADER_LE and raw[:4] != b"\x00\x00\x00\x00":
        raise WireError(key, f"not CDR: encapsulation header {raw[:4].hex()} (expected 00010000)")
    try:
        msg = typestore().deserialize_cdr(raw, type_name)
    except Exception as exc:
        raise WireError(key, f"cannot decode as {type_name}: {_first_line(exc)}") from exc
    # A payload of another type often decodes into garbage: its re-encoding then differs in length.
    try:
        again = len(typestore().serialize_cdr(msg, type_name))
    except Exception as exc:
        raise WireError(key, f"decoded {type_name} is not valid: {_first_line(exc)}") from exc
    if again != len(raw) and not (len(raw) > again and len(raw) - again < 4 and not any(raw[again:])):
        raise WireError(key, f"{len(raw)} bytes do not form one {type_name} ({again} bytes decoded)")
    validate(type_name, msg, key)
    return msg


_HEADER_STAMP = struct.Struct("<iI")     # a leading std_msgs/Header's stamp: sec, nanosec
HEADER_STAMP_END = 4 + _HEADER_STAMP.size  # where a leading header's stamp ends in its CDR


@cache
def has_leading_header(type_name: str) -> bool:
    """Whether the type's first field is a `std_msgs/Header` (its CDR starts with the stamp)."""
    fields = typestore().fielddefs[full_type(type_name)][1]
    return bool(fields) and fields[0][1] == (Nodetype.NAME, "std_msgs/msg/Header")


def leading_stamp_ns(payload: bytes) -> int | None:
    """The stamp (ns) of a little-endian CDR message's leading header; None when it has no valid one."""
    if payload[:4] != CDR_HEADER_LE or len(payload) < HEADER_STAMP_END:
        return None
    sec, nanosec = _HEADER_STAMP.unpack_from(payload, 4)
    return sec * 1_000_000_000 + nanosec if nanosec < 1_000_000_000 else None


def restamp(payload: bytes, stamp_ns: int) -> bytes:
    """A little-endian CDR message that starts with a `std_msgs/Header`, stamped `stamp_ns` instead:
    a stream whose content did not change is sent again without encoding it again."""
    if payload[:4] != CDR_HEADER_LE or len(payload) < 4 + _HEADER_STAMP.size:
        raise ValueError("restamp: not a little-endian CDR message with a leading header")
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    out = bytearray(payload)
    _HEADER_STAMP.pack_into(out, 4, sec, nanosec)
    return bytes(out)


def _first_line(exc: Exception) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


# Fields where NaN is meaningful (ROS uses NaN for "not measured").
NAN_ALLOWED = {("sensor_msgs/msg/JointState", "velocity"), ("sensor_msgs/msg/JointState", "effort")}


def validate(type_name: str, msg: Any, key: str = "") -> None:
    """Checks beyond CDR: finite floats, matching array lengths, sane stamps and tri-states."""
    key = key or type_name
    _check_finite(type_name, msg, key, type_name)
    checker = _SEMANTIC_CHECKS.get(type_name)
    if checker is not None:
        problem = checker(msg)
        if problem:
            raise WireError(key, problem)


def _check_finite(type_name: str, msg: Any, key: str, path: str) -> None:
    store = typestore()
    _, defs = store.fielddefs[type_name]
    if type_name == "builtin_interfaces/msg/Time" and not 0 <= msg.nanosec < 1_000_000_000:
        raise WireError(key, f"{path}.nanosec = {msg.nanosec} is not below 1e9")
    for name, (kind, detail) in defs:
        value = getattr(msg, name)
        where = f"{path.rsplit('/', 1)[-1] if '/' in path else path}.{name}"
        if kind == Nodetype.BASE:
            if detail[0].startswith("float") and not math.isfinite(value):
                raise WireError(key, f"{where} is {value}, must be finite")
        elif kind == Nodetype.NAME:
            _check_finite(detail, value, key, where)
        else:
            sub = detail[0]
            if sub[0] == Nodetype.BASE and sub[1][0].startswith("float"):
                bad = np.isinf(value) if (type_name, name) in NAN_ALLOWED else ~np.isfinite(value)
                if bad.any():
                    raise WireError(key, f"{where}[{int(np.argmax(bad))}] is {value[bad][0]}, must be finite")
            elif sub[0] == Nodetype.NAME:
                for i, item in enumerate(value):
                    _check_finite(sub[1], item, key, f"{where}[{i}]")


def _check_joint_state(msg: Any) -> str | None:
    n = len(msg.name)
    if len(msg.position) != n:
        return f"name has {n} entries but position has {len(msg.position)}"
    for field in ("velocity", "effort"):
        if len(getattr(msg, field)) not in (0, n):
            return f"name has {n} entries but {field} has {len(getattr(msg, field))} (must be 0 or {n})"
    if len(set(msg.name)) != n:
        return "name has duplicate joints"
    return None


def _check_trajectory(msg: Any) -> str | None:
    n = len(msg.joint_names)
    if len(set(msg.joint_names)) != n:
        return "joint_names has duplicates"
    for i, point in enumerate(msg.points):
        if len(point.positions) != n:
            return f"points[{i}].positions has {len(point.positions)} values for {n} joint_names"
        for field in ("velocities", "accelerations", "effort"):
            if len(getattr(point, field)) not in (0, n):
                return f"points[{i}].{field} has {len(getattr(point, field))} values (must be 0 or {n})"
        if not 0 <= point.time_from_start.nanosec < 1_000_000_000:
            return f"points[{i}].time_from_start.nanosec is not below 1e9"
    return None


def _check_tristates(*fields: str):
    def check(msg: Any) -> str | None:
        for field in fields:
            if getattr(msg, field) not in (-1, 0, 1):
                return f"{field} = {getattr(msg, field)}, must be -1, 0 or 1"
        return None
    return check


def _check_controller_status(msg: Any) -> str | None:
    problem = _check_tristates("drives_powered", "e_stopped", "in_error", "in_motion", "motion_possible",
                               "held", "trajectory_mode")(msg)
    if problem:
        return problem
    for i, group in enumerate(msg.groups):
        problem = _check_tristates("drives_powered", "in_motion", "motion_possible", "link_ok")(group)
        if problem:
            return f"groups[{i}].{problem}"
    return None


def _check_compressed_image(msg: Any) -> str | None:
    if not msg.format:
        return "format is empty"
    if len(msg.data) == 0:
        return "data is empty"
    return None


def _check_camera_info(msg: Any) -> str | None:
    if msg.width == 0 or msg.height == 0:
        return f"image size {msg.width}x{msg.height} must be positive"
    return None


def _check_gripper(msg: Any) -> str | None:
    q = msg.tcp_pose.orientation
    norm = math.hypot(q.x, q.y, q.z, q.w)   # no overflow for huge components (the fuzzer's find)
    if abs(norm - 1.0) > 1e-3:
        return f"tcp_pose.orientation has norm {norm:.4f}, must be a unit quaternion"
    if msg.arm not in ("r1", "r2"):
        return f"arm {msg.arm!r} must be r1 or r2"
    return None


def _check_nonempty(field: str):
    def check(msg: Any) -> str | None:
        return None if getattr(msg, field) else f"{field} is empty"
    return check


def _check_observation(msg: Any) -> str | None:
    if len(msg.polygon_px) != len(msg.polygon_table) and len(msg.polygon_table) != 0:
        return f"polygon_px has {len(msg.polygon_px)} points but polygon_table has {len(msg.polygon_table)}"
    return None


_SEMANTIC_CHECKS = {
    "sensor_msgs/msg/JointState": _check_joint_state,
    "trajectory_msgs/msg/JointTrajectory": _check_trajectory,
    "foldcell_msgs/msg/ControllerStatus": _check_controller_status,
    "sensor_msgs/msg/CompressedImage": _check_compressed_image,
    "sensor_msgs/msg/CameraInfo": _check_camera_info,
    "foldcell_msgs/msg/GripperState": _check_gripper,
    "foldcell_msgs/msg/CellCommand": _check_nonempty("command"),
    "foldcell_msgs/msg/CellState": _check_nonempty("state"),
    "foldcell_msgs/msg/GarmentObservation": _check_observation,
}


def to_dict(msg: Any) -> Any:
    """A message as plain Python data (dicts, lists, numbers, strings), for JSON and YAML."""
    if hasattr(msg, "__msgtype__"):
        return {name: to_dict(getattr(msg, name)) for name, _ in typestore().fielddefs[msg.__msgtype__][1]}
    if isinstance(msg, np.ndarray):
        return msg.tolist()
    if isinstance(msg, (list, tuple)):
        return [to_dict(v) for v in msg]
    if isinstance(msg, np.generic):
        return msg.item()
    return msg


def from_dict(type_name: str, data: Any, path: str = "") -> Any:
    """Plain data -> message of `type_name`; fields left out take their defaults. Errors name the field."""
    type_name = full_type(type_name)
    where = path or type_name
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ValueError(f"{where}: expected a mapping for {type_name}, got {type(data).__name__}")
    _, defs = typestore().fielddefs[type_name]
    known = dict(defs)
    unknown = set(data) - set(known)
    if unknown:
        at = f"{path}: " if path else ""
        raise ValueError(f"{at}{type_name} has no field {sorted(unknown)[0]!r} (fields: {', '.join(known)})")
    values = {}
    for name, value in data.items():
        kind, detail = known[name]
        field = f"{where}.{name}" if path else name
        try:
            if kind == Nodetype.NAME:
                values[name] = from_dict(detail, value, field)
            elif kind in (Nodetype.SEQUENCE, Nodetype.ARRAY):
                if not isinstance(value, (list, tuple)):
                    raise ValueError(f"{field}: expected a list, got {type(value).__name__}")
                sub = detail[0]
                if sub[0] == Nodetype.NAME:
                    values[name] = [from_dict(sub[1], v, f"{field}[{i}]") for i, v in enumerate(value)]
                elif sub[1][0] in _NUMPY_DTYPES:
                    values[name] = np.asarray(value, dtype=_NUMPY_DTYPES[sub[1][0]])
                else:
                    values[name] = [str(v) for v in value]
                if kind == Nodetype.ARRAY and len(value) != detail[1]:
                    raise ValueError(f"{field}: expected {detail[1]} values, got {len(value)}")
            else:
                base = detail[0]
                if base == "string":
                    if not isinstance(value, str):
                        raise ValueError(f"{field}: expected a string, got {value!r}")
                    values[name] = value
                elif base == "bool":
                    values[name] = bool(value)
                elif base.startswith("float"):
                    values[name] = float(value)
                else:
                    values[name] = int(value)
        except (TypeError, OverflowError) as exc:
            raise ValueError(f"{field}: {exc}") from exc
    return new(type_name, **values)
