"""Camera sources: parsing, life cycle, folder cycling, the sim camera's bytes."""

import numpy as np
import pytest

from drivers.camera import CameraNotConnectedError, CameraSourceError, parse_source
from drivers.camera.directory import DirectoryCamera
from drivers.camera.opencv_device import OpenCVDeviceCamera
from drivers.sim.camera import SimCamera
from drivers.sim.dataset import generate, render_scene_png
from tools.camera_cli import open_source


def test_parse_source():
    assert parse_source("sim").kind == "sim"
    assert parse_source("dir:/tmp/x").path == "/tmp/x"
    assert parse_source("device:2").index == 2
    for bad in ("", "simulated", "dir:", "device:", "device:-1", "device:a", "file:/x"):
        with pytest.raises(CameraSourceError, match="--source"):
            parse_source(bad)


def test_directory_camera_cycles_in_order(tmp_path):
    paths = generate(tmp_path, 2, seed=1, categories=["towel"], progress=False)
    cam = DirectoryCamera(tmp_path)
    with pytest.raises(CameraNotConnectedError):
        cam.capture()
    with cam:
        assert cam.is_connected
        order = sorted(paths)
        got = [cam.capture() for _ in range(len(order) + 1)]
        assert [f.png for f in got] == [p.read_bytes() for p in order] + [order[0].read_bytes()]
        assert got[0].image.shape == (1024, 1280, 3) and got[0].info.width == 1280
        assert got[1].stamp >= got[0].stamp
    assert not cam.is_connected


def test_directory_camera_errors(tmp_path):
    with pytest.raises(CameraSourceError, match="not a directory"):
        DirectoryCamera(tmp_path / "nope").connect()
    with pytest.raises(CameraSourceError, match="no images"):
        DirectoryCamera(tmp_path).connect()


def test_sim_camera_returns_the_dataset_bytes_and_follows_grippers():
    with open_source("sim", seed=6, category="towel", folding="geometric") as cam:
        assert isinstance(cam, SimCamera)
        frame = cam.capture()
        assert frame.png == render_scene_png(6, "towel")
        w = cam.world
        lm = dict(zip(w.garment.names, w.garment.landmarks, strict=True))
        z = w.table.height + 0.005
        for arm, name in (("r1", "bottom-left"), ("r2", "bottom-right")):
            cam.gripper_event(arm, True, np.append(w.table.table_to_world(lm[name][None])[0][:2], z))
        for arm, name in (("r1", "top-left"), ("r2", "top-right")):
            cam.gripper_event(arm, False, np.append(w.table.table_to_world(lm[name][None])[0][:2], z))
        after = cam.capture()
        assert len(w.history) == 1
        assert not np.array_equal(after.image, frame.image)


def test_missing_device_is_a_clear_error():
    with pytest.raises(CameraSourceError, match="device:97"):
        OpenCVDeviceCamera(97).connect()


def test_sim_camera_renders_from_a_wrist_pose_and_reports_it():
    from drivers.common.rotations import pose_matrix
    with SimCamera(seed=2, category="pants") as cam:
        fixed = cam.capture()
        pose = pose_matrix([1.05, 0.05, 1.6], [np.pi + 0.1, 0.05, -1.5])
        cam.camera_pose_world = pose
        wrist = cam.capture()
    assert np.allclose(np.array(wrist.info.pose_in_world).reshape(4, 4), pose)
    assert not np.array_equal(np.array(fixed.info.pose_in_world), np.array(wrist.info.pose_in_world))
    assert wrist.image.shape == fixed.image.shape and not np.array_equal(wrist.image, fixed.image)
