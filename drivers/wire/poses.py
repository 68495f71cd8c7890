"""The one codec between a 4x4 homogeneous pose and `geometry_msgs/Pose` (and `PoseStamped`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from drivers.common.rotations import quaternion_to_matrix, quaternion_xyzw
from drivers.wire import messages


def pose_msg(pose: np.ndarray) -> Any:
    """`geometry_msgs/Pose` of a 4x4 homogeneous matrix."""
    x, y, z, w = quaternion_xyzw(pose[:3, :3])
    return messages.new("geometry_msgs/msg/Pose",
                        position=messages.new("geometry_msgs/msg/Point", x=float(pose[0, 3]),
                                              y=float(pose[1, 3]), z=float(pose[2, 3])),
                        orientation=messages.new("geometry_msgs/msg/Quaternion", x=float(x), y=float(y),
                                                 z=float(z), w=float(w)))


def pose_stamped_msg(pose: np.ndarray, stamp_ns: int, frame_id: str = "world") -> Any:
    """`geometry_msgs/PoseStamped` of a 4x4 homogeneous matrix in `frame_id` at `stamp_ns`."""
    return messages.new("geometry_msgs/msg/PoseStamped", header=messages.header(stamp_ns, frame_id),
                        pose=pose_msg(pose))


def pose_matrix(pose: Any) -> np.ndarray:
    """4x4 homogeneous matrix of a `geometry_msgs/Pose`."""
    q = pose.orientation
    matrix = np.eye(4)
    matrix[:3, :3] = quaternion_to_matrix((q.x, q.y, q.z, q.w))
    matrix[:3, 3] = [pose.position.x, pose.position.y, pose.position.z]
    return matrix
