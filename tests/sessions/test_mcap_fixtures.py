"""Shared helpers for the mcaplog tests (no tests here): standard ROS 2 messages made with rosbags."""

from __future__ import annotations

from functools import cache, lru_cache
from pathlib import Path

import numpy as np
from rosbags.typesys import Stores, get_typestore

from drivers.sessions.mcap import SessionWriter

JOINT_STATE = "sensor_msgs/msg/JointState"
LOG = "rcl_interfaces/msg/Log"
JOINTS_TOPIC = "/foldcell/cell1/controller/joint_states"
LOG_TOPIC = "/foldcell/cell1/cell/log"
T0 = 1_700_000_000_000_000_000  # ns, a fixed epoch so expected values are exact


@lru_cache(maxsize=1)
def typestore():
    return get_typestore(Stores.ROS2_JAZZY)


@cache
def msgdef(type_name: str) -> str:
    text, _ = typestore().generate_msgdef(type_name, ros_version=2)
    return text


def joint_state(i: int) -> bytes:
    ts = typestore()
    T = ts.types["builtin_interfaces/msg/Time"]
    H = ts.types["std_msgs/msg/Header"]
    JS = ts.types[JOINT_STATE]
    names = [f"r1_joint_{c}" for c in "slurbt"]
    msg = JS(header=H(stamp=T(sec=i // 100, nanosec=(i % 100) * 10_000_000), frame_id="world"),
             name=names, position=np.arange(6, dtype=np.float64) * 0.01 + i,
             velocity=np.full(6, 0.5 * i), effort=np.zeros(0, dtype=np.float64))
    return bytes(ts.serialize_cdr(msg, JOINT_STATE))


def log_msg(i: int) -> bytes:
    ts = typestore()
    T = ts.types["builtin_interfaces/msg/Time"]
    L = ts.types[LOG]
    msg = L(stamp=T(sec=i, nanosec=7), level=20, name="foldcell.cell", msg=f"step {i} " + "x" * (i % 13),
            file="cell/run.py", function="step", line=i)
    return bytes(ts.serialize_cdr(msg, LOG))


def write_session(path: Path, n: int, *, log_every: int = 10, **kwargs) -> list[tuple[str, int, bytes]]:
    """Write n joint states (100 Hz) and a log every `log_every`; return (topic, log_time, data) written."""
    written: list[tuple[str, int, bytes]] = []
    with SessionWriter(path, **kwargs) as w:
        for i in range(n):
            t = T0 + i * 10_000_000
            data = joint_state(i)
            w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), data, t, t - 1000)
            written.append((JOINTS_TOPIC, t, data))
            if i % log_every == 0:
                data = log_msg(i)
                w.write(LOG_TOPIC, LOG, msgdef(LOG), data, t + 1, t - 2000)
                written.append((LOG_TOPIC, t + 1, data))
    return written
