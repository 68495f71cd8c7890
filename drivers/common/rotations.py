"""Rotations: roll-pitch-yaw (as URDF), rotation matrices, unit quaternions (x, y, z, w as ROS)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

Quaternion = tuple[float, float, float, float]   # (x, y, z, w)


def rpy_to_matrix(rpy: ArrayLike) -> NDArray[np.float64]:
    """Rotation matrix of roll-pitch-yaw (extrinsic x, then y, then z), as URDF."""
    roll, pitch, yaw = (float(v) for v in np.asarray(rpy, dtype=float).reshape(3))
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    about_x = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    about_y = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    about_z = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return about_z @ about_y @ about_x


def pose_matrix(position: ArrayLike, rpy: ArrayLike) -> NDArray[np.float64]:
    """4x4 homogeneous transform from a position and roll-pitch-yaw."""
    pose = np.eye(4)
    pose[:3, :3] = rpy_to_matrix(rpy)
    pose[:3, 3] = np.asarray(position, dtype=float)
    return pose


def quaternion_xyzw(rotation: ArrayLike) -> Quaternion:
    """A rotation matrix as a unit quaternion (x, y, z, w).

    The branch is chosen by the largest of the trace and the diagonal terms, so the square root
    never takes a small number (numerically safe for every rotation).
    """
    r = np.asarray(rotation, dtype=float)
    trace = float(np.trace(r))
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s
    else:
        s = 2.0 * np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s
    norm = float(np.sqrt(x * x + y * y + z * z + w * w))
    return (float(x) / norm, float(y) / norm, float(z) / norm, float(w) / norm)


def quaternion_to_matrix(quaternion: Sequence[float]) -> NDArray[np.float64]:
    """The rotation matrix of a quaternion (x, y, z, w); it need not be of unit length."""
    x, y, z, w = (float(v) for v in quaternion)
    norm = float(np.sqrt(x * x + y * y + z * z + w * w))
    if not norm > 0:
        raise ValueError(f"quaternion: must not be zero, got {(x, y, z, w)}")
    if abs(norm - 1.0) > 1e-12:  # a unit quaternion is used as it is: a round trip changes no bit
        x, y, z, w = x / norm, y / norm, z / norm, w / norm
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
