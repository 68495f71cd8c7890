"""Camera geometry: pixel <-> table plane, axes of the default mount, wrist poses, camera info."""

from pathlib import Path

import numpy as np
import pytest

from drivers.camera.model import CameraModel, ConfigError, load_camera_config
from drivers.common.rotations import pose_matrix
from drivers.robot.table import default_table_config


def test_default_camera_looks_down_with_image_x_along_minus_world_y():
    cam = CameraModel()
    t = default_table_config()
    centre = cam.table_to_pixel([[t.size_x / 2, t.size_y / 2]])[0]
    assert np.allclose(centre, [cam.config.cx, cam.config.cy], atol=1e-6)
    # moving along table +y (world +y) goes left in the image; along +x (away from the robot) goes up
    d = cam.table_to_pixel([[t.size_x / 2, t.size_y / 2 + 0.1], [t.size_x / 2 + 0.1, t.size_y / 2]]) - centre
    assert d[0, 0] < -100 and abs(d[0, 1]) < 1e-6
    assert d[1, 1] < -100 and abs(d[1, 0]) < 1e-6


def test_table_fills_the_image_at_under_a_millimetre_per_pixel():
    cam = CameraModel()
    t = default_table_config()
    corners = cam.pixel_to_table([[0, 0], [1279, 0], [1279, 1023], [0, 1023]])
    assert np.all(t.contains(corners))
    assert 0.0007 < cam.pixel_size_at_table() < 0.001


@pytest.mark.parametrize("seed", range(10))
def test_pixel_table_round_trip_from_tilted_poses(seed):
    rng = np.random.default_rng(seed)
    pose = pose_matrix([1.0 + rng.uniform(-0.2, 0.2), rng.uniform(-0.2, 0.2), 1.6 + rng.uniform(-0.1, 0.2)],
                       [np.pi + rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(-3, 3)])
    cam = CameraModel(pose_in_world=pose)
    xy = rng.uniform([0, 0], [0.8, 1.2], size=(50, 2))
    px = cam.table_to_pixel(xy)
    assert np.allclose(cam.pixel_to_table(px), xy, atol=1e-9)
    world = default_table_config().table_to_world(xy)
    assert np.allclose(cam.world_to_pixel(world), px, atol=1e-6)


def test_wrist_pose_composes_flange_and_mount():
    cfg = load_camera_config()
    flange = pose_matrix([1.0, 0.1, 1.5], [np.pi, 0.0, 0.2])
    pose = CameraModel.wrist_pose(flange, cfg)
    assert np.allclose(pose, flange @ cfg.wrist_pose_in_parent)


def test_camera_info_carries_k_p_and_pose():
    cam = CameraModel()
    info = cam.camera_info()
    assert (info.width, info.height) == (1280, 1024)
    k = np.array(info.k).reshape(3, 3)
    assert np.allclose(k, cam.k)
    assert np.allclose(np.array(info.p).reshape(3, 4)[:, :3], k)
    assert np.allclose(np.array(info.pose_in_world).reshape(4, 4), cam.pose_in_world)


def test_bad_config_names_field(tmp_path: Path):
    p = tmp_path / "camera.yaml"
    p.write_text(Path("config/camera.yaml").read_text().replace("mount: fixed", "mount: ceiling"))
    with pytest.raises(ConfigError, match="mount"):
        load_camera_config(p)


def test_bad_pose_is_rejected():
    with pytest.raises(ValueError, match="pose_in_world"):
        CameraModel(pose_in_world=np.eye(3))


def test_a_camera_rebuilt_from_its_info_maps_pixels_the_same_way():
    from drivers.camera.model import CameraModel

    original = CameraModel()
    rebuilt = CameraModel.from_info(original.camera_info())
    px = np.array([[0.0, 0.0], [640.0, 512.0], [1279.0, 1023.0]])
    np.testing.assert_allclose(rebuilt.pixel_to_table(px), original.pixel_to_table(px), atol=1e-9)


def test_a_wrist_view_below_the_table_is_named_in_the_error(tmp_path):
    import yaml

    from tests.conftest import REPO

    camera = yaml.safe_load((REPO / "config" / "camera.yaml").read_text())
    camera["wrist"]["views"][1]["position"][2] = -0.1
    path = tmp_path / "camera.yaml"
    path.write_text(yaml.safe_dump(camera))
    with pytest.raises(ConfigError, match=r"wrist\.views\[1\]\.position.*height"):
        load_camera_config(path)
