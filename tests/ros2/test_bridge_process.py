"""`foldcell ros2` as a real process between a live cell and an independent rmw_zenoh peer.

The cell: the controller emulator and the cell daemon on their own loopback endpoint. The ROS 2 side: a
Zenoh router on another endpoint, standing in for rmw_zenohd (router mode, gossip, no multicast). The
ROS 2 node: zenoh-ros2-sdk, which shares no code with foldcell: it finds the graph from liveliness
tokens, computes every type hash itself from the `.msg` texts below (and the `.srv` file: the contract a
ROS user builds foldcell_msgs from), subscribes on the key expression it derives, and calls the service
with rmw_zenoh's attachment. A wrong key, hash, token or attachment and it hears or gets nothing.
"""

from __future__ import annotations

import json
import struct
import threading
import time
from pathlib import Path

import pytest
import zenoh

from drivers.robot.config import default_robot_config
from tests.conftest import Endpoint, foldcell_argv, free_port, wait_until

sdk = pytest.importorskip("zenoh_ros2_sdk")

CELL = "ros2test"
DOMAIN = 7
# The standard types the peer needs, as ROS 2 defines them (std_msgs, builtin_interfaces, sensor_msgs).
STANDARD_MSGS = {
    "builtin_interfaces/msg/Time": "int32 sec\nuint32 nanosec\n",
    "std_msgs/msg/Header": "builtin_interfaces/Time stamp\nstring frame_id\n",
    "sensor_msgs/msg/JointState": "std_msgs/Header header\nstring[] name\nfloat64[] position\n"
                                  "float64[] velocity\nfloat64[] effort\n",
}
SRV = Path(__file__).resolve().parents[2] / "drivers/wire/msgs/foldcell_msgs/srv/CellCommand.srv"


def ros_router(port: int) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "true")
    return zenoh.open(conf)


@pytest.mark.timeout(120)
def test_a_ros2_peer_lists_subscribes_and_calls_the_cell(tmp_path, spawn, monkeypatch):
    for type_name, text in STANDARD_MSGS.items():
        path = tmp_path / "msgs" / f"{type_name}.msg"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    monkeypatch.setattr(sdk.message_registry, "_registry", sdk.MessageRegistry(str(tmp_path / "msgs")))
    request_def, response_def = SRV.read_text().split("\n---\n")

    ep = Endpoint(CELL)
    ros_port = free_port()
    router = ros_router(ros_port)
    controller = spawn(foldcell_argv("controller", "serve", "--role", "both", *ep.args()))
    cell = spawn(foldcell_argv("run", "--no-record", *ep.args()))
    bridge = spawn(foldcell_argv("ros2", "--ros-connect", f"tcp/127.0.0.1:{ros_port}",
                                 "--domain-id", str(DOMAIN), *ep.args()))
    sdk.ZenohSession._instance = None
    session = sdk.ZenohSession.get_instance("127.0.0.1", ros_port)
    for type_name, text in STANDARD_MSGS.items():   # its type store decodes nested types it was given
        session.register_message_type(text, type_name)
    received: list = []
    got = threading.Event()

    def on_joint_state(msg) -> None:
        received.append(msg)
        got.set()

    try:
        topic = f"/foldcell/{CELL}/controller/joint_states"
        service = f"/foldcell/{CELL}/cell/command"

        topics: dict = {}
        services: dict = {}

        def listed() -> bool:   # `ros2 topic list -t` and `ros2 service list -t`, as the peer does them
            topics.update(sdk.get_topic_names_and_types(domain_id=DOMAIN, router_port=ros_port, timeout=2))
            services.update(sdk.get_service_names_and_types(domain_id=DOMAIN, router_port=ros_port,
                                                            timeout=2))
            return topic in topics and service in services

        assert wait_until(listed, 60, 0.5), (topics, services, bridge.stderr()[-3000:])
        assert topics[topic] == ["sensor_msgs/msg/JointState"]
        assert services[service] == ["foldcell_msgs/srv/CellCommand"]
        infos: list = []   # `ros2 topic info -v`; asked again while the peer's links to the others form
        assert wait_until(lambda: infos.append(sdk.get_topic_info(
            topic, domain_id=DOMAIN, router_port=ros_port, timeout=2, verbose=True)) or infos[-1], 30, 0.5)
        info = infos[-1]
        assert info.publisher_count == 1, info
        assert info.publishers[0].node_name == "ros2_bridge"
        assert info.publishers[0].node_namespace == f"/foldcell/{CELL}"
        assert sdk.qos.QosProfile.decode(info.publishers[0].qos).reliability == \
            sdk.qos.QosReliability.BEST_EFFORT   # the 250 Hz stream drops when congested

        sub = sdk.ROS2Subscriber(topic, "sensor_msgs/msg/JointState", on_joint_state,
                                 msg_definition=STANDARD_MSGS["sensor_msgs/msg/JointState"],
                                 domain_id=DOMAIN, router_port=ros_port)
        assert got.wait(30), bridge.stderr()[-3000:]
        assert wait_until(lambda: len(received) >= 20, 30)
        sub.close()
        msg = received[-1]
        assert list(msg.name) == list(default_robot_config().joint_names)
        assert len(msg.position) == len(msg.name)
        assert abs(msg.header.stamp.sec - time.time()) < 60   # one time base: the wall clock

        client = sdk.ROS2ServiceClient(service, "foldcell_msgs/srv/CellCommand",
                                       request_definition=request_def, response_definition=response_def,
                                       domain_id=DOMAIN, router_port=ros_port, timeout=10.0)
        reply = None
        deadline = time.monotonic() + 30   # the cell may still be starting
        while reply is None and time.monotonic() < deadline:
            now = time.time_ns()
            header = session.store.types["std_msgs/msg/Header"](
                stamp=session.store.types["builtin_interfaces/msg/Time"](sec=now // 10**9,
                                                                        nanosec=now % 10**9),
                frame_id="")
            reply = client.call(header=header, command="status", argument="", client="ros2-test")
        assert reply is not None, (bridge.stderr()[-3000:], cell.stderr()[-3000:])
        assert reply.accepted, reply
        assert reply.state == "idle", reply

        # rclcpp pairs a response with its request by the reply's attachment (the peer above does not
        # look): it must carry the request's sequence number and client GID, as rmw_zenoh's design says.
        gid = bytes(range(16))
        request = struct.pack("<qqB", 41, time.time_ns(), 16) + gid
        payload = bytes(session.store.serialize_cdr(
            client.request_msg_class(header=header, command="status", argument="", client=""),
            client.request_store_type))
        replies = list(session.session.get(client.keyexpr, payload=payload, attachment=request, timeout=10))
        client.close()
        assert len(replies) == 1 and replies[0].ok is not None, replies
        attachment = replies[0].ok.attachment.to_bytes()
        seq, stamp_ns, gid_len = struct.unpack_from("<qqB", attachment)
        assert (seq, gid_len, attachment[17:]) == (41, 16, gid)
        assert abs(stamp_ns - time.time_ns()) < 60e9
        assert f"from ros2:{gid.hex()}" in cell.stderr()   # a nameless ROS client is named by its GID
    finally:
        session.close()
        router.close()
        bridge.stop()
        cell.stop()
        controller.stop()
    assert "Traceback" not in bridge.stderr(), bridge.stderr()
