"""config/planning.yaml loaded into frozen dataclasses."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from cell.planning.collision import BACKENDS, CollisionParams
from cell.planning.ik import IkParams
from cell.planning.trajectory import TrajectoryParams
from drivers.common.configfile import Fields, config_dir, load_yaml


@dataclass(frozen=True)
class MotionParams:
    check_step: float
    rrt_check_step: float
    rrt_time_limit: float
    rrt_range: float
    simplify: bool
    check_period: float
    rrt_attempts: int
    perceive: tuple[float, ...]


@dataclass(frozen=True)
class GraspParams:
    pitch: float
    yaw_offsets: tuple[float, ...]
    turntable_angles: tuple[float, ...]
    height: float
    release_height: float
    depth: float
    approach_distance: float
    approach_lift: float
    retreat_distance: float
    retreat_lift: float
    cartesian_step: float
    max_joint_step: float


@dataclass(frozen=True)
class PlanningConfig:
    ik: IkParams
    ik_seeds: tuple[tuple[float, ...], ...]
    collision: CollisionParams
    trajectory: TrajectoryParams
    motion: MotionParams
    grasp: GraspParams
    merge_distance: float
    min_two_arm_spacing: float
    max_wrist_reach: float
    wrist_offset: float
    reach_radius: float
    pull_margin: float
    max_pull: float
    max_pulls: int
    pull_grasp_spacing: float
    pull_arm_spacing: float
    one_arm_edge_distance: float = float("inf")


def load_planning_config(path: str | Path | None = None) -> PlanningConfig:
    path = Path(path) if path else config_dir() / "planning.yaml"
    f = load_yaml(path)
    f.reject_unknown({"ik", "collision", "trajectory", "motion", "grasp", "folds"})
    i = f.sub("ik")
    i.reject_unknown({"max_iterations", "damping", "position_tolerance", "angle_tolerance", "max_step",
                      "limit_margin", "seeds"})
    ik = IkParams(i.int("max_iterations", min=1), i.float("damping", positive=True),
                  i.float("position_tolerance", positive=True), i.float("angle_tolerance", positive=True),
                  i.float("max_step", positive=True), i.float("limit_margin", min=0.0))
    seeds_raw = i.raw("seeds")
    if not isinstance(seeds_raw, list) or not seeds_raw:
        raise i.error("seeds", "must be a non-empty list of 6-value lists")
    seeds = tuple(_seed(i, k) for k in range(len(seeds_raw)))
    c = f.sub("collision")
    c.reject_unknown({"backend", "finger_links", "table_link", "disable_samples", "disable_fraction"})
    coll = CollisionParams(c.str("backend", choices=BACKENDS), c.strs("finger_links"), c.str("table_link"),
                           c.int("disable_samples", min=1), c.float("disable_fraction", min=0.0, max=1.0))
    t = f.sub("trajectory")
    t.reject_unknown({"sample_period", "velocity_scale", "acceleration_scale", "jerk_scale"})
    traj = TrajectoryParams(t.float("sample_period", positive=True),
                            t.float("velocity_scale", positive=True, max=1.0),
                            t.float("acceleration_scale", positive=True, max=1.0),
                            t.float("jerk_scale", positive=True, max=1.0))
    m = f.sub("motion")
    m.reject_unknown({"check_step", "rrt_check_step", "rrt_time_limit", "rrt_range", "simplify",
                      "check_period", "rrt_attempts", "perceive"})
    motion = MotionParams(m.float("check_step", positive=True), m.float("rrt_check_step", positive=True),
                          m.float("rrt_time_limit", positive=True),
                          m.float("rrt_range", positive=True), m.bool("simplify"),
                          m.float("check_period", positive=True), m.int("rrt_attempts", min=0),
                          m.floats("perceive", length=13))
    g = f.sub("grasp")
    g.reject_unknown({"pitch", "yaw_offsets", "turntable_angles", "height", "release_height", "depth",
                      "approach_distance",
                      "approach_lift", "retreat_distance", "retreat_lift", "cartesian_step",
                      "max_joint_step"})
    grasp = GraspParams(g.float("pitch", min=0.0, max=1.5), g.floats("yaw_offsets"),
                        g.floats("turntable_angles"),
                        g.float("height", min=0.0), g.float("release_height", min=0.0, max=0.3),
                        g.float("depth", min=0.0),
                        g.float("approach_distance", positive=True), g.float("approach_lift", min=0.0),
                        g.float("retreat_distance", positive=True), g.float("retreat_lift", min=0.0),
                        g.float("cartesian_step", positive=True), g.float("max_joint_step", positive=True))
    if not grasp.yaw_offsets or not grasp.turntable_angles:
        raise g.error("yaw_offsets", "yaw_offsets and turntable_angles must not be empty")
    fo = f.sub("folds")
    fo.reject_unknown({"merge_distance", "min_two_arm_spacing", "max_wrist_reach", "wrist_offset",
                       "reach_radius", "one_arm_edge_distance", "pull_margin", "max_pull",
                       "max_pulls", "pull_grasp_spacing", "pull_arm_spacing"})
    return PlanningConfig(ik, seeds, coll, traj, motion, grasp, fo.float("merge_distance", positive=True),
                          fo.float("min_two_arm_spacing", min=0.0),
                          fo.float("max_wrist_reach", positive=True),
                          fo.float("wrist_offset", min=0.0), fo.float("reach_radius", positive=True),
                          fo.float("pull_margin", min=0.0), fo.float("max_pull", positive=True),
                          fo.int("max_pulls", min=0), fo.float("pull_grasp_spacing", positive=True),
                          fo.float("pull_arm_spacing", min=0.0),
                          fo.float("one_arm_edge_distance", positive=True)
                          if fo.has("one_arm_edge_distance") else float("inf"))


def _seed(ik: Fields, k: int) -> tuple[float, ...]:
    """ik.seeds[k]: six joint values of one arm (S, L, U, R, B, T)."""
    value = ik.raw("seeds")[k]
    holder = Fields({f"seeds[{k}]": value}, ik.file, ik.prefix)
    return holder.floats(f"seeds[{k}]", length=6)


@lru_cache(maxsize=1)
def default_planning_config() -> PlanningConfig:
    return load_planning_config()


__all__ = ["GraspParams", "MotionParams", "PlanningConfig", "default_planning_config", "load_planning_config"]
