"""How ROS 2 nodes on rmw_zenoh_cpp name things on Zenoh (pure: strings and bytes, no Zenoh).

After rmw_zenoh's design document (docs/design.md of ros2/rmw_zenoh, Jazzy and later):
- a topic's or a service's data travel on `<domain_id>/<name without leading slash>/<DDS type>/<hash>`;
- every node, publisher and service server holds a liveliness token
  `@ros2_lv/<domain>/<zid>/<nid>/<eid>/<kind>/<enclave>/<namespace>/<node>[/<name>/<type>/<hash>/<qos>]`,
  each name "mangled" (`/` -> `%`), which `ros2 node|topic|service list` read as the graph;
- each sample, request and reply carries an attachment: int64 sequence number, int64 source time (ns
  since the epoch), both little-endian, then one byte for the GID's length and the 16-byte GID.
"""

from __future__ import annotations

import hashlib
import re
import struct
from dataclasses import dataclass

ADMIN_SPACE = "@ros2_lv"
NODE, PUBLISHER, SERVICE_SERVER = "NN", "MP", "SS"
GID_SIZE = 16
_ATTACHMENT_HEAD = struct.Struct("<qqB")

# rmw's QoS enums (rmw/types.h) and rmw_zenoh's defaults (detail/qos.cpp): a token writes a field only
# where the entity's QoS differs from the default.
RELIABLE, BEST_EFFORT = 1, 2
RELIABILITIES = {"reliable": RELIABLE, "best_effort": BEST_EFFORT}
_DEFAULT_RELIABILITY, _DEFAULT_DEPTH = RELIABLE, 42

# A ROS 2 name token (design.ros2.org "Topic and Service name mapping"): letters, digits and
# underscores, not starting with a digit, no repeated underscores.
_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class RosNameError(ValueError):
    """A foldcell name (cell id, key) that is not a valid ROS 2 name; says which part and why."""


def check_token(token: str, what: str) -> str:
    if not _TOKEN.match(token):
        raise RosNameError(f"{what} {token!r} is not a ROS 2 name token: letters, digits and '_' only, "
                         "not starting with a digit")
    if "__" in token:
        raise RosNameError(f"{what} {token!r} is not a ROS 2 name token: it repeats '_'")
    return token


def ros_name(namespace: str, cell: str, relative_key: str) -> str:
    """The ROS topic or service name of a foldcell key: `/foldcell/cell1/controller/joint_states`
    (the topic a session log files it under)."""
    check_token(cell, "cell id")
    for chunk in relative_key.split("/"):
        check_token(chunk, f"key {relative_key!r}: chunk")
    return f"{namespace.rstrip('/')}/{cell}/{relative_key}"


def dds_type(type_name: str) -> str:
    """`sensor_msgs/msg/JointState` -> `sensor_msgs::msg::dds_::JointState_` (also `.../srv/...`)."""
    package, kind, name = type_name.split("/")
    return f"{package}::{kind}::dds_::{name}_"


def mangle(name: str) -> str:
    return name.replace("/", "%")


def data_key(domain_id: int, name: str, type_name: str, type_hash: str) -> str:
    """The key expression a topic's samples (or a service's queries) travel on."""
    return f"{domain_id}/{name.strip('/')}/{dds_type(type_name)}/{type_hash}"


@dataclass(frozen=True)
class Qos:
    reliability: int = RELIABLE
    depth: int = 10

    def encoded(self) -> str:
        """rmw_zenoh's compact form `<rel>:<dur>:<hist>,<depth>:<deadline s,ns>:<lifespan s,ns>:
        <liveliness,lease s,ns>`, empty where the value is rmw_zenoh's default (volatile, keep last,
        infinite deadline and lifespan, automatic liveliness)."""
        reliability = "" if self.reliability == _DEFAULT_RELIABILITY else str(self.reliability)
        depth = "" if self.depth == _DEFAULT_DEPTH else str(self.depth)
        return f"{reliability}::,{depth}:,:,:,,"


@dataclass(frozen=True)
class Node:
    domain_id: int
    zid: str             # the Zenoh session id, hex
    node_id: int
    namespace: str       # `/foldcell/cell1`
    name: str
    enclave: str = "/"

    def token(self) -> str:
        return "/".join((ADMIN_SPACE, str(self.domain_id), self.zid, str(self.node_id), str(self.node_id),
                         NODE, mangle(self.enclave), mangle(self.namespace), mangle(self.name)))

    def entity_token(self, entity_id: int, kind: str, name: str, type_name: str, type_hash: str,
                     qos: Qos) -> str:
        """The token of a publisher (MP) or service server (SS) of this node."""
        return "/".join((ADMIN_SPACE, str(self.domain_id), self.zid, str(self.node_id), str(entity_id), kind,
                         mangle(self.enclave), mangle(self.namespace), mangle(self.name), mangle(name),
                         dds_type(type_name), type_hash, qos.encoded()))


def gid_of(token: str) -> bytes:
    """An entity's 16-byte GID, derived from its token so it is unique and stable (rmw_zenoh hashes
    the token too, with XXH3; any unique value serves: peers only compare GIDs)."""
    return hashlib.sha256(token.encode()).digest()[:GID_SIZE]


def attachment(seq: int, stamp_ns: int, gid: bytes) -> bytes:
    if len(gid) != GID_SIZE:
        raise ValueError(f"gid: must be {GID_SIZE} bytes, got {len(gid)}")
    return _ATTACHMENT_HEAD.pack(seq, stamp_ns, GID_SIZE) + gid


def parse_attachment(data: bytes) -> tuple[int, int, bytes]:
    """(sequence number, source time ns, GID) of an rmw_zenoh attachment; ValueError says what is wrong."""
    if len(data) < _ATTACHMENT_HEAD.size:
        raise ValueError(f"attachment of {len(data)} bytes is shorter than rmw_zenoh's "
                         f"{_ATTACHMENT_HEAD.size}-byte head (sequence number, time, GID length)")
    seq, stamp_ns, gid_len = _ATTACHMENT_HEAD.unpack_from(data)
    gid = data[_ATTACHMENT_HEAD.size:]
    if len(gid) != gid_len:
        raise ValueError(f"attachment announces a GID of {gid_len} bytes and holds {len(gid)}")
    return seq, stamp_ns, gid
