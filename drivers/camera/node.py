"""The camera process: answers `camera/capture`, publishes images, intrinsics and pose; the `sim`
source follows the emulated grippers (`controller/gripper/<arm>`) and publishes its ground truth."""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import cv2
import numpy as np

from drivers.camera.base import Camera, Frame
from drivers.camera.model import CameraInfo
from drivers.wire import messages
from drivers.wire.transport import RequestInfo, Wire

log = logging.getLogger(__name__)

PROCESS_NAME = "camera"


def camera_info_message(info: CameraInfo, stamp_ns: int) -> Any:
    return messages.new(
        "sensor_msgs/msg/CameraInfo", header=messages.header(stamp_ns, info.frame_id), height=info.height,
        width=info.width, distortion_model=info.distortion_model, d=list(info.d), k=list(info.k),
        r=list(info.r), p=list(info.p))


def pose_message(pose_4x4: np.ndarray, stamp_ns: int, frame_id: str = "world") -> Any:
    rot = pose_4x4[:3, :3]
    # rotation matrix -> quaternion (w, x, y, z), numerically safe branch by the largest diagonal term
    q = _quaternion(rot)
    return messages.from_dict("geometry_msgs/msg/PoseStamped", {
        "header": {"stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000},
                   "frame_id": frame_id},
        "pose": {"position": dict(zip("xyz", (float(v) for v in pose_4x4[:3, 3]))),
                 "orientation": {"w": q[0], "x": q[1], "y": q[2], "z": q[3]}},
    })


def _quaternion(r: np.ndarray) -> tuple[float, float, float, float]:
    trace = float(np.trace(r))
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s)
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s)
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s)
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    norm = float(np.linalg.norm(q))
    return tuple(float(v) / norm for v in q)  # type: ignore[return-value]


def png_of(frame: Frame) -> bytes:
    if frame.png is not None:
        return frame.png
    ok, data = cv2.imencode(".png", frame.image)
    if not ok:
        raise RuntimeError("PNG encoding failed")
    return data.tobytes()


class CameraNode:
    """Serves one camera on the wire. For a `SimCamera`, also drives its world from gripper states."""

    def __init__(self, wire: Wire, camera: Camera, info_period_s: float):
        self.wire = wire
        self.camera = camera
        self.info_period_s = info_period_s
        self.lock = threading.Lock()  # the world changes on gripper events while a capture renders
        self.image_pub = wire.publisher("camera/image")
        self.info_pub = wire.publisher("camera/info")
        self.pose_pub = wire.publisher("camera/pose")
        self.world = getattr(camera, "world", None)
        self.truth_pub = wire.publisher("sim/truth") if self.world is not None else None
        self.gripper_closed: dict[str, bool] = {}
        self.last_event = "start"
        self.last_info: CameraInfo | None = None
        self.stop = threading.Event()
        self.joint_positions: np.ndarray | None = None
        self.wrist = None
        if self.world is not None and self.world.camera.config.mount == "wrist":
            # the camera rides on the arm: its pose follows the joint states (FK of the parent frame)
            from drivers.robot.kinematics import CellKinematics
            self.wrist = CellKinematics()
            wire.subscribe("controller/joint_states", self._on_joints)
        wire.serve("camera/capture", self._on_capture)
        if self.world is not None:
            wire.subscribe("controller/gripper/*", self._on_gripper)
        self.ticker = threading.Thread(target=self._tick, name="camera-info", daemon=True)

    def start(self) -> None:
        self.ticker.start()

    def close(self) -> None:
        self.stop.set()
        self.ticker.join(2.0)

    # the world follows the emulated grippers
    def _on_gripper(self, _key: str, msg: Any, _raw: Any) -> None:
        arm = msg.arm
        if self.gripper_closed.get(arm) == bool(msg.closed):
            return  # the pose moved, the gripper did not change: nothing happens to the cloth
        self.gripper_closed[arm] = bool(msg.closed)
        p = msg.tcp_pose.position
        with self.lock:
            result = self.camera.gripper_event(arm, bool(msg.closed), np.array([p.x, p.y, p.z]))
            self.last_event = f"{'grasp' if msg.closed else 'release'} {arm}"
            if result is not None and hasattr(result, "grasped"):
                self.last_event += " (cloth)" if result.grasped else " (nothing)"
            if self.world.history and not self.world.holding():
                record = self.world.history[-1]
                self.last_event = f"fold {len(self.world.history)}" + (" crumpled" if record.crumpled else "")
        log.info("gripper %s %s: %s", arm, "closed" if msg.closed else "open", self.last_event)
        self._publish_truth()

    def _on_joints(self, _key: str, msg: Any, _raw: Any) -> None:
        self.joint_positions = np.asarray(msg.position, dtype=float)

    def _on_capture(self, _request: Any, _info: RequestInfo) -> Any:
        with self.lock:
            if self.wrist is not None:
                if self.joint_positions is None:
                    raise RuntimeError("wrist camera: no controller/joint_states yet, so no camera pose")
                cfg = self.world.camera.config
                parent = self.wrist.fk(self.joint_positions, cfg.wrist_parent_frame)
                self.camera.camera_pose_world = parent @ cfg.wrist_pose_in_parent
            frame = self.camera.capture()
        stamp_ns = int(frame.stamp * 1e9)
        msg = messages.new("sensor_msgs/msg/CompressedImage", header=messages.header(stamp_ns, frame.info.frame_id),
                           format="png", data=np.frombuffer(png_of(frame), dtype=np.uint8))
        if frame.info != self.last_info:  # before the image: a client maps the image with the info it has
            self.last_info = frame.info
            self._publish_info(frame.info, stamp_ns)
        self.image_pub.put(msg)
        return msg

    def _publish_info(self, info: CameraInfo, stamp_ns: int) -> None:
        self.info_pub.put(camera_info_message(info, stamp_ns))
        self.pose_pub.put(pose_message(np.array(info.pose_in_world).reshape(4, 4), stamp_ns))

    def _publish_truth(self) -> None:
        if self.truth_pub is None:
            return
        with self.lock:
            world = self.world
            names, pts = world.truth_polygon()
            px = world.camera.table_to_pixel(pts)
            silhouette = world.silhouette()
            iou = world.silhouette_iou() if world.history else 1.0
            holding = sorted(world.holding())
            event = self.last_event
            folds = len(world.history)
        landmarks = [messages.new("foldcell_msgs/msg/Landmark", name=n, x_px=float(u), y_px=float(v),
                                  x_table=float(x), y_table=float(y))
                     for n, (u, v), (x, y) in zip(names, px, pts)]
        outline = [messages.new("geometry_msgs/msg/Point", x=float(x), y=float(y), z=0.0) for x, y in silhouette]
        self.truth_pub.put(messages.new(
            "foldcell_msgs/msg/SimTruth", header=messages.header(frame_id="table"),
            category=world.category, folds_applied=folds, landmarks=landmarks, silhouette_table=outline,
            iou_vs_ideal=float(iou), holding=holding, last_event=event))

    def _tick(self) -> None:
        while not self.stop.wait(0 if self.last_info is None else self.info_period_s):
            info = self.last_info
            if info is None:
                try:
                    info = self.camera.current_info() if hasattr(self.camera, "current_info") else None
                except Exception:  # a device that is not ready yet: the next capture publishes it
                    info = None
                if info is None and self.world is not None:
                    info = self.world.camera.camera_info()
                if info is None:
                    self.stop.wait(self.info_period_s)
                    continue
                self.last_info = info
            self._publish_info(info, time.time_ns())
            self._publish_truth()
