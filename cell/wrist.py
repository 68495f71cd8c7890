"""The camera on the wrist: the arm configurations of its perceiving views and the table image they
are merged into.

The views are configuration data (config/camera.yaml `wrist.views`: where the camera looks from);
the arm that carries the camera reaches each by inverse kinematics, with the turn-table at the
view's angle and the other arm in its perceiving configuration, and every configuration must be
free of collisions. The cell moves there with planned free moves like any other motion.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cell.planning.errors import PlanningError
from cell.planning.motion import MotionPlanner
from drivers.camera.model import CameraConfig, CameraModel
from drivers.camera.table_image import table_image_model
from drivers.robot.table import TableConfig


@dataclass(frozen=True)
class WristCamera:
    """The joint configurations (13 values, project order) that put the camera at its views, the
    camera's pose (4x4, `world`) at each by forward kinematics, and the camera describing the merged
    table image."""

    views: tuple[np.ndarray, ...]
    camera_poses: tuple[np.ndarray, ...]
    table_image: CameraModel


def wrist_camera(planner: MotionPlanner, camera: CameraConfig, table: TableConfig) -> WristCamera:
    """The views of `camera` (a wrist mount) solved for the arm whose TCP carries it. Raises
    PlanningError naming the view that the arm cannot reach or that collides."""
    arms = {arm.tcp_frame: arm.name for arm in planner.robot.arms}
    if camera.wrist_parent_frame not in arms:
        raise PlanningError(f"wrist.parent_frame: must be an arm's TCP frame ({', '.join(sorted(arms))}), "
                            f"got {camera.wrist_parent_frame!r}")
    if camera.table_image is None:
        raise PlanningError("wrist.table_image: missing")
    arm = arms[camera.wrist_parent_frame]
    camera_to_tcp = np.linalg.inv(camera.wrist_pose_in_parent)
    configurations = []
    for index, view in enumerate(camera.wrist_views):
        tcp_target = view.pose_in_world(table) @ camera_to_tcp
        seeds = []
        for arm_seed in planner.config.ik_seeds:
            seed = planner.perceive.copy()
            seed[planner.arm_indices[arm]] = arm_seed
            seed[planner.ext_index] = view.turntable
            seeds.append(seed)
        result = planner.ik.solve_multi(arm, tcp_target, seeds)
        if not result.success:
            raise PlanningError(f"wrist.views[{index}]: {arm} cannot put the camera there (IK misses by "
                                f"{result.position_error * 1000:.1f} mm, "
                                f"{np.degrees(result.angle_error):.1f} deg)")
        if not planner.valid(result.q):
            pairs = planner.collision.colliding_pairs(result.q)
            raise PlanningError(f"wrist.views[{index}]: the arm collides there ({pairs or 'joint limits'})")
        configurations.append(result.q)
    poses = tuple(planner.kin.fk(q, camera.wrist_parent_frame) @ camera.wrist_pose_in_parent
                  for q in configurations)
    return WristCamera(tuple(configurations), poses, table_image_model(camera.table_image, table))


__all__ = ["WristCamera", "wrist_camera"]
