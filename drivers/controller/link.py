"""How a cell reaches its controller, chosen by URL (`controller:` in config/cell.yaml, `foldcell run
--controller`):

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
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

from drivers.controller.config import default_controller_config
from drivers.controller.interface import PROCESS_NAMES, Controller
from drivers.controller.motoros_client import MotorosController
from drivers.controller.publisher import StatePublisher
from drivers.controller.zenoh_client import ZenohController
from drivers.motoros.config import load_motoros_config
from drivers.motoros.messages import DIALECTS
from drivers.robot.config import RobotConfig, default_robot_config
from drivers.wire.tls import client_context
from drivers.wire.transport import Wire

log = logging.getLogger(__name__)


ZENOH = "zenoh"
MOTOROS_SCHEME = "motoros://"


@dataclass(frozen=True)
class ControllerAddress:
    """Where the cell's controller is: on the cell's Zenoh, or a MotoROS controller at host:port
    speaking `dialect` (port, dialect None: config/motoros.yaml's)."""

    kind: str                         # zenoh | motoros
    host: str = ""
    port: int | None = None
    dialect: str | None = None

    def __str__(self) -> str:
        if self.kind == ZENOH:
            return ZENOH
        return (f"{MOTOROS_SCHEME}{self.host}" + (f":{self.port}" if self.port is not None else "")
                + (f"?dialect={self.dialect}" if self.dialect is not None else ""))


def controller_address(url: str) -> ControllerAddress:
    """`zenoh` or `motoros://HOST[:PORT][?dialect=upstream|clopema]`; ValueError with the reason
    otherwise."""
    if url == ZENOH:
        return ControllerAddress(ZENOH)
    if not url.startswith(MOTOROS_SCHEME):
        raise ValueError(f"must be {ZENOH} or {MOTOROS_SCHEME}HOST[:PORT][?dialect=D], got {url!r}")
    where, question, query = url[len(MOTOROS_SCHEME):].partition("?")
    dialect = None
    if question:
        name, equals, value = query.partition("=")
        if name != "dialect" or not equals:
            raise ValueError(f"{url!r}: the only option is ?dialect={'|'.join(DIALECTS)}, got {query!r}")
        if value not in DIALECTS:
            raise ValueError(f"{url!r}: dialect must be one of {', '.join(DIALECTS)}, got {value!r}")
        dialect = value
    host, colon, port = where.rpartition(":")
    if not colon:
        host, port = port, ""
    host = host.strip("[]")
    if not host or "/" in host:
        raise ValueError(f"{url!r}: HOST missing (expected {MOTOROS_SCHEME}HOST[:PORT])")
    if colon and not (port.isdigit() and 1 <= int(port) <= 65534):
        raise ValueError(f"{url!r}: PORT must be a number 1..65534 (the state port is PORT + 1), "
                         f"got {port!r}")
    return ControllerAddress("motoros", host, int(port) if colon else None, dialect)


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
    """`MotorosController` whose state and grips go on the cell's Zenoh (`StatePublisher`)."""

    def __init__(self, wire: Wire, host: str, port: int | None, dialect: str | None,
                 robot_config: RobotConfig):
        settings = wire.settings
        tls = (client_context(settings.security, settings.role, settings.security_source)
               if settings.security else None)
        super().__init__(host, port, dialect, robot_config=robot_config, motoros_config=load_motoros_config(),
                         tls=tls)
        self.publisher = StatePublisher(wire, robot_config, default_controller_config())
        self.add_state_listener(self.publisher.report)

    def grip(self, arm: str, closed: bool) -> None:
        super().grip(arm, closed)
        self.publisher.gripped(arm, closed, self.joint_state().positions)


class MotorosLink(ControllerLink):
    def __init__(self, wire: Wire, host: str, port: int | None, dialect: str | None = None):
        robot_config = default_robot_config()
        self.controller = self.motoros = PublishingMotorosController(wire, host, port, dialect, robot_config)
        self.where = f"MotoROS ({self.motoros.dialect.name}) at {host}:{self.motoros.port}"

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

    def close(self) -> None:
        self.motoros.disconnect()
        self.motoros.publisher.close()


def controller_link(url: str, wire: Wire, process_name: str) -> ControllerLink:
    """The link to the controller at `url` (`zenoh` or `motoros://HOST[:PORT][?dialect=D]`)."""
    address = controller_address(url)
    if address.kind == ZENOH:
        return ZenohLink(wire, process_name)
    return MotorosLink(wire, address.host, address.port, address.dialect)
