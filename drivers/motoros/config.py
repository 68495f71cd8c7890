"""`config/motoros.yaml` loaded into a frozen dataclass."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import config_dir, load_yaml
from drivers.motoros.messages import DIALECTS

_FIELDS = {"port", "dialect", "state_period", "queue_increments", "motion_slots", "state_slots",
           "start_tolerance_pulses", "in_motion_lag_pulses", "pulses_per_radian", "max_point_time",
           "tool_count", "partial_frame_timeout", "io_slots", "gripper_outputs"}


@dataclass(frozen=True)
class MotorosConfig:
    """The MotoROS server's parameters. Units: s, rad, encoder pulses."""

    port: int = 50240
    dialect: str = "upstream"
    state_period: float = 0.025
    queue_increments: int = 200
    motion_slots: int = 1
    state_slots: int = 4
    start_tolerance_pulses: tuple[tuple[str, int], ...] = (("upstream", 30), ("clopema", 10))
    in_motion_lag_pulses: int = 30
    pulses_per_radian: float = 10000.0
    max_point_time: float = 14400.0
    tool_count: int = 64
    partial_frame_timeout: float = 0.2
    io_slots: int = 1
    gripper_outputs: tuple[tuple[str, int], ...] = (("r1", 10010), ("r2", 10011))

    def start_tolerance(self, dialect: str) -> float:
        """rad: the start tolerance of `dialect` in pulses, over the pulses per radian."""
        return dict(self.start_tolerance_pulses)[dialect] / self.pulses_per_radian


def load_motoros_config(path: str | Path | None = None) -> MotorosConfig:
    """Read and validate `config/motoros.yaml` (or `path`); errors name file, field and reason."""
    f = load_yaml(Path(path) if path else config_dir() / "motoros.yaml")
    f.reject_unknown(_FIELDS)
    grippers = f.sub("gripper_outputs")
    tolerances = f.sub("start_tolerance_pulses")
    tolerances.reject_unknown(set(DIALECTS))
    return MotorosConfig(
        port=f.int("port", min=1, max=65534),
        dialect=f.str("dialect", choices=tuple(DIALECTS)),
        state_period=f.float("state_period", positive=True),
        queue_increments=f.int("queue_increments", min=1),
        motion_slots=f.int("motion_slots", min=1),
        state_slots=f.int("state_slots", min=1),
        start_tolerance_pulses=tuple((name, tolerances.int(name, min=0)) for name in DIALECTS),
        in_motion_lag_pulses=f.int("in_motion_lag_pulses", min=0),
        pulses_per_radian=f.float("pulses_per_radian", positive=True),
        max_point_time=f.float("max_point_time", positive=True),
        tool_count=f.int("tool_count", min=1),
        partial_frame_timeout=f.float("partial_frame_timeout", positive=True),
        io_slots=f.int("io_slots", min=1),
        gripper_outputs=tuple((arm, grippers.int(arm, min=0)) for arm in grippers.keys()),  # noqa: SIM118 - Fields
    )
