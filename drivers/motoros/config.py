"""`config/motoros.yaml` loaded into a frozen dataclass."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import config_dir, load_fields, load_yaml, rule
from drivers.motoros.messages import DIALECTS


@dataclass(frozen=True)
class MotorosConfig:
    """The MotoROS server's parameters. Units: s, rad, encoder pulses."""

    port: int = rule(min=1, max=65534)
    dialect: str = rule(choices=tuple(DIALECTS))
    state_period: float = rule(positive=True)
    queue_increments: int = rule(min=1)
    motion_slots: int = rule(min=1)
    state_slots: int = rule(min=1)
    start_tolerance_pulses: tuple[tuple[str, int], ...] = rule()   # dialect -> pulses (given by the loader)
    in_motion_lag_pulses: int = rule(min=0)
    pulses_per_radian: float = rule(positive=True)
    max_point_time: float = rule(positive=True)
    tool_count: int = rule(min=1)
    partial_frame_timeout: float = rule(positive=True)
    io_slots: int = rule(min=1)
    gripper_outputs: tuple[tuple[str, int], ...] = rule()   # arm -> output number (given by the loader)

    def start_tolerance(self, dialect: str) -> float:
        """rad: the start tolerance of `dialect` in pulses, over the pulses per radian."""
        return dict(self.start_tolerance_pulses)[dialect] / self.pulses_per_radian


def load_motoros_config(path: str | Path | None = None) -> MotorosConfig:
    """Read and validate `config/motoros.yaml` (or `path`); errors name file, field and reason."""
    f = load_yaml(Path(path) if path else config_dir() / "motoros.yaml")
    grippers = f.sub("gripper_outputs")
    tolerances = f.sub("start_tolerance_pulses")
    tolerances.reject_unknown(set(DIALECTS))
    return load_fields(
        MotorosConfig, f,
        start_tolerance_pulses=tuple((name, tolerances.int(name, min=0)) for name in DIALECTS),
        gripper_outputs=tuple((arm, grippers.int(arm, min=0)) for arm in grippers.keys()),  # noqa: SIM118 - Fields
    )
