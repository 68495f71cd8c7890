"""The cell model: URDF against joints.yaml, and FK against hand-computed poses."""

import math
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from drivers.robot.config import default_robot_config
from drivers.robot.kinematics import CellKinematics, KinematicsError

TILT = math.radians(15.0)


@pytest.fixture(scope="module")
def kin() -> CellKinematics:
    return CellKinematics()


def test_urdf_joints_match_joints_yaml():
    robot = default_robot_config()
    root = ET.parse(robot.urdf_path).getroot()
    urdf = {j.get("name"): j for j in root.iter("joint") if j.get("type") == "revolute"}
    assert sorted(urdf) == sorted(robot.joint_names)
    for spec in robot.joints:
        lim = urdf[spec.name].find("limit")
        assert float(lim.get("lower")) == pytest.approx(spec.lower)
        assert float(lim.get("upper")) == pytest.approx(spec.upper)
        assert float(lim.get("velocity")) == pytest.approx(spec.max_velocity)


def test_tcp_frames_exist(kin):
    for arm in ("r1", "r2"):
        assert kin.model.existFrame(f"{arm}_tcp")
    assert kin.model.existFrame("table") and kin.model.existFrame("camera")


def _mount(side: float) -> np.ndarray:
    """Arm base in world at ext_axis = 0: (0, 0.3 side, 0.9), tilted 15 deg outwards about x."""
    a = -side * TILT
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]
    T[:3, 3] = [0.0, 0.3 * side, 0.9]
    return T


@pytest.mark.parametrize("arm,side", [("r1", 1.0), ("r2", -1.0)])
def test_fk_zero_pose_by_hand(kin, arm, side):
    # zero pose, in the arm base frame: TCP at x = 0.15 + 0.64 + 0.1 + 0.2, z = 0.45 + 0.614 + 0.2,
    # approach (TCP z) along base x, jaw (TCP x) along base -z
    pose = kin.tcp_pose(np.zeros(13), arm)
    M = _mount(side)
    expected_p = M @ np.array([1.09, 0.0, 1.264, 1.0])
    np.testing.assert_allclose(pose[:3, 3], expected_p[:3], atol=1e-6)
    np.testing.assert_allclose(pose[:3, 2], M[:3, 0], atol=1e-6)
    np.testing.assert_allclose(pose[:3, 0], -M[:3, 2], atol=1e-6)


def test_fk_turntable_and_shoulder_by_hand(kin):
    robot = kin.robot
    q = np.zeros(13)
    q[robot.index("ext_axis")] = math.pi / 2
    q[robot.index("r1_joint_l")] = math.pi / 2   # upper arm forward, forearm pointing down
    pose = kin.tcp_pose(q, "r1")
    # base frame: L at (0.15, 0, 0.45); U 0.614 further along +x; forearm offset 0.2 along +x;
    # B 0.64 down; flange 0.1 and TCP 0.2 further down; approach = base -z
    p_base = np.array([0.15 + 0.614 + 0.2, 0.0, 0.45 - 0.64 - 0.1 - 0.2, 1.0])
    Rz = np.eye(4)
    Rz[:2, :2] = [[0, -1], [1, 0]]
    M = Rz @ _mount(1.0)
    np.testing.assert_allclose(pose[:3, 3], (M @ p_base)[:3], atol=1e-6)
    np.testing.assert_allclose(pose[:3, 2], -M[:3, 2], atol=1e-6)


def test_project_order_is_kept(kin):
    # changing only r2's S must leave r1's TCP where it was
    q = np.zeros(13)
    a = kin.tcp_pose(q, "r1")
    q[kin.robot.index("r2_joint_s")] = 1.0
    np.testing.assert_allclose(kin.tcp_pose(q, "r1"), a)
    assert not np.allclose(kin.tcp_pose(q, "r2"), kin.tcp_pose(np.zeros(13), "r2"))


def test_bad_joint_vector_is_named(kin):
    with pytest.raises(KinematicsError, match="13 values"):
        kin.tcp_pose(np.zeros(12), "r1")
    with pytest.raises(KinematicsError, match="unknown arm"):
        kin.tcp_pose(np.zeros(13), "r3")


def test_planning_config_errors_name_file_and_field(tmp_path):
    from cell.planning.config import load_planning_config
    from drivers.common.configfile import ConfigError, config_dir

    text = (config_dir() / "planning.yaml").read_text()
    bad = tmp_path / "planning.yaml"
    bad.write_text(text.replace("backend: coal", "backend: bullet"))
    with pytest.raises(ConfigError, match=r"planning.yaml: collision.backend: must be one of"):
        load_planning_config(bad)
    bad.write_text(text.replace("- [0.0, 0.6, -0.3, 0.0, -0.6, 0.0]", "- [0.0, 0.6]"))
    with pytest.raises(ConfigError, match=r"ik.seeds\[0\]"):
        load_planning_config(bad)
