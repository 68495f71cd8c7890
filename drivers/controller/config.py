"""`config/controller.yaml` loaded into a frozen dataclass."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from drivers.common.configfile import config_dir, load_yaml
from drivers.robot.config import CONTROLLER_ROLES


@dataclass(frozen=True)
class ControllerConfig:
    """What a controller front does and what its clients expect of it. Units: s, Hz, rad, m."""

    interpolation_period: float = 0.004
    feedback_rate: float = 250.0
    status_rate: float = 10.0
    start_tolerance: float = 0.003
    goal_tolerance: float = 0.001
    tracking_tolerance: float = 0.001
    limit_tolerance: float = 1e-6
    max_points: int = 200
    queue_size: int = 4
    reply_timeout: float = 2.0
    time_scale: float = 1.0
    groups: tuple[tuple[str, str], ...] = (("R1", "master"), ("R2", "slave"), ("B1", "master"))
    stop_acceleration_fraction: float = 0.9
    link_stall_timeout: float = 5.0
    link_reset_wait: float = 0.5
    lease_required: bool = True
    lease_silence_timeout: float = 3.0
    move_to_limit_fraction: float = 0.95
    gripper_open_width: float = 0.08
    gripper_rest_period: float = 1.0

    @property
    def group_owners(self) -> dict[str, str]:
        """Group name -> `master` or `slave`."""
        return dict(self.groups)


_TOP = {"interpolation_period", "feedback_rate", "status_rate", "start_tolerance", "goal_tolerance",
        "tracking_tolerance", "limit_tolerance", "max_points", "queue_size", "reply_timeout", "time_scale",
        "groups", "stop", "link", "lease", "move_to", "gripper",
        "server"}  # server: read by drivers/emulator/node


def load_controller_config(path: str | Path | None = None) -> ControllerConfig:
    """Read and validate `config/controller.yaml` (or `path`); errors name file, field and reason."""
    path = Path(path) if path else config_dir() / "controller.yaml"
    f = load_yaml(path)
    f.reject_unknown(_TOP)
    groups = f.sub("groups")
    owners = tuple((name, groups.str(name, choices=CONTROLLER_ROLES)) for name in groups.keys())  # noqa: SIM118 - Fields, not a dict
    if not owners:
        raise f.error("groups", "must name at least one group")
    stop, link, lease, move, gripper = (f.sub("stop"), f.sub("link"), f.sub("lease"), f.sub("move_to"),
                                        f.sub("gripper"))
    stop.reject_unknown({"acceleration_fraction"})
    link.reject_unknown({"stall_timeout", "reset_wait"})
    lease.reject_unknown({"required", "silence_timeout"})
    move.reject_unknown({"limit_fraction"})
    gripper.reject_unknown({"open_width", "rest_period"})
    return ControllerConfig(
        interpolation_period=f.float("interpolation_period", positive=True),
        feedback_rate=f.float("feedback_rate", positive=True),
        status_rate=f.float("status_rate", positive=True),
        start_tolerance=f.float("start_tolerance", positive=True),
        goal_tolerance=f.float("goal_tolerance", positive=True),
        tracking_tolerance=f.float("tracking_tolerance", positive=True),
        limit_tolerance=f.float("limit_tolerance", min=0.0, max=0.1),
        max_points=f.int("max_points", min=2),
        queue_size=f.int("queue_size", min=1),
        reply_timeout=f.float("reply_timeout", positive=True),
        time_scale=f.float("time_scale", positive=True),
        groups=owners,
        stop_acceleration_fraction=stop.float("acceleration_fraction", positive=True, max=1.0),
        link_stall_timeout=link.float("stall_timeout", positive=True),
        link_reset_wait=link.float("reset_wait", positive=True),
        lease_required=lease.bool("required"),
        lease_silence_timeout=lease.float("silence_timeout", positive=True),
        move_to_limit_fraction=move.float("limit_fraction", positive=True, max=1.0),
        gripper_open_width=gripper.float("open_width", min=0.0),
        gripper_rest_period=gripper.float("rest_period", positive=True),
    )


@lru_cache(maxsize=1)
def default_controller_config() -> ControllerConfig:
    return load_controller_config()
