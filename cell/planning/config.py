"""config/planning.yaml loaded into frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from cell.planning.collision import CollisionParams
from cell.planning.ik import IkParams
from cell.planning.trajectory import TrajectoryParams
from drivers.common.configfile import Fields, config_dir, load_fields, load_yaml, rule


@dataclass(frozen=True)
class MotionParams:
    check_step: float = rule(positive=True)
    rrt_check_step: float = rule(positive=True)
    rrt_time_limit: float = rule(positive=True)
    rrt_range: float = rule(positive=True)
    simplify: bool = rule()
    check_period: float = rule(positive=True)
    rrt_attempts: int = rule(min=0)
    perceive: tuple[float, ...] = rule(length=13)


@dataclass(frozen=True)
class GraspParams:
    pitch: float = rule(min=0.0, max=1.5)
    yaw_offsets: tuple[float, ...] = rule()
    turntable_angles: tuple[float, ...] = rule()
    height: float = rule(min=0.0)
    release_height: float = rule(min=0.0, max=0.3)
    depth: float = rule(min=0.0)
    approach_distance: float = rule(positive=True)
    approach_lift: float = rule(min=0.0)
    retreat_distance: float = rule(positive=True)
    retreat_lift: float = rule(min=0.0)
    cartesian_step: float = rule(positive=True)
    max_joint_step: float = rule(positive=True)


@dataclass(frozen=True)
class PlanningConfig:
    """config/planning.yaml; the fields `under="folds"` are keys of its `folds` section."""

    ik: IkParams = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    ik_seeds: tuple[tuple[float, ...], ...] = rule()   # the `ik` section's `seeds` (given by the loader)
    collision: CollisionParams = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    trajectory: TrajectoryParams = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    motion: MotionParams = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    grasp: GraspParams = rule(section=True)  # noqa: RUF009 - a frozen dataclass
    merge_distance: float = rule(positive=True, under="folds")
    min_two_arm_spacing: float = rule(min=0.0, under="folds")
    max_wrist_reach: float = rule(positive=True, under="folds")
    wrist_offset: float = rule(min=0.0, under="folds")
    reach_radius: float = rule(positive=True, under="folds")
    pull_margin: float = rule(min=0.0, under="folds")
    max_pull: float = rule(positive=True, under="folds")
    max_pulls: int = rule(min=0, under="folds")
    pull_grasp_spacing: float = rule(positive=True, under="folds")
    pull_arm_spacing: float = rule(min=0.0, under="folds")
    # optional in the file (given by the loader)
    one_arm_edge_distance: float = rule(positive=True, under="folds", default=float("inf"))


def load_planning_config(path: str | Path | None = None) -> PlanningConfig:
    path = Path(path) if path else config_dir() / "planning.yaml"
    f = load_yaml(path)
    i, fo = f.sub("ik"), f.sub("folds")
    seeds_raw = i.raw("seeds")
    if not isinstance(seeds_raw, list) or not seeds_raw:
        raise i.error("seeds", "must be a non-empty list of 6-value lists")
    config = load_fields(
        PlanningConfig, f, ik=load_fields(IkParams, i.without("seeds")),
        ik_seeds=tuple(_seed(i, k) for k in range(len(seeds_raw))),
        one_arm_edge_distance=fo.float("one_arm_edge_distance", positive=True)
        if fo.has("one_arm_edge_distance") else float("inf"))
    if not config.grasp.yaw_offsets or not config.grasp.turntable_angles:
        raise f.sub("grasp").error("yaw_offsets", "yaw_offsets and turntable_angles must not be empty")
    return config


def _seed(ik: Fields, k: int) -> tuple[float, ...]:
    """ik.seeds[k]: six joint values of one arm (S, L, U, R, B, T)."""
    value = ik.raw("seeds")[k]
    holder = Fields({f"seeds[{k}]": value}, ik.file, ik.prefix)
    return holder.floats(f"seeds[{k}]", length=6)


@lru_cache(maxsize=1)
def default_planning_config() -> PlanningConfig:
    return load_planning_config()


__all__ = ["GraspParams", "MotionParams", "PlanningConfig", "default_planning_config", "load_planning_config"]
