"""The pose codec: a 4x4 pose as geometry_msgs/Pose, its quaternion the textbook one, and back."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.wire import messages
from drivers.wire.poses import pose_matrix, pose_msg, pose_stamped_msg


def turned_about_z(angle: float, at: tuple[float, float, float]) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    pose = np.eye(4)
    pose[:2, :2] = [[c, -s], [s, c]]
    pose[:3, 3] = at
    return pose


@pytest.mark.parametrize("angle", [0.0, 0.3, -2.0, math.pi / 2])
def test_a_turn_about_z_is_the_textbook_quaternion_and_comes_back(angle: float) -> None:
    pose = turned_about_z(angle, (0.1, -0.2, 0.75))
    msg = pose_msg(pose)
    q = msg.orientation
    expected = (0.0, 0.0, math.sin(angle / 2), math.cos(angle / 2))
    assert np.allclose([q.x, q.y, q.z, q.w], expected, atol=1e-12) or \
        np.allclose([q.x, q.y, q.z, q.w], [-v for v in expected], atol=1e-12)
    assert (msg.position.x, msg.position.y, msg.position.z) == (0.1, -0.2, 0.75)
    # through the CDR bytes a ROS 2 peer would see
    decoded = messages.decode("geometry_msgs/msg/Pose", messages.encode("geometry_msgs/msg/Pose", msg))
    assert np.allclose(pose_matrix(decoded), pose, atol=1e-12)


def test_a_stamped_pose_carries_its_frame_and_stamp() -> None:
    msg = pose_stamped_msg(turned_about_z(1.0, (1.0, 2.0, 3.0)), 1_700_000_000_123_456_789, "world")
    assert msg.header.frame_id == "world"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1_700_000_000, 123_456_789)
    assert np.allclose(pose_matrix(msg.pose), turned_about_z(1.0, (1.0, 2.0, 3.0)))
