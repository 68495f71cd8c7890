"""Rotations against scipy's, an independent implementation: RPY as URDF (extrinsic x, y, z),
matrix <-> quaternion (x, y, z, w) for every branch of the conversion."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from drivers.common.rotations import pose_matrix, quaternion_to_matrix, quaternion_xyzw, rpy_to_matrix


def _same_rotation(q: tuple[float, ...], reference: np.ndarray) -> bool:
    return bool(np.allclose(q, reference, atol=1e-12) or np.allclose(q, -reference, atol=1e-12))


def test_rpy_is_extrinsic_xyz() -> None:
    rng = np.random.default_rng(0)
    for rpy in rng.uniform(-np.pi, np.pi, (50, 3)):
        reference = Rotation.from_euler("xyz", rpy).as_matrix()
        np.testing.assert_allclose(rpy_to_matrix(rpy), reference, atol=1e-12)
    # yaw alone turns x towards y
    np.testing.assert_allclose(rpy_to_matrix([0, 0, np.pi / 2]) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_pose_matrix() -> None:
    pose = pose_matrix([1.0, -2.0, 0.5], [0.1, 0.2, 0.3])
    reference = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_matrix()
    np.testing.assert_allclose(pose[:3, :3], reference, atol=1e-12)
    np.testing.assert_array_equal(pose[:3, 3], [1.0, -2.0, 0.5])
    np.testing.assert_array_equal(pose[3], [0, 0, 0, 1])


@pytest.mark.parametrize("rotvec", [
    [0.3, -0.2, 0.1],                                   # trace > 0
    # one diagonal term the largest
    [np.pi - 0.01, 0.02, 0.0], [0.01, np.pi - 0.02, 0.0], [0.0, 0.03, np.pi - 0.01],
    [np.pi, 0.0, 0.0], [0.0, np.pi, 0.0], [0.0, 0.0, np.pi],   # half turns: trace -1
])
def test_quaternion_of_every_branch(rotvec: list[float]) -> None:
    rotation = Rotation.from_rotvec(rotvec)
    q = quaternion_xyzw(rotation.as_matrix())
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)
    assert _same_rotation(q, rotation.as_quat())
    np.testing.assert_allclose(quaternion_to_matrix(q), rotation.as_matrix(), atol=1e-12)


def test_random_rotations_round_trip() -> None:
    for rotation in Rotation.random(200, random_state=1):
        q = quaternion_xyzw(rotation.as_matrix())
        assert _same_rotation(q, rotation.as_quat())
        np.testing.assert_allclose(quaternion_to_matrix(q), rotation.as_matrix(), atol=1e-12)


def test_quaternion_to_matrix_normalises_and_refuses_zero() -> None:
    q = Rotation.from_rotvec([0.2, 0.4, -0.1]).as_quat()
    np.testing.assert_allclose(quaternion_to_matrix(3.0 * q), Rotation.from_quat(q).as_matrix(), atol=1e-12)
    with pytest.raises(ValueError, match="quaternion"):
        quaternion_to_matrix((0.0, 0.0, 0.0, 0.0))
