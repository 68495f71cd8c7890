"""Every RIHS01 type hash the cell shows ROS 2 (`drivers/ros2/types.py`), against a reference
implementation of REP-2011's type-description hashing written here from the REP and rosidl's
`rosidl_generator_type_description` alone: it parses the `.msg`/`.srv` texts itself, builds the
type description (the type's fields, then every type it reaches, sorted by name; no comments, no
constants, no default values), and hashes the canonical JSON with sha256. It shares no code with
rosbags' hashing nor with zenoh-ros2-sdk (tests/ros2/test_names.py), and needs neither installed.

The reference is first checked against hashes ROS 2 itself publishes (`ros2 topic info -v`, rmw_zenoh's
design document), so a mistake in it cannot agree with a mistake in the code under test by chance."""

from __future__ import annotations

import hashlib
import json
import re
from functools import cache
from pathlib import Path

import pytest
import yaml

from drivers.ros2 import types
from drivers.wire.registry import KEYS
from tests.conftest import REPO

MSG_ROOT = REPO / "drivers/wire/msgs"

# type_description_interfaces/msg/FieldType
FIELD_TYPE_IDS = {
    "nested": 1, "int8": 2, "uint8": 3, "int16": 4, "uint16": 5, "int32": 6, "uint32": 7, "int64": 8,
    "uint64": 9, "float32": 10, "float64": 11, "char": 3,   # a .msg char is a uint8 in its IDL
    "bool": 15, "byte": 16, "string": 17, "wstring": 18, "bounded_string": 21, "bounded_wstring": 22,
}
ARRAY, BOUNDED_SEQUENCE, UNBOUNDED_SEQUENCE = 48, 96, 144   # added to the element's id

# Standard types the cell's types reach, as ROS 2 Jazzy's .msg files define them (comments and
# constants left out: neither is hashed).
STANDARD_MSGS = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec",
    "builtin_interfaces/msg/Duration": "int32 sec\nuint32 nanosec",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id",
    "std_msgs/msg/String": "string data",
    "std_msgs/msg/Empty": "",
    "geometry_msgs/msg/Point": "float64 x\nfloat64 y\nfloat64 z",
    "geometry_msgs/msg/Quaternion": "float64 x 0\nfloat64 y 0\nfloat64 z 0\nfloat64 w 1",
    "geometry_msgs/msg/Pose": "Point position\nQuaternion orientation",
    "geometry_msgs/msg/PoseStamped": "std_msgs/Header header\nPose pose",
    "sensor_msgs/msg/JointState": "std_msgs/Header header\nstring[] name\nfloat64[] position\n"
                                  "float64[] velocity\nfloat64[] effort",
    "sensor_msgs/msg/CompressedImage": "std_msgs/Header header\nstring format\nuint8[] data",
    "sensor_msgs/msg/RegionOfInterest": "uint32 x_offset\nuint32 y_offset\nuint32 height\nuint32 width\n"
                                        "bool do_rectify",
    "sensor_msgs/msg/CameraInfo": "std_msgs/Header header\nuint32 height\nuint32 width\n"
                                  "string distortion_model\nfloat64[] d\nfloat64[9] k\nfloat64[9] r\n"
                                  "float64[12] p\nuint32 binning_x\nuint32 binning_y\nRegionOfInterest roi",
    "trajectory_msgs/msg/JointTrajectoryPoint": "float64[] positions\nfloat64[] velocities\n"
                                                "float64[] accelerations\nfloat64[] effort\n"
                                                "builtin_interfaces/Duration time_from_start",
    "trajectory_msgs/msg/JointTrajectory": "std_msgs/Header header\nstring[] joint_names\n"
                                           "JointTrajectoryPoint[] points",
    "rcl_interfaces/msg/Log": "byte DEBUG=10\nbyte INFO=20\nbyte WARN=30\nbyte ERROR=40\nbyte FATAL=50\n"
                              "builtin_interfaces/Time stamp\nuint8 level\nstring name\nstring msg\n"
                              "string file\nstring function\nuint32 line",
    "service_msgs/msg/ServiceEventInfo": "uint8 REQUEST_SENT=0\nuint8 REQUEST_RECEIVED=1\n"
                                         "uint8 RESPONSE_SENT=2\nuint8 RESPONSE_RECEIVED=3\n"
                                         "uint8 event_type\nbuiltin_interfaces/Time stamp\n"
                                         "char[16] client_gid\nint64 sequence_number",
}

# Hashes ROS 2 publishes (`ros2 topic info -v`, rmw_zenoh's design document)
PUBLISHED = {
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
}
ADD_TWO_INTS = ("example_interfaces/srv/AddTwoInts", "int64 a\nint64 b", "int64 sum",
                "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a")

FIELD = re.compile(r"^(?P<type>[A-Za-z_][\w/]*)(?:<=(?P<strbound>\d+))?(?:\[(?P<array>[^\]]*)\])?$")


def own_definition(type_name: str) -> str | None:
    package, kind, name = type_name.split("/")
    path = MSG_ROOT / package / kind / f"{name}.{kind}"
    return path.read_text() if path.exists() else None


def msg_definition(type_name: str) -> str:
    own = own_definition(type_name)
    if own is not None:
        return own
    assert type_name in STANDARD_MSGS, f"no definition of {type_name} in this test"
    return STANDARD_MSGS[type_name]


def parse_fields(text: str, package: str) -> list[dict]:
    """The fields of a .msg text as REP-2011 describes them (name, type id, capacities, nested name)."""
    fields = []
    for raw in text.splitlines():
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        type_text, rest = line.split(None, 1)
        if re.match(r"\w+\s*=", rest):   # a constant, NAME=value: not part of the description
            continue
        name = rest.split(None, 1)[0]
        match = FIELD.match(type_text)
        assert match is not None, f"cannot read the type {type_text!r}"
        base, strbound, array = match["type"], match["strbound"], match["array"]
        nested = ""
        if base in ("string", "wstring"):
            type_id = FIELD_TYPE_IDS[f"bounded_{base}"] if strbound else FIELD_TYPE_IDS[base]
        elif base in FIELD_TYPE_IDS:
            type_id = FIELD_TYPE_IDS[base]
        else:
            if base == "Header":
                base = "std_msgs/Header"
            pkg, _, short = base.rpartition("/")
            nested = f"{pkg or package}/msg/{short}"
            type_id = FIELD_TYPE_IDS["nested"]
        capacity = 0
        if array is not None:
            if array == "":
                type_id += UNBOUNDED_SEQUENCE
            elif array.startswith("<="):
                type_id += BOUNDED_SEQUENCE
                capacity = int(array[2:])
            else:
                type_id += ARRAY
                capacity = int(array)
        fields.append({"name": name, "type": {"type_id": type_id, "capacity": capacity,
                                              "string_capacity": int(strbound or 0),
                                              "nested_type_name": nested}})
    if not fields:   # rosidl gives an empty structure one member
        fields.append({"name": "structure_needs_at_least_one_member",
                       "type": {"type_id": FIELD_TYPE_IDS["uint8"], "capacity": 0, "string_capacity": 0,
                                "nested_type_name": ""}})
    return fields


def rihs01(type_name: str, described: dict[str, list[dict]]) -> str:
    """REP-2011: sha256 over the type description (the type's own fields and every type it reaches,
    sorted by name) serialised as rosidl serialises it for hashing."""
    reached: set[str] = set()
    todo = [type_name]
    while todo:
        for field in described[todo.pop()]:
            nested = field["type"]["nested_type_name"]
            if nested and nested not in reached:
                reached.add(nested)
                todo.append(nested)
    reached.discard(type_name)
    description = {
        "type_description": {"type_name": type_name, "fields": described[type_name]},
        "referenced_type_descriptions": [{"type_name": name, "fields": described[name]}
                                         for name in sorted(reached)],
    }
    text = json.dumps(description, ensure_ascii=True, allow_nan=False, indent=None, separators=(", ", ": "),
                      sort_keys=False)
    return "RIHS01_" + hashlib.sha256(text.encode()).hexdigest()


def describe(type_name: str, described: dict[str, list[dict]]) -> None:
    """`type_name`'s fields and those of every message type it reaches, into `described`."""
    todo = [type_name]
    while todo:
        name = todo.pop()
        if name in described:
            continue
        described[name] = parse_fields(msg_definition(name), name.split("/")[0])
        todo.extend(f["type"]["nested_type_name"] for f in described[name] if f["type"]["nested_type_name"])


@cache
def reference_message_hash(type_name: str) -> str:
    described: dict[str, list[dict]] = {}
    describe(type_name, described)
    return rihs01(type_name, described)


def reference_service_hash(srv_type: str, request: str, response: str) -> str:
    """A service's description: request_message, response_message and event_message (`<Srv>_Event`:
    a ServiceEventInfo, and a request and a response each in a sequence of at most one)."""
    package = srv_type.split("/")[0]
    req, res, event = f"{srv_type}_Request", f"{srv_type}_Response", f"{srv_type}_Event"

    def nested(name: str, field_name: str, type_id: int = FIELD_TYPE_IDS["nested"],
               capacity: int = 0) -> dict:
        return {"name": field_name, "type": {"type_id": type_id, "capacity": capacity, "string_capacity": 0,
                                             "nested_type_name": name}}

    described = {
        req: parse_fields(request, package),
        res: parse_fields(response, package),
        event: [nested("service_msgs/msg/ServiceEventInfo", "info"),
                nested(req, "request", FIELD_TYPE_IDS["nested"] + BOUNDED_SEQUENCE, 1),
                nested(res, "response", FIELD_TYPE_IDS["nested"] + BOUNDED_SEQUENCE, 1)],
        srv_type: [nested(req, "request_message"), nested(res, "response_message"),
                   nested(event, "event_message")],
    }
    for name in [f["type"]["nested_type_name"] for fields in list(described.values()) for f in fields]:
        if name and name not in described:
            describe(name, described)
    return rihs01(srv_type, described)


def carried_message_types() -> list[str]:
    """Every message type the cell carries (the bridge's topics, the registry's request and reply
    types) and every .msg of the cell's own packages."""
    return sorted({name for spec in KEYS for name in (spec.type_name, spec.reply_type) if name}
                  | {f"{path.parent.parent.name}/msg/{path.stem}" for path in MSG_ROOT.glob("*/msg/*.msg")})


def offered_service_types() -> list[str]:
    """The services config/ros2.yaml offers ROS 2, and every .srv of the cell's own packages."""
    shipped = yaml.safe_load((REPO / "config" / "ros2.yaml").read_text())["ros2"]["services"]
    return sorted(set(shipped.values())
                  | {f"{path.parent.parent.name}/srv/{path.stem}" for path in MSG_ROOT.glob("*/srv/*.srv")})


def test_the_reference_reproduces_the_hashes_ros2_publishes():
    for type_name, published in PUBLISHED.items():
        assert reference_message_hash(type_name) == published, type_name
    srv_type, request, response, published = ADD_TWO_INTS
    assert reference_service_hash(srv_type, request, response) == published


def test_the_types_checked_include_the_controller_status_and_every_own_message():
    carried = carried_message_types()
    assert "foldcell_msgs/msg/ControllerStatus" in carried
    own = {f"{path.parent.parent.name}/msg/{path.stem}" for path in Path(MSG_ROOT).glob("*/msg/*.msg")}
    assert own and own <= set(carried)
    assert "foldcell_msgs/srv/CellCommand" in offered_service_types()


@pytest.mark.parametrize("type_name", carried_message_types())
def test_every_message_type_hash_is_the_rep_2011_hash_of_its_msg_text(type_name: str):
    assert types.message_hash(type_name) == reference_message_hash(type_name), type_name


@pytest.mark.parametrize("srv_type", offered_service_types())
def test_every_service_type_hash_is_the_rep_2011_hash_of_its_srv_text(srv_type: str):
    text = own_definition(srv_type)
    assert text is not None, srv_type
    request, response = re.split(r"^---\s*$", text, maxsplit=1, flags=re.MULTILINE)
    assert types.service_hash(srv_type) == reference_service_hash(srv_type, request, response), srv_type
