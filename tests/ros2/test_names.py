"""rmw_zenoh's names, tokens, hashes and attachments as the bridge forms them, against independent
references: the examples of rmw_zenoh's design document (docs/design.md), hashes published by ROS 2
(`ros2 topic info -v` output, rmw_zenoh's examples) and zenoh-ros2-sdk, which shares no code with ours."""

from __future__ import annotations

import re
import struct
from functools import cache
from pathlib import Path

import pytest
from rosbags.typesys import Stores, get_typestore

from drivers.common.configfile import ConfigError
from drivers.ros2 import names, types
from drivers.ros2.config import check_domain_id, load_ros2_config
from drivers.wire.registry import KEYS, spec_for
from drivers.wire.settings import load_wire_settings
from tests.conftest import REPO

STRING_HASH = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
ADD_TWO_INTS_HASH = "RIHS01_e118de6bf5eeb66a2491b5bda11202e7b68f198d6f67922cf30364858239c81a"
JOINT_STATE_HASH = "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"


def test_data_keys_are_those_of_the_design_documents_examples():
    assert names.data_key(0, "/chatter", "std_msgs/msg/String", STRING_HASH) == \
        f"0/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert names.data_key(0, "/robot1/chatter", "std_msgs/msg/String", STRING_HASH) == \
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{STRING_HASH}"
    assert names.data_key(2, "/add_two_ints", "example_interfaces/srv/AddTwoInts", ADD_TWO_INTS_HASH) == \
        f"2/add_two_ints/example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS_HASH}"


def test_tokens_are_those_of_the_design_documents_examples():
    listener = names.Node(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "/", "listener")
    assert listener.token() == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    talker = names.Node(2, "8b20917502ee955ac4476e0266340d5c", 0, "/", "talker")
    assert talker.entity_token(10, names.PUBLISHER, "/chatter", "std_msgs/msg/String", STRING_HASH,
                               names.Qos(names.RELIABLE, 7)) == (
        "@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
        f"std_msgs::msg::dds_::String_/{STRING_HASH}/::,7:,:,:,,")
    server = names.Node(2, "f9980ee0495eaafb3e38f0d19e2eae12", 0, "/", "add_two_ints_server")
    assert server.entity_token(10, names.SERVICE_SERVER, "/add_two_ints", "example_interfaces/srv/AddTwoInts",
                               ADD_TWO_INTS_HASH, names.Qos()) == (
        "@ros2_lv/2/f9980ee0495eaafb3e38f0d19e2eae12/0/10/SS/%/%/add_two_ints_server/%add_two_ints/"
        f"example_interfaces::srv::dds_::AddTwoInts_/{ADD_TWO_INTS_HASH}/::,10:,:,:,,")


def test_a_namespaced_node_mangles_every_slash():
    node = names.Node(0, "ab", 0, "/foldcell/cell1", "ros2_bridge")
    assert node.token() == "@ros2_lv/0/ab/0/0/NN/%/%foldcell%cell1/ros2_bridge"
    token = node.entity_token(3, names.PUBLISHER, "/foldcell/cell1/controller/joint_states",
                              "sensor_msgs/msg/JointState", JOINT_STATE_HASH, names.Qos(names.BEST_EFFORT, 5))
    assert token.split("/")[9] == "%foldcell%cell1%controller%joint_states"
    assert token.endswith("/2::,5:,:,:,,")


def test_the_qos_reads_back_in_an_independent_decoder():
    qos_module = pytest.importorskip("zenoh_ros2_sdk.qos")
    best_effort = qos_module.QosProfile.decode(names.Qos(names.BEST_EFFORT, 5).encoded())
    assert best_effort.reliability == qos_module.QosReliability.BEST_EFFORT
    assert best_effort.history_depth == 5
    reliable = qos_module.QosProfile.decode(names.Qos(names.RELIABLE, 10).encoded())
    assert reliable.reliability == qos_module.QosReliability.RELIABLE
    assert reliable.history_depth == 10


def test_message_hashes_are_the_published_ones():
    assert types.message_hash("std_msgs/msg/String") == STRING_HASH
    assert types.message_hash("sensor_msgs/msg/JointState") == JOINT_STATE_HASH


MSG_FILES = REPO / "drivers/wire/msgs"
PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16", "int32",
              "uint32", "int64", "uint64", "string", "wstring"}
# every type the cell carries: the registry's (the bridge's topics) and every .msg of its own packages
CARRIED_TYPES = sorted({name for spec in KEYS for name in (spec.type_name, spec.reply_type) if name}
                       | {f"{path.parent.parent.name}/msg/{path.stem}"
                          for path in MSG_FILES.glob("*/msg/*.msg")})


@cache
def ros2_definition(type_name: str) -> str:
    """The .msg text a ROS 2 peer compiles: the project's own file, or ROS 2 Jazzy's as rosbags ships it."""
    package, _, name = type_name.split("/")
    own = MSG_FILES / package / "msg" / f"{name}.msg"
    if own.exists():
        return own.read_text()
    with_dependencies = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(type_name, ros_version=2)[0]
    return with_dependencies.split("\n" + "=" * 80)[0]


def reached_definitions(type_name: str) -> dict[str, str]:
    """The definitions of every type `type_name` reaches through its fields, by full name."""
    found: dict[str, str] = {}
    todo = [type_name]
    while todo:
        name = todo.pop()
        if name in found:
            continue
        found[name] = ros2_definition(name)
        for line in found[name].splitlines():
            words = line.split("#")[0].split()
            if len(words) < 2 or "=" in "".join(words[1:]):      # blank, or a constant
                continue
            base = re.match(r"[\w/]+", words[0]).group()         # without <=N or [...]
            if base not in PRIMITIVES:
                package, _, short = base.rpartition("/")
                todo.append(f"{package or name.split('/')[0]}/msg/{short}")
    return found


@pytest.mark.parametrize("type_name", CARRIED_TYPES)
def test_every_carried_type_hash_agrees_with_an_independent_implementation(type_name: str):
    # zenoh-ros2-sdk hashes the .msg texts by its own code: what a ROS 2 peer computes for the type
    sdk_utils = pytest.importorskip("zenoh_ros2_sdk.utils")
    definitions = reached_definitions(type_name)
    own = definitions.pop(type_name)
    assert types.message_hash(type_name) == sdk_utils.compute_type_hash_from_msg(type_name, own, definitions)


def test_a_service_hash_is_the_published_one():
    assert types.service_hash_of("example_interfaces/srv/AddTwoInts", "int64 a\nint64 b", "int64 sum") == \
        ADD_TWO_INTS_HASH


def test_the_cell_command_service_hash_agrees_with_an_independent_implementation():
    sdk_utils = pytest.importorskip("zenoh_ros2_sdk.utils")
    request, response = types.srv_halves("foldcell_msgs/srv/CellCommand")
    dependencies = {"std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id",
                    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec"}
    assert types.service_hash("foldcell_msgs/srv/CellCommand") == sdk_utils.compute_service_type_hash(
        "foldcell_msgs/srv/CellCommand", request, response, dependencies)


def test_the_service_carries_the_registrys_bytes_and_a_mismatch_is_refused():
    types.check_layout("foldcell_msgs/srv/CellCommand", spec_for("cell/command"))
    with pytest.raises(types.ServiceTypeError, match="request is not laid out as"):
        types.check_layout("foldcell_msgs/srv/CellCommand", spec_for("controller/command"))


def test_the_attachment_is_laid_out_as_the_design_says():
    gid = bytes(range(16))
    data = names.attachment(5, 1_700_000_000_123456789, gid)
    assert data == struct.pack("<q", 5) + struct.pack("<q", 1_700_000_000_123456789) + b"\x10" + gid
    assert names.parse_attachment(data) == (5, 1_700_000_000_123456789, gid)
    sdk_attachment = pytest.importorskip("zenoh_ros2_sdk.attachment")
    parsed = sdk_attachment.Attachment.from_bytes(data)
    assert (parsed.sequence_id, parsed.timestamp_ns, parsed.gid) == (5, 1_700_000_000_123456789, gid)
    with pytest.raises(ValueError, match="shorter than"):
        names.parse_attachment(b"\x00" * 8)
    with pytest.raises(ValueError, match="announces a GID of 16 bytes and holds 3"):
        names.parse_attachment(data[:20])


def test_the_gid_is_stable_and_unique_per_token():
    assert names.gid_of("a") == names.gid_of("a") != names.gid_of("b")
    assert len(names.gid_of("a")) == names.GID_SIZE


def test_foldcell_names_map_to_ros_names_or_are_refused_with_the_reason():
    assert names.ros_name("/foldcell", "cell1", "controller/gripper/left") == \
        "/foldcell/cell1/controller/gripper/left"
    with pytest.raises(names.RosNameError, match=r"cell id 'cell-1'.*letters, digits and '_' only"):
        names.ros_name("/foldcell", "cell-1", "cell/state")
    with pytest.raises(names.RosNameError, match="not starting with a digit"):
        names.ros_name("/foldcell", "1cell", "cell/state")
    with pytest.raises(names.RosNameError, match="repeats '_'"):
        names.ros_name("/foldcell", "a__b", "cell/state")


def test_config_and_domain_ids_are_checked(tmp_path: Path):
    config = load_ros2_config()
    assert config.connect == ("tcp/127.0.0.1:7447",)   # rmw_zenohd's default endpoint
    assert config.services == {"cell/command": "foldcell_msgs/srv/CellCommand"}
    assert check_domain_id("42", "--domain-id") == 42
    with pytest.raises(ValueError, match=re.escape("--domain-id: must be 0..232, got 233")):
        check_domain_id("233", "--domain-id")
    with pytest.raises(ValueError, match="ROS_DOMAIN_ID: must be a whole number"):
        check_domain_id("x", "ROS_DOMAIN_ID")
    bad = tmp_path / "ros2.yaml"
    text = (REPO / "config/ros2.yaml").read_text()
    bad.write_text(text.replace("cell/command: foldcell_msgs", "cell/state: foldcell_msgs"))
    with pytest.raises(ConfigError, match=re.escape("ros2.services.cell/state: is a pub of the registry")):
        load_ros2_config(bad)


def test_foldcells_meeting_point_leaves_rmw_zenohds_port_free():
    """rmw_zenohd listens on tcp/[::]:7447, which also takes 127.0.0.1:7447: foldcell's default meeting
    point must be another port, or whichever starts second fails (README "ROS 2 users")."""
    settings = load_wire_settings()
    ports = {endpoint.rsplit(":", 1)[1] for endpoint in settings.listen + settings.connect}
    assert "7447" not in ports
    assert "7448" in ports
