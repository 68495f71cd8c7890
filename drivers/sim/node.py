"""The simulated world's part of the camera process: the world follows the emulated grippers
(`controller/gripper/<arm>`), a wrist camera follows the arm (`controller/joint_states`), and the
world's ground truth goes to `sim/truth` on every change and every `truth_period_s`. The physics world
runs in robot time: the controller's wall-clock stamps are turned into it by the time base its
`controller/status` states, so at any time scale the cloth sees the path's robot-time spacing.

The camera itself (`camera/capture`, images, info, pose) is served by `drivers.camera.node.CameraNode`
on the same `SimCamera`.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import numpy as np

from drivers.common.scheduling import load_priorities, set_thread_nice
from drivers.robot.kinematics import CellKinematics
from drivers.sim.camera import SimCamera
from drivers.sim.player import tcp_positions
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.timebase import TimeBase, timebase_of
from drivers.wire.transport import RawSample, Wire, decode_sample

log = logging.getLogger(__name__)

SIMULATE_PERIOD_S = 0.1   # the physics world catches up at least this often while cloth is held
JOINTS_BATCH_S = 0.02     # the joint states (250 a second) are handled in batches at most this far apart
JOINTS_BUFFER = 1024      # joint states kept between two batches: 4 s of them


class SimWorldNode:
    """Drives the world of `camera` from the wire and publishes its ground truth."""

    def __init__(self, wire: Wire, camera: SimCamera, truth_period_s: float):
        self.camera = camera
        self.world = camera.scene()
        self.truth_period_s = truth_period_s
        self.truth_pub = wire.publisher("sim/truth")
        self.gripper_closed: dict[str, bool] = {}
        self.last_event = "start"
        self.stop = threading.Event()
        assert self.world.camera is not None
        self.camera_config = self.world.camera.config
        self.kinematics: CellKinematics | None = None
        self.physics = self.world.cloth is not None
        self.timebase: TimeBase | None = None  # the controller's, from its status
        self.wrist = camera.mount == "wrist"
        self._joints_content = b""   # the last joint state decoded, after its stamp
        self._tcps: dict[str, np.ndarray] = {}   # and the grippers' positions there
        self.joints = None
        if self.wrist or self.physics:
            # a wrist camera's pose and the grippers' path follow the joint states (FK), read in batches
            self.kinematics = CellKinematics()
            self.joints = wire.buffer("controller/joint_states", JOINTS_BUFFER)
        self._truth: tuple[tuple, bytes] | None = None   # the world's state and its encoded truth
        if self.physics:
            wire.subscribe("controller/status", self._on_status)
        self.simulate = threading.Event()
        wire.subscribe("controller/gripper/*", self._on_gripper)
        self.ticker = threading.Thread(target=self._tick, name="sim-truth", daemon=True)
        self.follower = threading.Thread(target=self._follow_joints, name="sim-joints", daemon=True)

    def start(self) -> None:
        self.ticker.start()
        if self.joints is not None:
            self.follower.start()

    def close(self) -> None:
        self.stop.set()
        self.ticker.join(2.0)
        if self.follower.is_alive():
            self.follower.join(2.0)

    def _follow_joints(self) -> None:
        assert self.joints is not None
        while not self.stop.wait(JOINTS_BATCH_S):
            for raw in self.joints.drain():
                self._on_joints(raw)

    def _on_status(self, _key: str, msg: Any, _raw: Any) -> None:
        self.timebase = timebase_of(msg)

    def _robot_time(self, msg: Any) -> float | None:
        """Robot time (s) of a controller message's stamp; None before the controller's status."""
        timebase = self.timebase
        return None if timebase is None else timebase.robot(messages.message_stamp_ns(msg) or 0) * 1e-9

    def _on_gripper(self, _key: str, msg: Any, _raw: Any) -> None:
        arm, closed = msg.arm, bool(msg.closed)
        robot_time = self._robot_time(msg) if self.physics else None
        if self.physics and robot_time is None:
            log.warning("gripper %s heard before the controller's status: its time is unknown", arm)
            return
        if self.gripper_closed.get(arm) == closed:
            if robot_time is not None:
                self.world.gripper_heard(arm, robot_time)
            return  # the pose moved, the gripper did not change: nothing happens to the cloth
        self.gripper_closed[arm] = closed
        position = msg.tcp_pose.position
        tcp = np.array([position.x, position.y, position.z])
        if robot_time is not None:
            # recorded without the camera's lock (a capture may be waiting on the simulation);
            # the ticker simulates it
            self.world.gripper_event(arm, closed, tcp, robot_time=robot_time)
            self.last_event = f"{'grasp' if closed else 'release'} {arm}"
            self.simulate.set()
            return
        result = self.camera.gripper_event(arm, closed, tcp)
        event = f"{'grasp' if closed else 'release'} {arm}"
        if result is not None:
            event += " (cloth)" if result.grasped else " (nothing)"
        with self.camera.lock:
            if self.world.history and not self.world.holding():
                record = self.world.history[-1]
                event = f"fold {len(self.world.history)}" + (" crumpled" if record.crumpled else "")
            self.last_event = event
        log.info("gripper %s %s: %s", arm, "closed" if closed else "open", event)
        self._publish_truth()

    def _on_joints(self, raw: RawSample) -> None:
        assert self.kinematics is not None
        if raw.is_delete:
            return
        stamp_ns = messages.leading_stamp_ns(raw.payload)
        content = raw.payload[messages.HEADER_STAMP_END:]
        # at rest the arms repeat their sample but for the stamp: nothing to decode
        if stamp_ns is None or content != self._joints_content:
            try:
                msg = decode_sample(raw)
            except WireError as err:
                log.warning("dropped a bad joint state: %s", err)
                return
            joints = np.asarray(msg.position, dtype=float)
            stamp_ns = messages.stamp_to_ns(msg.header.stamp)
            self._joints_content = content
            self._tcps = tcp_positions(self.kinematics, joints)
            if self.wrist:
                parent = self.kinematics.fk(joints, self.camera_config.wrist_parent_frame)
                self.camera.camera_pose_world = parent @ self.camera_config.wrist_pose_in_parent
        timebase = self.timebase
        if self.physics and timebase is not None:
            # recorded at rest too: a grasp heard late needs the path since
            self.world.gripper_motion(timebase.robot(stamp_ns) * 1e-9, self._tcps)
        elif not self.physics:
            # the geometric world keeps only how high a held point went (a pull never lifts it)
            self.world.gripper_motion(0.0, self._tcps)

    def _publish_truth(self) -> None:
        world = self.world
        assert world.camera is not None
        state = self._world_state()
        if self._truth is not None and self._truth[0] == state:
            # nothing happened to the world since: the same truth, stamped now
            self.truth_pub.put_encoded(messages.restamp(self._truth[1], time.time_ns()))
            return
        with self.camera.lock:
            names, points = world.truth_polygon()
            flat_names, flat_points = world.flat_polygon()
            flat_outline = world.garment.outline
            silhouette = world.silhouette()
            iou = world.silhouette_iou() if world.history else 1.0
            holding = sorted(world.holding())
            event = self.last_event
            folds = len(world.history)
            vertices = world.landmark_vertices()
            layers = world.layer_count()
        pixels = world.camera.table_to_pixel(points)
        landmarks = _landmarks(names, points, pixels)
        flat_landmarks = _landmarks(flat_names, flat_points, world.camera.table_to_pixel(flat_points))
        outline, flat_outline_msg = _points(silhouette), _points(flat_outline)
        truth = messages.new(
            "foldcell_msgs/msg/SimTruth", header=messages.header(frame_id="table"),
            category=world.category, folds_applied=folds, landmarks=landmarks, silhouette_table=outline,
            flat_landmarks=flat_landmarks, flat_outline_table=flat_outline_msg,
            iou_vs_ideal=float(iou), holding=holding, last_event=event, layers=layers,
            landmark_vertex_names=list(vertices),
            landmark_vertices=[messages.new("geometry_msgs/msg/Point", x=float(x), y=float(y), z=float(z))
                               for x, y, z in vertices.values()])
        payload = messages.encode("foldcell_msgs/msg/SimTruth", truth)
        self._truth = (state, payload)
        self.truth_pub.put_encoded(payload, messages.message_stamp_ns(truth))

    def _world_state(self) -> tuple:
        """What the ground truth depends on: its folds, its grippers, its last event and, in the physics
        world, how far the cloth has been simulated."""
        with self.camera.lock:
            cloth = self.world.cloth
            simulated = None if cloth is None else float(cloth.world.data.time)
            return (len(self.world.history), tuple(sorted(self.world.holding())), self.last_event, simulated)

    def _catch_up(self) -> None:
        """Physics world: simulate what the grippers did so far (a capture waits on the lock)."""
        with self.camera.lock:
            records = self.world.catch_up()
            if records:
                self.last_event = f"fold {len(self.world.history)}"
        if records:
            self._publish_truth()

    def _tick(self) -> None:
        if self.physics:
            # the cloth may lag, the controllers' loops and the links' keep-alives may not
            set_thread_nice(load_priorities().simulation, "the simulating thread")
        last = 0.0
        while not self.stop.is_set():
            if self.physics:
                self._catch_up()
            now = time.monotonic()
            if now - last >= self.truth_period_s:
                self._publish_truth()
                last = now
            if self.simulate.wait(min(self.truth_period_s, SIMULATE_PERIOD_S)):
                self.simulate.clear()


def _landmarks(names: list[str], points: np.ndarray, pixels: np.ndarray) -> list[Any]:
    return [messages.new("foldcell_msgs/msg/Landmark", name=name, x_px=float(u), y_px=float(v),
                         x_table=float(x), y_table=float(y))
            for name, (u, v), (x, y) in zip(names, pixels, points, strict=True)]


def _points(xy: np.ndarray) -> list[Any]:
    return [messages.new("geometry_msgs/msg/Point", x=float(x), y=float(y), z=0.0) for x, y in xy]
