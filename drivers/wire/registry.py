"""The one registry of key expressions and their ROS 2 types (design page, "The wire").

Keys are relative to `foldcell/<cell>/`. A `*` matches exactly one chunk, as in Zenoh.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

from drivers.wire.limits import Quantities, QueryRate, load_quantities, load_query_rates, max_cdr_size
from drivers.wire.messages import WireError

ROOT = "foldcell"


@dataclass(frozen=True)
class KeySpec:
    pattern: str
    kind: str                 # pub | queryable | liveliness
    type_name: str            # published type, or the request type of a queryable
    reply_type: str = ""      # reply type of a queryable
    drop_when_congested: bool = False  # streams drop old samples; commands and logs never do
    description: str = ""


KEYS: tuple[KeySpec, ...] = (
    KeySpec("controller/joint_states", "pub", "sensor_msgs/msg/JointState", drop_when_congested=True,
            description="all joints of all groups, fixed rate"),
    # The controller's loop publishes these; a late one is worthless (the next comes within 0.1 s),
    # so they drop when congested and a partition never blocks the loop.
    KeySpec("controller/status", "pub", "foldcell_msgs/msg/ControllerStatus", drop_when_congested=True,
            description="on change and at 10 Hz"),
    KeySpec("controller/trajectory", "queryable", "trajectory_msgs/msg/JointTrajectory",
            "foldcell_msgs/msg/MotionReply", description="submit a trajectory"),
    KeySpec("controller/command", "queryable", "foldcell_msgs/msg/ControllerCommand",
            "foldcell_msgs/msg/MotionReply",
            description="servo, e-stop, hold, stop, grippers, lease, faults"),
    # A gripper's change is an event the world and the log must not lose (a fold taken or released
    # elsewhere than it happened), so these never drop; the controller puts them from a thread of their
    # own, so a congested link never holds its loop.
    KeySpec("controller/gripper/*", "pub", "foldcell_msgs/msg/GripperState",
            description="per arm, on change, at 10 Hz while the arms move, at 1 Hz at rest"),
    KeySpec("controller/slave/joint_states", "pub", "sensor_msgs/msg/JointState", drop_when_congested=True,
            description="the slave DX100's own feedback, merged by the master"),
    KeySpec("controller/slave/status", "pub", "foldcell_msgs/msg/ControllerStatus", drop_when_congested=True,
            description="the slave DX100's own status"),
    KeySpec("controller/slave/trajectory", "queryable", "trajectory_msgs/msg/JointTrajectory",
            "foldcell_msgs/msg/MotionReply", description="the master forwards the slave's part here"),
    KeySpec("controller/slave/command", "queryable", "foldcell_msgs/msg/ControllerCommand",
            "foldcell_msgs/msg/MotionReply", description="master-to-slave commands"),
    KeySpec("camera/capture", "queryable", "std_msgs/msg/Empty", "sensor_msgs/msg/CompressedImage",
            description="a fresh image"),
    KeySpec("camera/image", "pub", "sensor_msgs/msg/CompressedImage", drop_when_congested=True),
    KeySpec("camera/info", "pub", "sensor_msgs/msg/CameraInfo"),
    # CameraInfo has no pose; the optical frame's pose in `world` rides beside it.
    KeySpec("camera/pose", "pub", "geometry_msgs/msg/PoseStamped",
            description="camera optical frame in world"),
    # The simulated world's ground truth, for scoring the demo; a real cell publishes nothing here.
    KeySpec("sim/truth", "pub", "foldcell_msgs/msg/SimTruth", description="simulation only"),
    KeySpec("cell/state", "pub", "foldcell_msgs/msg/CellState", description="on change and at 2 Hz"),
    KeySpec("cell/command", "queryable", "foldcell_msgs/msg/CellCommand", "foldcell_msgs/msg/CellReply"),
    KeySpec("cell/log", "pub", "rcl_interfaces/msg/Log"),
    # Per-fold outcome and timings, for the demo's summary, the monitor and replayed sessions.
    KeySpec("cell/fold_report", "pub", "foldcell_msgs/msg/FoldReport"),
    KeySpec("perception/observation", "pub", "foldcell_msgs/msg/GarmentObservation"),
    KeySpec("perception/annotations", "pub", "foxglove_msgs/msg/ImageAnnotations"),
    KeySpec("plan/trajectory", "pub", "trajectory_msgs/msg/JointTrajectory"),
    KeySpec("alive/*", "liveliness", "", description="one token per running process"),
)


_JOINT_ARRAYS = {"position": "joints", "velocity": "joints", "effort": "joints", "positions": "joints",
                 "velocities": "joints", "accelerations": "joints"}
# What bounds each sequence (and each free-text string; other strings are names) of the types on the
# wire: a quantity of drivers/wire/limits.py. `Type.field` names a field of a nested type.
BOUNDS: dict[str, dict[str, str]] = {
    "sensor_msgs/msg/JointState": {"name": "joints", **_JOINT_ARRAYS},
    "foldcell_msgs/msg/ControllerStatus": {"alarm_text": "reason", "groups": "groups",
                                           "joint_names": "joints", "faults": "faults"},
    "trajectory_msgs/msg/JointTrajectory": {"joint_names": "joints", "points": "trajectory_points",
                                            **_JOINT_ARRAYS},
    "foldcell_msgs/msg/ControllerCommand": {"values": "joints"},
    "foldcell_msgs/msg/MotionReply": {"text": "reason"},
    "foldcell_msgs/msg/GripperState": {},
    "std_msgs/msg/Empty": {},
    "sensor_msgs/msg/CompressedImage": {"data": "image_bytes"},
    "sensor_msgs/msg/CameraInfo": {"d": "distortion"},
    "geometry_msgs/msg/PoseStamped": {},
    "foldcell_msgs/msg/SimTruth": {"landmarks": "landmarks", "silhouette_table": "outline_points",
                                   "holding": "arms", "last_event": "reason",
                                   "landmark_vertex_names": "landmarks", "landmark_vertices": "landmarks",
                                   "flat_landmarks": "landmarks", "flat_outline_table": "outline_points"},
    "foldcell_msgs/msg/CellState": {"reason": "reason", "history": "transitions", "triggers": "triggers",
                                    "processes_lost": "processes"},
    "foldcell_msgs/msg/CellCommand": {},
    "foldcell_msgs/msg/CellReply": {"text": "reason"},
    "rcl_interfaces/msg/Log": {"msg": "text", "file": "text"},
    "foldcell_msgs/msg/FoldReport": {"outcome": "reason", "timings": "stage_timings"},
    "foldcell_msgs/msg/GarmentObservation": {"landmarks": "landmarks", "polygon_px": "outline_points",
                                             "polygon_table": "outline_points", "timings": "stage_timings"},
    "foxglove_msgs/msg/ImageAnnotations": {"circles": "landmarks", "ImageAnnotations.points": "point_sets",
                                           "texts": "landmarks", "PointsAnnotation.points": "outline_points",
                                           "outline_colors": "outline_points"},
}


@cache
def payload_limit(type_name: str) -> int:
    """The largest payload (bytes) of a message of `type_name` the cell accepts: its layout with every
    sequence and string at its bound (config/limits.yaml)."""
    if type_name not in BOUNDS:
        raise WireError(type_name, "no size bound: add the type to drivers/wire/registry.py BOUNDS")
    return max_cdr_size(type_name, BOUNDS[type_name], _quantities())


@cache
def _quantities() -> Quantities:
    return load_quantities()


@cache
def _query_rates() -> dict[str, QueryRate]:
    return load_query_rates([spec.pattern for spec in KEYS if spec.kind == "queryable"])


def query_rate(spec: KeySpec) -> QueryRate:
    """How many requests the queryable of `spec` answers (config/limits.yaml `query_rates`)."""
    if spec.kind != "queryable":
        raise WireError(spec.pattern, f"is a {spec.kind}, not a queryable")
    return _query_rates()[spec.pattern]


def check_size(key: str, type_name: str, size: int) -> None:
    """Refuse a payload of `size` bytes on `key` above the bound of `type_name`, before decoding it."""
    limit = payload_limit(type_name)
    if size > limit:
        raise WireError(key, f"payload of {size} bytes is over the limit of {limit} bytes for a {type_name}; "
                             "not decoded")


def _matches(pattern: str, key: str) -> bool:
    p_chunks, k_chunks = pattern.split("/"), key.split("/")
    return len(p_chunks) == len(k_chunks) and all(
        p in ("*", k) for p, k in zip(p_chunks, k_chunks, strict=True))


def spec_for(relative_key: str) -> KeySpec:
    """The registry entry of a key relative to `foldcell/<cell>/`."""
    for spec in KEYS:
        if _matches(spec.pattern, relative_key):
            return spec
    raise WireError(relative_key, "not a key of the foldcell registry")


def full_key(cell_id: str, relative_key: str) -> str:
    return f"{ROOT}/{cell_id}/{relative_key}"


def split_key(key: str) -> tuple[str, str]:
    """`foldcell/<cell>/<rel>` -> (cell, rel)."""
    parts = str(key).split("/", 2)
    if len(parts) < 3 or parts[0] != ROOT:
        raise WireError(str(key), f"not under {ROOT}/<cell>/")
    return parts[1], parts[2]


def type_for_full_key(key: str, *, reply: bool = False) -> str:
    """The type carried by a sample (or a reply) on a full key."""
    spec = spec_for(split_key(key)[1])
    if spec.kind == "liveliness":
        raise WireError(str(key), "liveliness keys carry no payload")
    return spec.reply_type if reply else spec.type_name
