"""Trajectory files for `foldcell controller send TRAJECTORY.yaml`.

Format (units: s, rad, rad/s)::

    joint_names: [r1_joint_s, ...]     # optional: default all joints in project order
    points:
      - {time: 0.0, positions: [...], velocities: [...]}   # velocities optional on every point
      - {time: 1.5, positions: [...]}

Only the file's shape is checked here; the controller's acceptance rules judge the motion.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from drivers.common.configfile import ConfigError, load_yaml
from drivers.controller.trajectory import JointTrajectory
from drivers.robot.config import RobotConfig


def load_trajectory(path: str | Path, robot_config: RobotConfig) -> JointTrajectory:
    """Read a trajectory file; errors (`ConfigError`) name the file, the field and the reason."""
    f = load_yaml(path)
    f.reject_unknown({"joint_names", "points"})
    names = f.strs("joint_names", robot_config.joint_names)
    points = f.items("points")
    if not points:
        raise f.error("points", "must hold at least one point")
    n = len(names)
    times, pos, vel = [], [], []
    with_vel = [p.has("velocities") for p in points]
    if any(with_vel) and not all(with_vel):
        i = with_vel.index(False)
        raise ConfigError(f.file, f"points[{i}].velocities",
                          "missing: give velocities on every point or on none")
    for p in points:
        p.reject_unknown({"time", "positions", "velocities"})
        times.append(p.float("time"))
        pos.append(p.floats("positions", length=n))
        if p.has("velocities"):
            vel.append(p.floats("velocities", length=n))
    return JointTrajectory(tuple(names), np.array(times), np.array(pos), np.array(vel) if vel else None)
