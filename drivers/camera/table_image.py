"""Several views of the table merged into one top-down (orthographic) image of the table plane.

A wrist camera sees the table in parts, each from the pose the arm had when it took it. Every view
is resampled onto one grid on the table plane and the views are blended where they overlap. The
grid is described as a camera straight above the table (`table_image_model`): seen from straight
above, the table plane maps to pixels by one scale, so the merged image is orthographic on the
table and its `CameraInfo` serves perception and pixel <-> table maps like any camera's.
"""

from __future__ import annotations

import cv2
import numpy as np

from drivers.camera.base import Frame
from drivers.camera.errors import CameraError
from drivers.camera.model import CameraConfig, CameraModel, TableImageConfig
from drivers.common.rotations import pose_matrix
from drivers.robot.table import TableConfig

TABLE_IMAGE_FRAME = "table_image"
# straight down, image x along world -y and image y along world -x: the fixed camera's axes, so a
# garment lying upright has its top away from the robot in both
TABLE_IMAGE_RPY = (np.pi, 0.0, -np.pi / 2)
# the described camera's height above the table; any height gives the same table-plane map (the
# focal length follows it), 1 m keeps the numbers in its CameraInfo readable
TABLE_IMAGE_HEIGHT = 1.0


def table_image_model(image: TableImageConfig, table: TableConfig) -> CameraModel:
    """The merged image's camera: straight above `image.centre_table`, one pixel per `resolution`."""
    focal = TABLE_IMAGE_HEIGHT / image.resolution
    centre = np.array([image.centre_table[0], image.centre_table[1], TABLE_IMAGE_HEIGHT])
    pose = pose_matrix(centre + table.origin_in_world, TABLE_IMAGE_RPY)
    config = CameraConfig(width=image.width, height=image.height, fx=focal, fy=focal,
                          cx=(image.width - 1) / 2.0, cy=(image.height - 1) / 2.0, distortion=(0.0,) * 5,
                          frame_id=TABLE_IMAGE_FRAME, mount="fixed", fixed_pose_in_world=pose)
    return CameraModel(config, pose_in_world=pose, table=table)


def _border_distance(width: int, height: int) -> np.ndarray:
    """Per pixel, 1 + its distance (px) to the nearest image border: a view's blending weight, so a
    view counts least where it ends and the seam between views fades instead of stepping."""
    columns = np.minimum(np.arange(width), np.arange(width)[::-1]).astype(np.float32) + 1.0
    rows = np.minimum(np.arange(height), np.arange(height)[::-1]).astype(np.float32) + 1.0
    return np.minimum(rows[:, None], columns[None, :])


def merge_views(frames: list[Frame], model: CameraModel) -> Frame:
    """One image on `model`'s grid from `frames` (each mapped to the table by its own `info`).

    Raises CameraError when the views leave part of the grid unseen.
    """
    if not frames:
        raise CameraError("merge: no views to merge")
    size = (model.config.width, model.config.height)
    total = np.zeros((size[1], size[0], 3), np.float32)
    weights = np.zeros((size[1], size[0]), np.float32)
    for frame in frames:
        view = CameraModel.from_info(frame.info, model.table)
        # merged pixel -> table plane -> the view's pixel
        merged_to_view = view.table_to_image @ model.image_to_table
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        image = cv2.warpPerspective(frame.image.astype(np.float32), merged_to_view, size, flags=flags,
                                    borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))
        height, width = frame.image.shape[:2]
        weight = cv2.warpPerspective(_border_distance(width, height), merged_to_view, size, flags=flags,
                                     borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        total += image * weight[..., None]
        weights += weight
    unseen = weights <= 0
    if unseen.any():
        raise CameraError(f"merge: the views leave {unseen.mean():.1%} of the table image unseen "
                          f"(views: config/camera.yaml wrist.views)")
    merged = np.clip(total / weights[..., None] + 0.5, 0, 255).astype(np.uint8)
    return Frame(image=merged, stamp=max(f.stamp for f in frames), info=model.camera_info())


__all__ = ["TABLE_IMAGE_FRAME", "merge_views", "table_image_model"]
