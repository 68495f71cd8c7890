"""The cell daemon's settings: the `cell:` section of config/cell.yaml."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from drivers.common.configfile import Fields, config_dir, load_yaml_over
from drivers.controller.link import ZENOH, controller_address

CELL_FIELDS = {"max_attempts", "verify_min_iou", "camera_timeout_s", "motion_timeout_margin_s",
               "motion_timeout_factor", "state_period_s", "required_processes", "reply_timeout_s",
               "verify_resolution_m", "rejoin_tolerance_rad", "unchanged_min_iou", "view_pose_tolerance",
               "view_retry_period_s", "lost_grace_s", "controller"}


@dataclass(frozen=True)
class CellConfig:
    max_attempts: int                 # tries of one fold (re-perceive, re-plan, re-fold) before giving up
    verify_min_iou: float             # a fold is good when the seen outline overlaps the expected this much
    verify_resolution_m: float        # raster cell of that comparison
    unchanged_min_iou: float          # a failed check overlapping the outline before this much: nothing moved
    camera_timeout_s: float           # a capture slower than this is a camera fault
    motion_timeout_factor: float      # wall-time allowance: factor x robot time / time scale + margin
    motion_timeout_margin_s: float
    state_period_s: float             # cell/state is repeated this often besides on change
    required_processes: tuple[str, ...]   # exact process names the cell needs; losing one is a fault
    lost_grace_s: float               # a cell at rest faults on a lost token not back within this
    reply_timeout_s: float            # controller and camera queries
    rejoin_tolerance_rad: float       # farther than this from a trajectory's start: move there first
    view_pose_tolerance: float        # a wrist camera's image is of its view when its pose is this close
    view_retry_period_s: float        # and is taken again after this pause until then (camera_timeout_s)
    controller: str = "zenoh"         # zenoh, or motoros://HOST[:PORT] (`controller_address`)


def load_cell_config(path: str | Path | None = None) -> CellConfig:
    f = load_yaml_over(path, config_dir() / "cell.yaml").sub("cell")
    f.reject_unknown(CELL_FIELDS)
    return CellConfig(
        max_attempts=f.int("max_attempts", min=1, max=10),
        verify_min_iou=f.float("verify_min_iou", min=0.0, max=1.0),
        verify_resolution_m=f.float("verify_resolution_m", positive=True),
        unchanged_min_iou=f.float("unchanged_min_iou", min=0.0, max=1.0),
        camera_timeout_s=f.float("camera_timeout_s", positive=True),
        motion_timeout_factor=f.float("motion_timeout_factor", min=1.0),
        motion_timeout_margin_s=f.float("motion_timeout_margin_s", min=0.0),
        state_period_s=f.float("state_period_s", positive=True),
        required_processes=f.strs("required_processes"),
        lost_grace_s=f.float("lost_grace_s", positive=True),
        reply_timeout_s=f.float("reply_timeout_s", positive=True),
        rejoin_tolerance_rad=f.float("rejoin_tolerance_rad", positive=True),
        view_pose_tolerance=f.float("view_pose_tolerance", positive=True),
        view_retry_period_s=f.float("view_retry_period_s", positive=True),
        controller=controller_url(f),
    )


def controller_url(f: Fields) -> str:
    url = f.str("controller", ZENOH)
    try:
        controller_address(url)
    except ValueError as exc:
        raise f.error("controller", str(exc)) from exc
    return url
