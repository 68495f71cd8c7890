"""The cell daemon's settings: the `cell:` section of config/cell.yaml."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_fields, load_yaml_over, rule
from drivers.controller.link import ZENOH, controller_address


@dataclass(frozen=True)
class CellConfig:
    # tries of one fold (re-perceive, re-plan, re-fold) before giving up
    max_attempts: int = rule(min=1, max=10)
    # a fold is good when the seen outline overlaps the expected this much
    verify_min_iou: float = rule(min=0.0, max=1.0)
    verify_resolution_m: float = rule(positive=True)       # raster cell of that comparison
    # a failed check overlapping the outline before this much: nothing moved
    unchanged_min_iou: float = rule(min=0.0, max=1.0)
    camera_timeout_s: float = rule(positive=True)          # a capture slower than this is a camera fault
    # wall-time allowance: factor x robot time / time scale + margin
    motion_timeout_factor: float = rule(min=1.0)
    motion_timeout_margin_s: float = rule(min=0.0)
    state_period_s: float = rule(positive=True)            # cell/state is repeated this often, and on change
    # exact process names the cell needs; losing one is a fault
    required_processes: tuple[str, ...] = rule()
    # a cell at rest faults on a lost token not back within this
    lost_grace_s: float = rule(positive=True)
    # ... and a working cell too, for these (no motion needs them)
    graced_while_working: tuple[str, ...] = rule()
    reply_timeout_s: float = rule(positive=True)           # controller and camera queries
    # farther than this from a trajectory's start: move there first
    rejoin_tolerance_rad: float = rule(positive=True)
    # a wrist camera's image is of its view when its pose is this close
    view_pose_tolerance: float = rule(positive=True)
    # and is taken again after this pause until then (camera_timeout_s)
    view_retry_period_s: float = rule(positive=True)
    controller: str = ZENOH           # zenoh, or motoros://HOST[:PORT] (`controller_address`)


def load_cell_config(path: str | Path | None = None) -> CellConfig:
    f = load_yaml_over(path, config_dir() / "cell.yaml").sub("cell")
    return load_fields(CellConfig, f, controller=controller_url(f))


def controller_url(f: Fields) -> str:
    url = f.str("controller", ZENOH)
    try:
        controller_address(url)
    except ValueError as exc:
        raise f.error("controller", str(exc)) from exc
    return url
