"""How the cell reaches its controller (`controller:` in config/cell.yaml, `foldcell run --controller`):

- `zenoh`: the emulator (`foldcell controller serve`) or an adapter on the cell's Zenoh; it publishes
  the robot's `controller/*` topics and announces its processes' liveliness itself.
- `motoros://HOST[:PORT][?dialect=upstream|clopema]`: a DX100's MotoROS 1 (or `controller serve
  --motoros`) over TCP, in the dialect of config/motoros.yaml unless named. Nothing of it
  is on Zenoh, so the cell publishes what it reads there: `controller/joint_states`,
  `controller/status` and `controller/gripper/<arm>` (the emulator's message types, stamped with the
  wall clock as a ROS driver stamps them: a real robot's time is wall time), and the loss of its
  connection stands for the loss of its process. A secured cell (`--security`) reaches it over TLS
  with the cell's certificate.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Callable

import numpy as np

from cell.config import ZENOH, controller_address
from drivers.controller import codec
from drivers.controller.interface import Controller, ControllerStatus, JointFeedback
from drivers.controller.zenoh_client import ZenohController
from drivers.emulator.node import PROCESS_NAMES, load_server_config
from drivers.motoros.client import MotorosController
from drivers.motoros.config import load_motoros_config
from drivers.robot.config import RobotConfig, default_robot_config
from drivers.robot.kinematics import CellKinematics
from drivers.wire import messages
from drivers.wire.tls import client_context
from drivers.wire.transport import Lane, Wire

log = logging.getLogger(__name__)


class ControllerLink(ABC):
    """The cell's controller and what the daemon needs of the link to it."""

    controller: Controller
    where: str  # for the log and fault reasons

    def required(self, processes: tuple[str, ...]) -> tuple[str, ...]:
        """The processes whose liveliness the cell watches, of the configured ones."""
        return processes

    @abstractmethod
    def on_lost(self, listener: Callable[[str], None]) -> None:
        """Call `listener(reason)` when the controller is lost otherwise than by a liveliness token."""

    @abstractmethod
    def start(self) -> None:
        """Begin what the link does on its own (the daemon has started)."""

    @abstractmethod
    def close(self) -> None:
        """Release the lease and close the link."""


class ZenohLink(ControllerLink):
    def __init__(self, wire: Wire, process_name: str):
        self.controller = ZenohController(wire, process_name)
        self.where = "zenoh"

    def on_lost(self, listener: Callable[[str], None]) -> None:
        """Its processes' liveliness tokens tell the daemon."""

    def start(self) -> None:
        """It connects on the first command that needs it."""

    def close(self) -> None:
        self.controller.disconnect()


class PublishingMotorosController(MotorosController):
    """`MotorosController` that publishes the grippers on `controller/gripper/<arm>` as the emulator does
    (MotoROS reports no I/O in its state stream: the cell says what it wrote): every gripper it has set,
    at each grip and at the status rate while the arms move, so a listener knows each gripper's state up
    to then (the simulated world waits for that before it moves held cloth on)."""

    def __init__(self, wire: Wire, host: str, port: int | None, dialect: str | None,
                 robot_config: RobotConfig):
        settings = wire.settings
        tls = (client_context(settings.security, settings.role, settings.security_source)
               if settings.security else None)
        super().__init__(host, port, dialect, robot_config=robot_config, motoros_config=load_motoros_config(),
                         tls=tls)
        self.gripper_pubs = {arm.name: wire.publisher(f"controller/gripper/{arm.name}")
                             for arm in robot_config.arms}
        # (publisher, message), put in order by a thread of their own: a reliable put may wait, the
        # MotoROS state thread may not
        self.gripper_lane = Lane("controller/gripper", lambda item: item[0].put(item[1]))
        self.kinematics: CellKinematics | None = None
        self.open_width = load_server_config().gripper_open_width  # reported as the emulator does
        self.gripper_lock = threading.Lock()    # grips on the cell's thread, state bursts on the link's
        self.gripper_closed: dict[str, bool] = {}   # the grippers this cell has set
        self.grippers_published_at = -math.inf      # monotonic s
        self.grippers_published_from: np.ndarray | None = None

    def grip(self, arm: str, closed: bool) -> None:
        super().grip(arm, closed)
        with self.gripper_lock:
            self.gripper_closed[arm] = closed
        self.publish_grippers(self.joint_state().positions, time.time_ns(), changed=True)

    def publish_grippers(self, positions: np.ndarray, stamp_ns: int, changed: bool = False) -> None:
        """The grippers' states with their TCP poses at joints `positions`: now if `changed`, else if the
        status period has passed and the arms have moved since the last time."""
        with self.gripper_lock:
            now = time.monotonic()
            moved = self.grippers_published_from is None or not np.array_equal(
                positions, self.grippers_published_from)
            due = now - self.grippers_published_at >= 1.0 / self.config.status_rate
            if not self.gripper_closed or not (changed or (due and moved)):
                return
            if self.kinematics is None:  # built on first use: pinocchio takes a while to load the model
                self.kinematics = CellKinematics(self.robot_config)
            poses = self.kinematics.tcp_poses(positions)
            for arm, closed in self.gripper_closed.items():
                opening = 0.0 if closed else self.open_width
                self.gripper_lane.push((self.gripper_pubs[arm],
                                        codec.gripper_msg(arm, closed, opening, poses[arm], stamp_ns)))
            self.grippers_published_at, self.grippers_published_from = now, positions.copy()


class MotorosLink(ControllerLink):
    def __init__(self, wire: Wire, host: str, port: int | None, dialect: str | None = None):
        robot_config = default_robot_config()
        self.controller = self.motoros = PublishingMotorosController(wire, host, port, dialect, robot_config)
        self.where = f"MotoROS ({self.motoros.dialect.name}) at {host}:{self.motoros.port}"
        self.joint_state_pub = wire.publisher("controller/joint_states")
        self.status_pub = wire.publisher("controller/status")
        self.joint_state_msg = codec.joint_state_msg(robot_config.joint_names)
        self.group_joints = {g.name: tuple(g.joints) for g in robot_config.groups}
        self.motoros.add_state_listener(self._publish)

    def required(self, processes: tuple[str, ...]) -> tuple[str, ...]:
        emulator = set(PROCESS_NAMES.values())
        return tuple(p for p in processes if p not in emulator)

    def on_lost(self, listener: Callable[[str], None]) -> None:
        self.motoros.add_loss_listener(listener)

    def start(self) -> None:
        """Connect now, so the robot is on Zenoh from the start; if it is not there yet, the first
        command that needs it connects."""
        try:
            self.motoros.connect()
            log.info("controller: %s", self.where)
        except Exception as exc:
            log.warning("controller %s not reached yet: %s", self.where, exc)

    def _publish(self, status: ControllerStatus, feedback: JointFeedback) -> None:
        stamp_ns = time.time_ns()
        msg = self.joint_state_msg
        msg.header.stamp = messages.stamp_from_ns(stamp_ns)
        msg.position[:] = feedback.positions
        msg.velocity[:] = feedback.velocities
        self.joint_state_pub.put(msg)
        self.status_pub.put(codec.status_msg(status, stamp_ns, status.time_scale,
                                             group_joints=self.group_joints))
        self.motoros.publish_grippers(feedback.positions, stamp_ns)

    def close(self) -> None:
        self.motoros.disconnect()
        self.motoros.gripper_lane.close(1.0)


def controller_link(url: str, wire: Wire, process_name: str) -> ControllerLink:
    """The link to the controller at `url` (`zenoh` or `motoros://HOST[:PORT][?dialect=D]`)."""
    address = controller_address(url)
    if address.kind == ZENOH:
        return ZenohLink(wire, process_name)
    return MotorosLink(wire, address.host, address.port, address.dialect)
