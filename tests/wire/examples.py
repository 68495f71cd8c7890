"""Random, valid example messages of every registry type (for round-trip tests and benchmarks)."""

from __future__ import annotations

import numpy as np
from rosbags.typesys.base import Nodetype

from drivers.wire import messages
from drivers.wire.registry import KEYS

_INT_RANGES = {"int8": (-128, 127), "uint8": (0, 255), "byte": (0, 255), "char": (0, 255),
               "int16": (-2**15, 2**15 - 1), "uint16": (0, 2**16 - 1), "int32": (-2**31, 2**31 - 1),
               "uint32": (0, 2**32 - 1), "int64": (-2**63, 2**63 - 1), "uint64": (0, 2**64 - 1)}


def concrete_key(pattern: str) -> str:
    return pattern.replace("*", "r1")


def _value(base: str, rng: np.random.Generator):
    if base == "string":
        return "".join(rng.choice(list("abcxyz-_09 é"), size=int(rng.integers(0, 12))))
    if base == "bool":
        return bool(rng.integers(0, 2))
    if base.startswith("float"):
        return float(np.float32(rng.normal(0, 10)))
    lo, hi = _INT_RANGES[base]
    return int(rng.integers(lo, hi, dtype=np.int64 if hi < 2**63 else np.uint64, endpoint=True))


def random_message(type_name: str, rng: np.random.Generator, depth: int = 0):
    store = messages.typestore()
    _, defs = store.fielddefs[type_name]
    fields = {}
    for name, (kind, detail) in defs:
        if kind == Nodetype.BASE:
            fields[name] = _value(detail[0], rng)
        elif kind == Nodetype.NAME:
            fields[name] = random_message(detail, rng, depth + 1)
        else:
            sub, count = detail
            n = count if kind == Nodetype.ARRAY else int(rng.integers(0, 4 if depth < 2 else 2))
            if sub[0] == Nodetype.NAME:
                fields[name] = [random_message(sub[1], rng, depth + 1) for _ in range(n)]
            else:
                fields[name] = [_value(sub[1][0], rng) for _ in range(n)]
    msg = messages.new(type_name, **fields)
    return _make_valid(type_name, msg, rng)


def _make_valid(type_name: str, msg, rng):
    if type_name == "builtin_interfaces/msg/Time":
        msg.nanosec = int(msg.nanosec % 1_000_000_000)
        msg.sec = int(abs(msg.sec))
    elif type_name == "builtin_interfaces/msg/Duration":
        msg.nanosec = int(msg.nanosec % 1_000_000_000)
    elif type_name == "sensor_msgs/msg/JointState":
        n = len(msg.name)
        msg.name = [f"j{i}" for i in range(n)]
        msg.position = rng.normal(size=n)
        msg.velocity = rng.normal(size=n)
        msg.effort = np.zeros(0)
    elif type_name == "trajectory_msgs/msg/JointTrajectory":
        n = len(msg.joint_names)
        msg.joint_names = [f"j{i}" for i in range(n)]
        for p in msg.points:
            p.positions = rng.normal(size=n)
            p.velocities = rng.normal(size=n)
            p.accelerations = np.zeros(0)
            p.effort = np.zeros(0)
    elif type_name == "geometry_msgs/msg/Quaternion":
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        msg.x, msg.y, msg.z, msg.w = (float(v) for v in q)
    elif type_name == "foldcell_msgs/msg/GripperState":
        msg.arm = "r2"
    elif type_name in ("foldcell_msgs/msg/ControllerStatus", "foldcell_msgs/msg/GroupStatus"):
        for field in ("drives_powered", "e_stopped", "in_error", "in_motion", "motion_possible", "held",
                      "trajectory_mode", "link_ok"):
            if hasattr(msg, field):
                setattr(msg, field, int(rng.integers(-1, 2)))
    elif type_name == "sensor_msgs/msg/CompressedImage":
        msg.format = "png"
        msg.data = rng.integers(0, 256, size=64, dtype=np.uint8)
    elif type_name == "sensor_msgs/msg/CameraInfo":
        msg.width, msg.height = 1280, 1024
    elif type_name in ("foldcell_msgs/msg/CellState",):
        msg.state = "idle"
    elif type_name == "foldcell_msgs/msg/CellCommand":
        msg.command = "status"
    elif type_name == "foldcell_msgs/msg/GarmentObservation":
        msg.polygon_table = list(msg.polygon_px)
    return msg


def registry_types() -> list[str]:
    out = []
    for spec in KEYS:
        for t in (spec.type_name, spec.reply_type):
            if t and t not in out:
                out.append(t)
    return out
