"""The Foxglove bridge: URDF frames and annotations (pure), a live cell served over WebSocket (real
server, a minimal WebSocket client here), and a session log exported for Foxglove."""

from __future__ import annotations

import base64
import json
import os
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from drivers.robot.config import default_robot_config
from drivers.sessions.foxglove import (
    BridgeError,
    FoxgloveBridge,
    annotations_from_observation,
    joint_transform,
    load_foxglove_config,
    parse_urdf_joints,
    quaternion_xyzw,
    tf_message,
)
from drivers.sessions.mcap.reader import iter_messages
from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.conftest import REPO, Endpoint, foldcell_argv, wait_until
from tests.nodes.fake_cell import towel_image_and_observation

CFG = load_foxglove_config()
URDF = Path(default_robot_config().urdf_path)


# --- pure parts ---------------------------------------------------------------------------------


def chain_to(joints, positions: dict[str, float], link: str) -> np.ndarray:
    by_child = {j.child: j for j in joints}
    t = np.eye(4)
    while link in by_child:
        j = by_child[link]
        t = joint_transform(j, positions.get(j.name, 0.0)) @ t
        link = j.parent
    return t


def test_urdf_link_frames_agree_with_pinocchio() -> None:
    import pinocchio as pin

    joints = parse_urdf_joints(URDF.read_text(), str(URDF))
    model = pin.buildModelFromUrdf(str(URDF))
    data = model.createData()
    rng = np.random.default_rng(11)
    robot = default_robot_config()
    for _ in range(20):
        q_named = {j.name: float(rng.uniform(j.lower, j.upper)) for j in robot.joints}
        q = pin.neutral(model)
        for name, value in q_named.items():
            jid = model.getJointId(name)
            q[model.joints[jid].idx_q] = value
        pin.framesForwardKinematics(model, data, q)
        for frame in ("r1_tcp", "r2_tcp", "r1_link_b", "camera"):
            expected = data.oMf[model.getFrameId(frame)].homogeneous
            np.testing.assert_allclose(chain_to(joints, q_named, frame), expected, atol=1e-9)


def test_quaternions_are_unit_and_rebuild_the_rotation() -> None:
    rng = np.random.default_rng(5)
    for _ in range(200):
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        angle = float(rng.uniform(-np.pi, np.pi))
        from drivers.sessions.foxglove import _axis_angle

        r = _axis_angle(axis, angle)
        x, y, z, w = quaternion_xyzw(r)
        assert abs(x * x + y * y + z * z + w * w - 1) < 1e-9
        rebuilt = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        np.testing.assert_allclose(rebuilt, r, atol=1e-9)


def test_tf_message_has_every_joint_and_encodes() -> None:
    joints = parse_urdf_joints(URDF.read_text())
    msg = tf_message(joints, {"r1_joint_s": 0.5}, 123)
    assert len(msg.transforms) == len(joints)
    names = {(t.header.frame_id, t.child_frame_id) for t in msg.transforms}
    assert ("turntable_base", "turntable") in names
    messages.encode("tf2_msgs/msg/TFMessage", msg)


@pytest.mark.parametrize(
    "text,words",
    [
        ("<robot><joint", "not valid XML"),
        ("<robot><joint name='j'/></robot>", "no parent"),
        (
            "<robot><joint name='j'><parent link='a'/><child link='b'/>"
            "<origin xyz='1 2'/></joint></robot>",
            "three numbers",
        ),
    ],
)
def test_bad_urdf_is_named(text: str, words: str) -> None:
    with pytest.raises(BridgeError, match=words):
        parse_urdf_joints(text, "x.urdf")


def test_annotations_draw_the_polygon_and_named_landmarks() -> None:
    _, obs = towel_image_and_observation(42)
    ann = annotations_from_observation(obs, CFG.style)
    assert len(ann.points) == 1 and ann.points[0].type == 2  # LINE_LOOP
    assert [(p.x, p.y) for p in ann.points[0].points] == [(p.x, p.y) for p in obs.polygon_px]
    assert [(c.position.x, c.position.y) for c in ann.circles] == [(lm.x_px, lm.y_px) for lm in obs.landmarks]
    assert {t.text for t in ann.texts} >= {lm.name for lm in obs.landmarks}
    assert all(messages.stamp_to_ns(c.timestamp) == 42 for c in ann.circles)
    data = messages.encode("foxglove_msgs/msg/ImageAnnotations", ann)
    assert messages.decode("foxglove_msgs/msg/ImageAnnotations", data).texts[0].text == obs.landmarks[0].name


# --- a minimal Foxglove WebSocket client ---------------------------------------------------------


class WsClient:
    """`subprotocol`: what the client asks for (Foxglove Studio 2.x: foxglove.sdk.v1; Lichtblick and older
    Studio: foxglove.websocket.v1); `.granted` is what the server answered."""

    def __init__(self, port: int, subprotocol: str = "foxglove.sdk.v1"):
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=10)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\n"
                f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                f"Sec-WebSocket-Protocol: {subprotocol}\r\n\r\n"
            ).encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        assert b" 101 " in head.split(b"\r\n")[0], head
        granted = [line.split(b":", 1)[1].strip() for line in head.split(b"\r\n")
                   if line.lower().startswith(b"sec-websocket-protocol:")]
        self.granted = granted[0].decode() if granted else ""

    def _read(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            if not chunk:
                raise ConnectionError("closed")
            out += chunk
        return out

    def frame(self) -> tuple[int, bytes]:
        data, opcode = b"", None
        while True:
            b0, b1 = self._read(2)
            n = b1 & 0x7F
            if n == 126:
                n = struct.unpack(">H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack(">Q", self._read(8))[0]
            data += self._read(n)
            opcode = opcode or (b0 & 0x0F)
            if b0 & 0x80:
                return opcode, data

    def send_json(self, doc: dict) -> None:
        payload = json.dumps(doc).encode()
        mask = os.urandom(4)
        header = bytes([0x81]) + (
            bytes([0x80 | len(payload)])
            if len(payload) < 126
            else bytes([0x80 | 126]) + struct.pack(">H", len(payload))
        )
        self.sock.sendall(header + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload)))

    def close(self) -> None:
        self.sock.close()


@pytest.mark.parametrize("subprotocol", ["foxglove.sdk.v1", "foxglove.websocket.v1"])
def test_a_live_cell_is_served_over_the_foxglove_protocol(spawn, subprotocol: str) -> None:
    ep = Endpoint("fx")
    with Wire(ep.settings(), "foxglove-test") as wire:
        bridge = FoxgloveBridge(wire, "fx", CFG, URDF, port=0)
        client = None
        try:
            spawn(
                [
                    sys.executable,
                    "-m",
                    "tests.nodes.fake_cell",
                    *ep.args(),
                    "--forever",
                    "--image",
                    "--state-period",
                    "0.2",
                ]
            )
            assert wait_until(lambda: bridge.forwarded > 50, 20)
            client = WsClient(bridge.port, subprotocol)
            assert client.granted == subprotocol   # the name the client asked for, as RFC 6455 wants
            channels: dict[str, dict] = {}
            deadline = time.monotonic() + 10
            wanted = {
                "/foldcell/fx/controller/joint_states",
                "/robot_description",
                "/tf",
                "/foldcell/fx/cell/state",
            }
            while not wanted <= set(channels) and time.monotonic() < deadline:
                opcode, data = client.frame()
                if opcode == 1:
                    doc = json.loads(data)
                    if doc.get("op") == "advertise":
                        channels.update({c["topic"]: c for c in doc["channels"]})
            assert wanted <= set(channels), sorted(channels)
            js = channels["/foldcell/fx/controller/joint_states"]
            assert js["encoding"] == "cdr" and js["schemaName"] == "sensor_msgs/msg/JointState"
            assert js["schemaEncoding"] == "ros2msg" and "float64[] position" in js["schema"]
            subs = {1: "/foldcell/fx/controller/joint_states", 2: "/tf", 3: "/robot_description"}
            client.send_json(
                {
                    "op": "subscribe",
                    "subscriptions": [{"id": i, "channelId": channels[t]["id"]} for i, t in subs.items()],
                }
            )
            got: dict[str, bytes] = {}
            deadline = time.monotonic() + 10
            while len(got) < len(subs) and time.monotonic() < deadline:
                opcode, data = client.frame()
                if opcode == 2 and data[0] == 1:  # binary message data
                    sub_id, _log_time = struct.unpack_from("<IQ", data, 1)
                    got[subs[sub_id]] = data[13:]
            assert set(got) == set(subs.values())
            state = messages.decode("sensor_msgs/msg/JointState", got["/foldcell/fx/controller/joint_states"])
            assert list(state.name) == list(default_robot_config().joint_names)
            tf = messages.decode("tf2_msgs/msg/TFMessage", got["/tf"])
            assert len(tf.transforms) == len(bridge.joints)
            assert "<robot" in messages.decode("std_msgs/msg/String", got["/robot_description"]).data
        finally:
            if client is not None:
                client.close()
            bridge.close()


def test_export_adds_annotations_frames_and_the_urdf(tmp_path: Path) -> None:
    from drivers.sessions.mcap.writer import SessionWriter

    src, dst = tmp_path / "s.mcap", tmp_path / "s.foxglove.mcap"
    image, obs = towel_image_and_observation(5_000_000_000)
    names = list(default_robot_config().joint_names)
    with SessionWriter(src) as w:

        def put(key: str, type_name: str, msg, t: int) -> None:
            w.write(
                "/foldcell/x/" + key,
                type_name,
                messages.msgdef(type_name),
                messages.encode(type_name, msg),
                t,
                t,
            )

        for i in range(100):  # 1 s of 100 Hz joints
            put(
                "controller/joint_states",
                "sensor_msgs/msg/JointState",
                messages.new("sensor_msgs/msg/JointState", name=names, position=np.full(len(names), i / 100)),
                4 * 10**9 + i * 10**7,
            )
        put("camera/image", "sensor_msgs/msg/CompressedImage", image, 5 * 10**9)
        put("perception/observation", "foldcell_msgs/msg/GarmentObservation", obs, 5 * 10**9 + 1)
    r = subprocess.run(
        foldcell_argv("foxglove", "--export", str(src), "-o", str(dst)),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    out = list(iter_messages(dst))
    by_topic: dict[str, list] = {}
    for m in out:
        by_topic.setdefault(m.topic, []).append(m)
    assert len(by_topic["/foldcell/x/controller/joint_states"]) == 100
    assert len(by_topic["/robot_description"]) == 1
    assert 20 <= len(by_topic["/tf"]) <= 40  # at most 30 Hz over 1 s
    ann = by_topic["/foldcell/x/foxglove/observation_annotations"]
    assert len(ann) == 1
    decoded = messages.decode("foxglove_msgs/msg/ImageAnnotations", ann[0].data)
    assert len(decoded.circles) == len(obs.landmarks)
    bad = subprocess.run(
        foldcell_argv("foxglove", "--export", str(tmp_path / "none.mcap")),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert bad.returncode == 2 and bad.stderr.startswith("foldcell: error:")


def test_bad_port_is_refused() -> None:
    r = subprocess.run(
        foldcell_argv("foxglove", "--port", "70000"), cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert r.returncode == 2 and "--port" in r.stderr


def test_the_layout_in_docs_is_the_generated_one() -> None:
    from drivers.sessions.foxglove import default_layout

    text = default_layout("cell1", CFG, list(default_robot_config().joint_names))
    assert (REPO / "docs" / "foxglove_layout.json").read_text() == text
    doc = json.loads(text)
    flat = json.dumps(doc)
    for topic in (
        "/foldcell/cell1/camera/image",
        "/foldcell/cell1/foxglove/observation_annotations",
        "/foldcell/cell1/controller/joint_states",
        "/foldcell/cell1/cell/log",
        "/robot_description",
    ):
        assert topic in flat
    other = subprocess.run(
        foldcell_argv("foxglove", "--layout", "--cell", "c9"),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert (
        other.returncode == 0 and "/foldcell/c9/camera/image" in other.stdout and "cell1" not in other.stdout
    )


def test_the_foxglove_command_serves_and_stops_on_sigint(spawn) -> None:
    from tests.conftest import free_port

    ep = Endpoint("fxcli")
    port = free_port()
    proc = spawn(foldcell_argv("foxglove", "--port", str(port), *ep.args()))

    def accepting() -> bool:
        try:
            WsClient(port).close()
            return True
        except (OSError, AssertionError):
            return False

    assert wait_until(accepting, 20)
    assert proc.stop() == 0
    # a busy port is reported cleanly, without a traceback
    with socket.socket() as s:
        s.bind(("127.0.0.1", port))
        s.listen()
        busy = subprocess.run(
            foldcell_argv("foxglove", "--port", str(port), *ep.args()),
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=60,
        )
    assert busy.returncode == 1 and busy.stderr.startswith(
        "foldcell: error: cannot start the Foxglove server"
    )
