"""`config/controller.yaml` loaded into a frozen dataclass."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from drivers.common.configfile import config_dir, load_fields, load_yaml, rule
from drivers.robot.config import CONTROLLER_ROLES


@dataclass(frozen=True)
class ControllerConfig:
    """What a controller front does and what its clients expect of it. Units: s, Hz, rad, m. A field
    `under` a section is that section's key (`stop_acceleration_fraction`: `stop.acceleration_fraction`)."""

    interpolation_period: float = rule(positive=True)
    feedback_rate: float = rule(positive=True)
    status_rate: float = rule(positive=True)
    start_tolerance: float = rule(positive=True)
    goal_tolerance: float = rule(positive=True)
    tracking_tolerance: float = rule(positive=True)
    limit_tolerance: float = rule(min=0.0, max=0.1)
    max_points: int = rule(min=2)
    queue_size: int = rule(min=1)
    reply_timeout: float = rule(positive=True)
    time_scale: float = rule(positive=True)
    groups: tuple[tuple[str, str], ...] = rule()   # group name, master or slave (given by the loader)
    stop_acceleration_fraction: float = rule(positive=True, max=1.0, under="stop")
    link_stall_timeout: float = rule(positive=True, under="link")
    link_reset_wait: float = rule(positive=True, under="link")
    lease_required: bool = rule(under="lease")
    lease_silence_timeout: float = rule(positive=True, under="lease")
    move_to_limit_fraction: float = rule(positive=True, max=1.0, under="move_to")
    gripper_open_width: float = rule(min=0.0, under="gripper")
    gripper_rest_period: float = rule(positive=True, under="gripper")

    @property
    def group_owners(self) -> dict[str, str]:
        """Group name -> `master` or `slave`."""
        return dict(self.groups)


def load_controller_config(path: str | Path | None = None) -> ControllerConfig:
    """Read and validate `config/controller.yaml` (or `path`); errors name file, field and reason."""
    path = Path(path) if path else config_dir() / "controller.yaml"
    f = load_yaml(path)
    groups = f.sub("groups")
    owners = tuple((name, groups.str(name, choices=CONTROLLER_ROLES)) for name in groups.keys())  # noqa: SIM118 - Fields, not a dict
    if not owners:
        raise f.error("groups", "must name at least one group")
    return load_fields(ControllerConfig, f.without("server"), groups=owners)  # server: drivers/emulator/node


@lru_cache(maxsize=1)
def default_controller_config() -> ControllerConfig:
    return load_controller_config()
