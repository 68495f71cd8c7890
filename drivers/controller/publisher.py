"""A controller's state on the cell's Zenoh, as every controller front puts it: the emulator's node, and
the cell for a controller that is not on Zenoh itself (MotoROS).

`GripperPublisher` puts each arm's gripper on `controller/gripper/<arm>` with its TCP pose where the
arms stand: at once on a change, at the status rate while the arms move, and every `rest_period` at rest
(a client that came late, a restarted cell, learns which gripper is closed). Its puts go through a
`Lane`: a reliable put may wait on a congested link, the caller's loop may not.

`StatePublisher` puts any `Controller`'s joint states, status and grippers from its state reports.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from drivers.controller import codec
from drivers.controller.config import ControllerConfig
from drivers.controller.interface import ControllerStatus, JointFeedback
from drivers.controller.trajectory import FloatArray
from drivers.robot.config import RobotConfig
from drivers.robot.kinematics import CellKinematics
from drivers.wire import messages
from drivers.wire.transport import Lane, Wire

GripperMessage = tuple[str, Any]   # (arm, foldcell_msgs/GripperState)


class GripperPublisher:
    def __init__(self, wire: Wire, robot_config: RobotConfig, config: ControllerConfig,
                 kinematics: CellKinematics | None = None):
        self.robot_config = robot_config
        self.config = config
        self.kinematics = kinematics
        self.publishers = {arm.name: wire.publisher(f"controller/gripper/{arm.name}")
                           for arm in robot_config.arms}
        self.lane = Lane("controller/gripper", lambda item: self.publishers[item[0]].put(item[1]))
        self.said: dict[str, bool] = {}   # arm -> closed, as last published
        self.looked_at = -math.inf        # monotonic s the grippers were last looked at
        self.said_at = -math.inf          # ... and last published
        self.said_from: FloatArray | None = None   # the joints they were last published at

    def changes(self, states: dict[str, bool], position: Callable[[], FloatArray], stamp_ns: int,
                now: float) -> list[GripperMessage]:
        """Every arm's message, posed at `position()`, when a state in `states` (arm -> closed) differs
        from the last one published; none otherwise. The caller pushes them (`push`) outside its lock."""
        if all(self.said.get(arm) == closed for arm, closed in states.items()):
            return []
        return self._messages(states, position(), stamp_ns, now)

    def periodic(self, states: dict[str, bool], position: Callable[[], FloatArray], stamp_ns: int,
                 now: float) -> None:
        """Push every arm's message if a state changed, or the status period has passed and the arms
        have moved, or `rest_period` has passed at rest."""
        changed = any(self.said.get(arm) != closed for arm, closed in states.items())
        if not states or (not changed and now - self.looked_at < 1.0 / self.config.status_rate):
            return
        self.looked_at = now
        q = position()
        still = self.said_from is not None and np.array_equal(q, self.said_from)
        if not changed and still and now - self.said_at < self.config.gripper_rest_period:
            return
        self.push(self._messages(states, q, stamp_ns, now))

    def push(self, gripper_messages: list[GripperMessage]) -> None:
        for item in gripper_messages:
            self.lane.push(item)

    def _messages(self, states: dict[str, bool], q: FloatArray, stamp_ns: int,
                  now: float) -> list[GripperMessage]:
        if self.kinematics is None:  # built on first use: pinocchio takes a while to load the model
            self.kinematics = CellKinematics(self.robot_config)
        poses = self.kinematics.tcp_poses(q)
        self.said_from, self.said_at, self.looked_at = q.copy(), now, now
        out = []
        for arm, closed in states.items():
            opening = 0.0 if closed else self.config.gripper_open_width
            out.append((arm, codec.gripper_msg(arm, closed, opening, poses[arm], stamp_ns)))
            self.said[arm] = closed
        return out

    def close(self, timeout: float = 1.0) -> None:
        self.lane.close(timeout)


class StatePublisher:
    """`controller/joint_states`, `controller/status` and `controller/gripper/<arm>` from a controller's
    state reports (`report(status, feedback)`) and the grips it was told (`gripped`), stamped with the
    wall clock as a ROS driver stamps them: a real robot's time is wall time. A controller reports no
    I/O here (MotoROS has none in its state stream), so the grippers are the ones this side has set."""

    def __init__(self, wire: Wire, robot_config: RobotConfig, config: ControllerConfig):
        self.joint_state_pub = wire.publisher("controller/joint_states")
        self.status_pub = wire.publisher("controller/status")
        self.joint_state_msg = codec.joint_state_msg(robot_config.joint_names)
        self.group_joints = {g.name: tuple(g.joints) for g in robot_config.groups}
        self.grippers = GripperPublisher(wire, robot_config, config)
        self.lock = threading.Lock()   # grips on the caller's thread, reports on the link's
        self.closed: dict[str, bool] = {}   # the grippers set through this side
        self.position = np.zeros(len(robot_config.joint_names))

    def report(self, status: ControllerStatus, feedback: JointFeedback) -> None:
        stamp_ns = time.time_ns()
        msg = self.joint_state_msg
        msg.header.stamp = messages.stamp_from_ns(stamp_ns)
        msg.position[:] = feedback.positions
        msg.velocity[:] = feedback.velocities
        self.joint_state_pub.put(msg)
        self.status_pub.put(codec.status_msg(status, stamp_ns, status.time_scale,
                                             group_joints=self.group_joints))
        with self.lock:
            self.position = np.array(feedback.positions, dtype=float)
            self.grippers.periodic(dict(self.closed), lambda: self.position, stamp_ns, time.monotonic())

    def gripped(self, arm: str, closed: bool, positions: FloatArray) -> None:
        """`arm`'s gripper was set, the arms standing at `positions`: published at once."""
        with self.lock:
            self.closed[arm] = closed
            q = np.array(positions, dtype=float)
            self.grippers.push(self.grippers.changes(dict(self.closed), lambda: q, time.time_ns(),
                                                     time.monotonic()))

    def close(self) -> None:
        self.grippers.close()
