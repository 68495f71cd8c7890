"""The monitor's parameters (config/replay_monitor.yaml, section `monitor`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_yaml

CONFIG_FILE = "replay_monitor.yaml"
CELL_COMMANDS = ("pause", "resume", "abort")  # what the monitor's keys may ask of the watched cell


@dataclass(frozen=True)
class MonitorConfig:
    refresh_hz: float
    rate_window_s: float
    stale_after_s: float
    max_errors: int
    max_states: int
    gone_keep_s: float
    max_gone: int
    error_log_level: int
    once_listen_s: float
    joint_warn_fraction: float
    observer_prefixes: tuple[str, ...]
    replay_prefixes: tuple[str, ...]
    transient_prefixes: tuple[str, ...]
    command_keys: dict[str, str]  # key -> the cell command it asks for (pause, resume, abort)
    confirm_keys: tuple[str, ...]
    quit_keys: tuple[str, ...]
    command_timeout_s: float


def monitor_config_from_fields(f: Fields) -> MonitorConfig:
    f.reject_unknown(
        {
            "refresh_hz",
            "rate_window_s",
            "stale_after_s",
            "max_errors",
            "max_states",
            "gone_keep_s",
            "max_gone",
            "error_log_level",
            "once_listen_s",
            "joint_warn_fraction",
            "observer_prefixes",
            "replay_prefixes",
            "transient_prefixes",
            "command_keys",
            "confirm_keys",
            "quit_keys",
            "command_timeout_s",
        }
    )
    keys = f.sub("command_keys")
    keys.reject_unknown(set(CELL_COMMANDS))
    command_keys = {keys.str(command): command for command in CELL_COMMANDS}
    if len(command_keys) != len(CELL_COMMANDS):
        raise f.error("command_keys", "each command needs a key of its own")
    return MonitorConfig(
        refresh_hz=f.float("refresh_hz", min=0.1, max=60.0),
        rate_window_s=f.float("rate_window_s", min=0.1),
        stale_after_s=f.float("stale_after_s", min=0.0),
        max_errors=f.int("max_errors", min=1),
        max_states=f.int("max_states", min=1),
        gone_keep_s=f.float("gone_keep_s", min=0.0),
        max_gone=f.int("max_gone", min=0),
        error_log_level=f.int("error_log_level", min=0),
        once_listen_s=f.float("once_listen_s", min=0.0),
        joint_warn_fraction=f.float("joint_warn_fraction", min=0.0, max=1.0),
        observer_prefixes=f.strs("observer_prefixes"),
        replay_prefixes=f.strs("replay_prefixes"),
        transient_prefixes=f.strs("transient_prefixes"),
        command_keys=command_keys,
        confirm_keys=f.strs("confirm_keys"),
        quit_keys=f.strs("quit_keys"),
        command_timeout_s=f.float("command_timeout_s", positive=True),
    )


def load_monitor_config(path: str | Path | None = None) -> MonitorConfig:
    return monitor_config_from_fields(
        load_yaml(Path(path) if path else config_dir() / CONFIG_FILE).sub("monitor")
    )
