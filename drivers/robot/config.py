"""The cell's joints, control groups and limits: the one place that fixes joint names and order."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path

import numpy as np

from drivers.common.configfile import ConfigError, config_dir, load_yaml


@dataclass(frozen=True)
class JointSpec:
    """One axis. Units: rad, rad/s, rad/s^2, rad/s^3."""

    name: str
    lower: float
    upper: float
    max_velocity: float
    max_acceleration: float
    max_jerk: float


@dataclass(frozen=True)
class ControlGroup:
    """A MotoROS control group (robot or station) and the controller (master/slave) that drives it."""

    name: str
    controller: str
    joints: tuple[str, ...]


@dataclass(frozen=True)
class ArmSpec:
    name: str
    group: str
    tcp_frame: str


@dataclass(frozen=True)
class RobotConfig:
    joints: tuple[JointSpec, ...]
    groups: tuple[ControlGroup, ...]
    arms: tuple[ArmSpec, ...]
    home: tuple[float, ...]
    urdf_path: Path

    @cached_property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @cached_property
    def _indices(self) -> dict[str, int]:
        return {name: i for i, name in enumerate(self.joint_names)}

    @property
    def lower(self) -> np.ndarray:
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> np.ndarray:
        return np.array([j.upper for j in self.joints])

    @property
    def max_velocity(self) -> np.ndarray:
        return np.array([j.max_velocity for j in self.joints])

    @property
    def max_acceleration(self) -> np.ndarray:
        return np.array([j.max_acceleration for j in self.joints])

    @property
    def max_jerk(self) -> np.ndarray:
        return np.array([j.max_jerk for j in self.joints])

    def index(self, joint_name: str) -> int:
        try:
            return self._indices[joint_name]
        except KeyError:
            raise ValueError(f"{joint_name!r} is not a joint of the cell") from None

    def group(self, name: str) -> ControlGroup:
        for g in self.groups:
            if g.name == name:
                return g
        raise KeyError(name)

    def group_indices(self, name: str) -> list[int]:
        return [self.index(j) for j in self.group(name).joints]

    def arm(self, name: str) -> ArmSpec:
        for a in self.arms:
            if a.name == name:
                return a
        raise KeyError(name)



CONTROLLER_ROLES = ("master", "slave")


def load_robot_config(path: str | Path | None = None) -> RobotConfig:
    path = Path(path) if path else config_dir() / "robot" / "joints.yaml"
    f = load_yaml(path)
    f.reject_unknown({"joints", "groups", "arms", "home", "urdf"})
    joints = []
    for item in f.items("joints"):
        spec = JointSpec(
            name=item.str("name"),
            lower=item.float("lower"),
            upper=item.float("upper"),
            max_velocity=item.float("velocity", positive=True),
            max_acceleration=item.float("acceleration", positive=True),
            max_jerk=item.float("jerk", positive=True),
        )
        if spec.lower >= spec.upper:
            raise item.error("upper", f"must be above lower ({spec.lower})")
        joints.append(spec)
    names = [j.name for j in joints]
    if len(set(names)) != len(names):
        raise f.error("joints", "joint names must be unique")
    groups = []
    seen: list[str] = []
    for item in f.items("groups"):
        group = ControlGroup(item.str("name"), item.str("controller", choices=CONTROLLER_ROLES),
                             item.strs("joints"))
        for j in group.joints:
            if j not in names:
                raise item.error("joints", f"unknown joint {j!r}")
        seen.extend(group.joints)
        groups.append(group)
    if sorted(seen) != sorted(names):
        raise f.error("groups", "every joint must belong to exactly one group")
    group_names = [g.name for g in groups]
    arms = []
    for item in f.items("arms"):
        arm = ArmSpec(item.str("name"), item.str("group", choices=tuple(group_names)), item.str("tcp_frame"))
        arms.append(arm)
    home = f.floats("home", length=len(joints))
    for joint, value in zip(joints, home, strict=True):
        if not joint.lower <= value <= joint.upper:
            raise f.error("home", f"{joint.name} = {value} is outside [{joint.lower}, {joint.upper}]")
    urdf = path.parent / f.str("urdf")
    return RobotConfig(tuple(joints), tuple(groups), tuple(arms), home, urdf)


@lru_cache(maxsize=1)
def default_robot_config() -> RobotConfig:
    return load_robot_config()


__all__ = ["ArmSpec", "ConfigError", "ControlGroup", "JointSpec", "RobotConfig", "default_robot_config",
           "load_robot_config"]
