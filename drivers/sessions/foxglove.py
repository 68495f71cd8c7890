"""A live cell served to the Foxglove app over its WebSocket protocol (the `foxglove-sdk` package).

Every sample of the cell's published keys is forwarded as received (CDR bytes, `ros2msg` schema),
on the same topic name as in a session log (`/foldcell/<cell>/<key>`), so one Foxglove layout
serves both a live cell and a recorded session. Added for the 3D and image panels:
- `/robot_description` (std_msgs/String): the cell's URDF, sent again periodically;
- `/tf` (tf2_msgs/TFMessage): every URDF joint's transform at the latest joint state;
- `/foldcell/<cell>/foxglove/observation_annotations` (foxglove_msgs/ImageAnnotations): the matched
  polygon and named landmarks of each `perception/observation`, to draw on `camera/image`.
The pure parts (URDF joints, transforms, annotations) are tested without a server.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drivers.common.configfile import Fields, config_dir, load_yaml
from drivers.common.rotations import quaternion_xyzw, rpy_to_matrix
from drivers.sessions.annotations import (
    ANNOTATIONS_TYPE,
    STYLE_FIELDS,
    AnnotationStyle,
    annotation_style_from_fields,
    annotations_from_observation,
)
from drivers.sessions.ws_subprotocol import SubprotocolProxy
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import KEYS, ROOT, split_key, type_for_full_key
from drivers.wire.transport import RawSample, Wire

log = logging.getLogger(__name__)

CONFIG_FILE = "replay_monitor.yaml"
JOINT_STATES = "controller/joint_states"
OBSERVATION = "perception/observation"
STRING_TYPE = "std_msgs/msg/String"
TF_TYPE = "tf2_msgs/msg/TFMessage"
MOVING = ("revolute", "continuous", "prismatic")


class BridgeError(ValueError):
    """The bridge cannot start or a URDF cannot be used: names the file or argument and the reason."""


@dataclass(frozen=True)
class FoxgloveConfig:
    host: str
    port: int
    robot_description_topic: str
    tf_topic: str
    description_period_s: float
    tf_rate_hz: float
    annotations_suffix: str
    style: AnnotationStyle


def foxglove_config_from_fields(f: Fields) -> FoxgloveConfig:
    f.reject_unknown((set(FoxgloveConfig.__dataclass_fields__) - {"style"}) | STYLE_FIELDS)
    return FoxgloveConfig(
        host=f.str("host"),
        port=f.int("port", min=0, max=65535),
        robot_description_topic=f.str("robot_description_topic"),
        tf_topic=f.str("tf_topic"),
        description_period_s=f.float("description_period_s", positive=True),
        tf_rate_hz=f.float("tf_rate_hz", positive=True),
        annotations_suffix=f.str("annotations_suffix"),
        style=annotation_style_from_fields(f),
    )


def load_foxglove_config(path: str | Path | None = None) -> FoxgloveConfig:
    return foxglove_config_from_fields(
        load_yaml(Path(path) if path else config_dir() / CONFIG_FILE).sub("foxglove")
    )


# --- URDF joints and link transforms ---------------------------------------------------------


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    type: str
    parent: str
    child: str
    origin: NDArray  # 4x4, child frame at zero position in the parent link frame
    axis: NDArray  # unit vector in the joint frame


def _axis_angle(axis: NDArray, angle: float) -> NDArray:
    x, y, z = axis
    c, s, t = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return np.array(
        [
            [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
        ]
    )


def _floats(text: str | None, default: tuple[float, float, float], where: str) -> NDArray:
    if text is None:
        return np.array(default, float)
    try:
        values = [float(v) for v in text.split()]
    except ValueError:
        values = []
    if len(values) != 3:
        raise BridgeError(f"{where}: expected three numbers, got {text!r}")
    return np.array(values)


def parse_urdf_joints(urdf_text: str, source: str = "URDF") -> list[UrdfJoint]:
    """Every joint of a URDF with its origin and axis."""
    try:
        root = ET.fromstring(urdf_text)
    except ET.ParseError as exc:
        raise BridgeError(f"{source}: not valid XML: {exc}") from exc
    joints = []
    for j in root.iter("joint"):
        name = j.get("name", "?")
        parent, child = j.find("parent"), j.find("child")
        if parent is None or child is None:
            raise BridgeError(f"{source}: joint {name!r} has no parent or child link")
        origin = np.eye(4)
        o = j.find("origin")
        if o is not None:
            origin[:3, :3] = rpy_to_matrix(
                _floats(o.get("rpy"), (0, 0, 0), f"{source}: joint {name!r} origin rpy")
            )
            origin[:3, 3] = _floats(o.get("xyz"), (0, 0, 0), f"{source}: joint {name!r} origin xyz")
        a = j.find("axis")
        axis = _floats(a.get("xyz") if a is not None else None, (1, 0, 0), f"{source}: joint {name!r} axis")
        norm = float(np.linalg.norm(axis))
        joints.append(
            UrdfJoint(
                name,
                j.get("type", "fixed"),
                parent.get("link", ""),
                child.get("link", ""),
                origin,
                axis / norm if norm > 0 else axis,
            )
        )
    return joints


def joint_transform(joint: UrdfJoint, position: float) -> NDArray:
    """Child link frame in the parent link frame at `position` (rad or m)."""
    motion = np.eye(4)
    if joint.type in ("revolute", "continuous"):
        motion[:3, :3] = _axis_angle(joint.axis, position)
    elif joint.type == "prismatic":
        motion[:3, 3] = joint.axis * position
    return joint.origin @ motion


def tf_message(joints: list[UrdfJoint], positions: Mapping[str, float], stamp_ns: int) -> Any:
    """A tf2_msgs/TFMessage with every joint's transform; joints without a position stay at 0."""
    transforms = []
    for j in joints:
        t = joint_transform(j, float(positions.get(j.name, 0.0)) if j.type in MOVING else 0.0)
        x, y, z, w = quaternion_xyzw(t[:3, :3])
        transforms.append(
            messages.new(
                "geometry_msgs/msg/TransformStamped",
                header=messages.header(stamp_ns, j.parent),
                child_frame_id=j.child,
                transform=messages.new(
                    "geometry_msgs/msg/Transform",
                    translation=messages.new(
                        "geometry_msgs/msg/Vector3", x=float(t[0, 3]), y=float(t[1, 3]), z=float(t[2, 3])
                    ),
                    rotation=messages.new("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
                ),
            )
        )
    return messages.new(TF_TYPE, transforms=transforms)


# --- the bridge ------------------------------------------------------------------------------


def topic_of(full_key: str) -> str:
    """The Foxglove topic of a key: the same name as in a session log."""
    return "/" + full_key


class FoxgloveBridge:
    """Forwards one cell (or every cell, '*') to a Foxglove WebSocket server.

    `server_factory` and `channel_factory` exist so tests can look inside without a network.
    """

    def __init__(
        self,
        wire: Wire,
        cell: str,
        config: FoxgloveConfig,
        urdf_path: Path,
        *,
        port: int | None = None,
        host: str | None = None,
        server_factory: Callable[..., Any] | None = None,
        channel_factory: Callable[[str, str], Any] | None = None,
    ):
        import foxglove

        self.config = config
        self.cell = cell
        self.wire = wire
        self.urdf_path = urdf_path
        try:
            self.urdf_text = urdf_path.read_text()
        except OSError as exc:
            raise BridgeError(f"{urdf_path}: cannot read the URDF: {exc.strerror or exc}") from exc
        self.joints = parse_urdf_joints(self.urdf_text, str(urdf_path))
        self.context = foxglove.Context()
        self.lock = threading.Lock()
        self.channels: dict[str, Any] = {}
        self.forwarded = 0
        self.last_tf_s = 0.0
        self.stop_event = threading.Event()
        self._channel_factory = channel_factory or self._sdk_channel
        start = server_factory or foxglove.start_server
        where = f"{host or config.host}:{config.port if port is None else port}"
        try:   # the SDK's server on a private loopback port, behind the door that clients reach
            self.server = start(name=f"foldcell {cell}", host="127.0.0.1", port=0, context=self.context,
                                asset_handler=self._asset)
        except Exception as exc:  # the SDK raises its own error type
            raise BridgeError(f"cannot start the Foxglove server: {exc}") from exc
        try:
            self.door = SubprotocolProxy(host or config.host, config.port if port is None else port,
                                         int(self.server.port))
        except OSError as exc:
            self.server.stop()
            raise BridgeError(f"cannot start the Foxglove server on {where}: {exc.strerror or exc}") from exc
        self.description = threading.Thread(target=self._send_description, name="foxglove-urdf", daemon=True)
        self.description.start()
        for spec in KEYS:
            if spec.kind == "pub":
                wire.subscribe_raw(
                    f"{ROOT}/{cell}/{spec.pattern}",
                    self._on_raw,
                    drop=spec.drop_when_congested,
                    name=f"foxglove:{spec.pattern}",
                )

    @property
    def port(self) -> int:
        return self.door.port

    def _sdk_channel(self, topic: str, type_name: str) -> Any:
        import foxglove

        schema = foxglove.Schema(name=type_name, encoding="ros2msg", data=messages.msgdef(type_name).encode())
        return foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=self.context)

    def _channel(self, topic: str, type_name: str) -> Any:
        with self.lock:
            ch = self.channels.get(topic)
            if ch is None:
                ch = self.channels[topic] = self._channel_factory(topic, type_name)
            return ch

    def _asset(self, uri: str) -> bytes | None:
        """Serve the URDF (the only asset: its shapes are primitives) to the 3D panel."""
        if uri.endswith(self.urdf_path.name):
            return self.urdf_text.encode()
        return None

    def _send_description(self) -> None:
        payload = messages.encode(STRING_TYPE, messages.new(STRING_TYPE, data=self.urdf_text))
        channel = self._channel(self.config.robot_description_topic, STRING_TYPE)
        while True:
            channel.log(payload, log_time=time.time_ns())
            tf = messages.encode(TF_TYPE, tf_message(self.joints, {}, time.time_ns()))
            if self.last_tf_s == 0.0:  # no joint state yet: show the robot at zero
                self._channel(self.config.tf_topic, TF_TYPE).log(tf, log_time=time.time_ns())
            if self.stop_event.wait(self.config.description_period_s):
                return

    def _on_raw(self, raw: RawSample) -> None:
        if raw.is_delete:
            return
        try:
            type_name = type_for_full_key(raw.key)
            cell, rel = split_key(raw.key)
        except WireError as err:
            log.warning("not forwarded: %s", err)
            return
        log_time = raw.stamp_ns or raw.receive_ns
        self._channel(topic_of(raw.key), type_name).log(raw.payload, log_time=log_time)
        with self.lock:
            self.forwarded += 1
        if rel == JOINT_STATES:
            now = time.monotonic()
            if now - self.last_tf_s >= 1.0 / self.config.tf_rate_hz:
                self.last_tf_s = now
                self._send_tf(raw, log_time)
        elif rel == OBSERVATION:
            self._send_annotations(raw, cell, log_time)

    def _send_tf(self, raw: RawSample, log_time: int) -> None:
        try:
            js = messages.decode("sensor_msgs/msg/JointState", raw.payload, raw.key)
        except WireError as err:
            log.warning("no frames from a bad joint state: %s", err)
            return
        positions = {n: float(p) for n, p in zip(js.name, js.position, strict=False)}
        tf = tf_message(self.joints, positions, messages.message_stamp_ns(js) or log_time)
        self._channel(self.config.tf_topic, TF_TYPE).log(messages.encode(TF_TYPE, tf), log_time=log_time)

    def _send_annotations(self, raw: RawSample, cell: str, log_time: int) -> None:
        try:
            obs = messages.decode("foldcell_msgs/msg/GarmentObservation", raw.payload, raw.key)
        except WireError as err:
            log.warning("no annotations from a bad observation: %s", err)
            return
        ann = annotations_from_observation(obs, self.config.style)
        topic = topic_of(f"{ROOT}/{cell}/{self.config.annotations_suffix}")
        self._channel(topic, ANNOTATIONS_TYPE).log(messages.encode(ANNOTATIONS_TYPE, ann), log_time=log_time)

    def close(self) -> None:
        self.stop_event.set()
        self.description.join(2.0)
        self.door.close()
        try:
            self.server.stop()
        except Exception:
            log.debug("server stop failed", exc_info=True)


# --- a session log prepared for Foxglove -----------------------------------------------------


def export_for_foxglove(
    src: Path,
    dst: Path,
    config: FoxgloveConfig,
    urdf_path: Path,
    progress: Callable[[int], None] | None = None,
) -> dict[str, int]:
    """Copy a session log, adding what the live bridge adds: the URDF, link frames at the joint
    states (at most `tf_rate_hz`), and the matched polygon of every observation as ImageAnnotations.

    A file cut short by a crash is read up to its last complete chunk. Returns counts written.
    """
    from drivers.sessions.mcap.writer import SessionWriter
    from drivers.sessions.replay import Selection, open_session, select

    try:
        urdf_text = urdf_path.read_text()
    except OSError as exc:
        raise BridgeError(f"{urdf_path}: cannot read the URDF: {exc.strerror or exc}") from exc
    joints = parse_urdf_joints(urdf_text, str(urdf_path))
    session = open_session(src)
    counts = {"messages": 0, "annotations": 0, "tf": 0}
    min_tf_gap_ns = round(1e9 / config.tf_rate_hz)
    last_tf = -min_tf_gap_ns
    try:
        with SessionWriter(dst, metadata={"foxglove_export_of": str(src)}) as out:

            def put(topic: str, type_name: str, msg: Any, log_ns: int) -> None:
                out.write(
                    topic,
                    type_name,
                    messages.msgdef(type_name),
                    messages.encode(type_name, msg),
                    log_ns,
                    log_ns,
                )

            put(
                config.robot_description_topic,
                STRING_TYPE,
                messages.new(STRING_TYPE, data=urdf_text),
                session.start_ns,
            )
            for m in select(session, Selection()):
                out.write(m.topic, m.type_name, m.msgdef, m.data, m.log_time_ns, m.publish_time_ns)
                counts["messages"] += 1
                if progress is not None:
                    progress(1)
                try:
                    cell, rel = split_key(m.topic.lstrip("/"))
                except WireError:
                    continue
                try:
                    if rel == JOINT_STATES and m.log_time_ns - last_tf >= min_tf_gap_ns:
                        js = messages.decode(m.type_name, m.data, m.topic)
                        positions = {n: float(p) for n, p in zip(js.name, js.position, strict=False)}
                        put(
                            config.tf_topic,
                            TF_TYPE,
                            tf_message(joints, positions, m.log_time_ns),
                            m.log_time_ns,
                        )
                        last_tf = m.log_time_ns
                        counts["tf"] += 1
                    elif rel == OBSERVATION:
                        obs = messages.decode(m.type_name, m.data, m.topic)
                        put(
                            topic_of(f"{ROOT}/{cell}/{config.annotations_suffix}"),
                            ANNOTATIONS_TYPE,
                            annotations_from_observation(obs, config.style),
                            m.log_time_ns,
                        )
                        counts["annotations"] += 1
                except WireError as err:
                    log.warning("nothing derived from a bad sample: %s", err)
    finally:
        session.close()
    return counts


# --- the layout ------------------------------------------------------------------------------


def default_layout(cell: str, config: FoxgloveConfig, joint_names: list[str]) -> str:
    """A Foxglove layout (JSON) for one cell: the image with the matched polygon, the robot in 3D,
    joint positions, the state machine's states, the controller status and the cell's log.
    `docs/foxglove_layout.json` is this for the default cell."""
    import foxglove.layouts as fl

    key = lambda rel: topic_of(f"{ROOT}/{cell}/{rel}")  # noqa: E731
    image = fl.ImagePanel(
        title="camera with the matched model",
        config=fl.ImageConfig(
            image_mode=fl.ImageModeConfig(
                image_topic=key("camera/image"),
                annotations={
                    key("perception/annotations"): fl.ImageAnnotationSettings(visible=True),
                    key(config.annotations_suffix): fl.ImageAnnotationSettings(visible=True),
                },
            )
        ),
    )
    robot = fl.ThreeDeePanel(
        title="cell",
        config=fl.ThreeDeeConfig(
            follow_tf="world",
            layers={
                "urdf": fl.BaseRendererUrdfLayerSettings(
                    layer_id="foxglove.Urdf",
                    label="cell URDF",
                    source_type="topic",
                    topic=config.robot_description_topic,
                    control_mode="jointStates",
                    joint_states_topic=key("controller/joint_states"),
                    display_mode="auto",
                )
            },
        ),
    )
    joints = fl.PlotPanel(
        title="joint positions (rad)",
        config=fl.PlotConfig(
            paths=[
                fl.PlotSeries(
                    value=f"{key('controller/joint_states')}.position[{i}]", label=name, enabled=True
                )
                for i, name in enumerate(joint_names)
            ]
        ),
    )
    states = fl.StateTransitionsPanel(
        title="cell state",
        config=fl.StateTransitionsConfig(
            paths=[
                fl.StateTransitionsSeries(value=f"{key('cell/state')}.state", label="state"),
                fl.StateTransitionsSeries(value=f"{key('cell/state')}.stage", label="stage"),
            ]
        ),
    )
    status = fl.RawMessagesPanel(
        title="controller status", config=fl.RawMessagesConfig(topic_path=key("controller/status"))
    )
    def column(top: fl.BasePanel, bottom: fl.BasePanel, top_share: int) -> fl.SplitItem:
        """A layout column: `top` over `bottom`, the top `top_share` times as tall."""
        return fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(proportion=top_share, content=top), fl.SplitItem(proportion=1, content=bottom)]))

    logs = fl.LogPanel(title="cell log", config=fl.LogConfig(topic_to_render=key("cell/log")))
    layout = fl.Layout(
        content=fl.SplitContainer(
            direction="row",
            items=[column(image, states, 2), column(robot, joints, 2), column(status, logs, 1)],
        )
    )
    import json

    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"
