"""The camera on the wrist: views merged into one table image, a fold end to end over Zenoh, and the
camera pose of every capture from the arm's joint states."""

from __future__ import annotations

import json
import subprocess
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader

from drivers.sessions.mcap.bag import find_session
from drivers.wire import messages
from tests.bench.bench_cell import min_final_iou
from tests.conftest import REPO, foldcell_argv

TIME_SCALE = "20"
URDF = REPO / "config" / "robot" / "cell.urdf"
# the pose an image reports is the forward kinematics of one of the joint states exactly (float noise
# only, m and rotation-matrix entries); the arm is at rest then, so the latest state gives it within
# AT_REST_M
POSE_TOLERANCE = 1e-6
RECENT_NS = 100_000_000   # 0.1 s of the controller's stamps before a capture's stamp
AT_REST_M = 0.001
# a capture this close to a view was taken there (config/cell.yaml view_pose_tolerance)
VIEW_TOLERANCE_M = 0.0005
# the merged image on the table: every true landmark (a vertex of the garment's outline) lies this
# close to the outline segmented in it (a pixel is 0.775 mm; the segmented border is within about
# two of the true one)
LANDMARK_TOLERANCE_M = 0.003
MIN_SILHOUETTE_IOU = 0.97


# ------------------------------------------------------------------ an FK of our own, from the URDF
def _rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    rot_x = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    rot_y = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rot_z = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rot_z @ rot_y @ rot_x


def _transform(xyz, rpy) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = _rpy(*rpy)
    out[:3, 3] = xyz
    return out


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    skew = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    out = np.eye(4)
    out[:3, :3] = np.eye(3) + np.sin(angle) * skew + (1 - np.cos(angle)) * skew @ skew
    return out


def urdf_fk(urdf: Path, joints: dict[str, float], frame: str) -> np.ndarray:
    """Pose of link `frame` in `world`: the URDF's joint chain multiplied out."""
    by_child = {}
    for joint in ElementTree.parse(urdf).getroot().iter("joint"):
        by_child[joint.find("child").get("link")] = joint
    pose = np.eye(4)
    link = frame
    while link in by_child:
        joint = by_child[link]
        origin = joint.find("origin")
        local = _transform([float(v) for v in origin.get("xyz", "0 0 0").split()],
                           [float(v) for v in origin.get("rpy", "0 0 0").split()])
        if joint.get("type") == "revolute":
            axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
            local = local @ _axis_rotation(axis, joints[joint.get("name")])
        pose = local @ pose
        link = joint.find("parent").get("link")
    assert link == "world", f"{frame}: chain ends at {link}"
    return pose


def _camera_yaml() -> dict:
    return yaml.safe_load((REPO / "config" / "camera.yaml").read_text())


# ------------------------------------------------------------------ the merged table image
@pytest.mark.parametrize("category", ["towel", "long-sleeve"])
def test_the_merged_views_map_the_table_as_the_truth_lies(category):
    """Views rendered from where the arm's configurations put the camera (the world's render, as
    the camera process does it), merged: the garment segmented in the merged image, mapped to the
    table by the merged image's camera, lies where the simulated world says it is."""
    from cell.fold_check import polygon_iou
    from cell.perception.config import load_perception_config
    from cell.perception.pipeline import extract_outline, load_garment_models, load_table_model
    from cell.planning.motion import default_motion_planner
    from cell.wrist import wrist_camera
    from drivers.camera.base import Frame
    from drivers.camera.model import CameraModel, default_camera_config
    from drivers.camera.table_image import merge_views
    from drivers.sim.dataset import build_world

    world = build_world(2, category)
    camera_config = default_camera_config()
    wrist = wrist_camera(default_motion_planner(), camera_config, world.table)
    assert len(wrist.views) >= 2  # the table does not fit one view from a reachable height
    mount = _camera_yaml()["wrist"]
    frames = []
    for q in wrist.views:
        joints = dict(zip(world_joint_names(), q, strict=True))
        pose = urdf_fk(URDF, joints, mount["parent_frame"]) @ _transform(mount["position"], mount["rpy"])
        info = CameraModel(camera_config, pose, world.table).camera_info()
        frames.append(Frame(world.render(pose), 0.0, info))
    merged = merge_views(frames, wrist.table_image)
    perception = load_perception_config()
    outline = extract_outline(merged.image, load_table_model(None, perception), perception,
                              [load_garment_models(perception)[category]])
    seen = _orthographic_pixel_to_table(outline.contour.astype(float), _camera_yaml()["wrist"]["table_image"])
    # the merged image's own camera says the same
    np.testing.assert_allclose(CameraModel.from_info(merged.info, world.table).pixel_to_table(
        outline.contour.astype(float)), seen, atol=1e-6)
    assert polygon_iou(seen, world.silhouette(), 0.001) >= MIN_SILHOUETTE_IOU
    names, truth = world.truth_polygon()
    distances = {name: float(np.min(np.linalg.norm(seen - point, axis=1)))
                 for name, point in zip(names, truth, strict=True)}
    assert max(distances.values()) <= LANDMARK_TOLERANCE_M, distances


def _orthographic_pixel_to_table(pixels: np.ndarray, table_image: dict) -> np.ndarray:
    """The table image as config/camera.yaml defines it: `resolution` m per pixel around `centre`,
    image x along world -y, image y along world -x (the fixed camera's axes)."""
    centre_u, centre_v = (table_image["width"] - 1) / 2, (table_image["height"] - 1) / 2
    x = table_image["centre"][0] - (pixels[:, 1] - centre_v) * table_image["resolution"]
    y = table_image["centre"][1] - (pixels[:, 0] - centre_u) * table_image["resolution"]
    return np.column_stack([x, y])


def world_joint_names() -> list[str]:
    joints = yaml.safe_load((REPO / "config" / "robot" / "joints.yaml").read_text())["joints"]
    return [joint["name"] for joint in joints]


# ------------------------------------------------------------------ end to end over Zenoh
@pytest.mark.slow
@pytest.mark.timeout(300)
def test_a_wrist_camera_fold_end_to_end_with_the_pose_of_every_capture_from_the_joint_states(tmp_path):
    out = tmp_path / "demo"
    # the geometric world: what is tested is the wrist camera's seeing, not how cloth folds
    result = subprocess.run(foldcell_argv("demo", "--camera", "wrist", "--garment", "towel", "--seed", "1",
                                          "--time-scale", TIME_SCALE, "--output", str(out), "--json",
                                          "--folding", "geometric"),
                            capture_output=True, text=True, timeout=240)
    assert result.stdout, result.stderr[-3000:]
    summary = json.loads(result.stdout)
    assert summary["camera"] == "wrist"
    (towel,) = summary["garments"]
    assert towel["outcome"] == "done", towel["reason"]
    assert towel["final_iou"] >= min_final_iou("towel")
    assert result.returncode == 0

    # every image the camera took, its pose, and the joint states the recorder heard
    images: set[int] = set()
    poses: list[tuple[int, int, np.ndarray]] = []  # (stamp, log time, 4x4)
    joint_states: list[tuple[int, int, np.ndarray]] = []  # (log time, stamp, positions)
    (session_file,) = find_session(out / "session").files   # the demo's bag: one file at this size
    with open(session_file, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            key = channel.topic.split("/", 3)[3]
            if key == "camera/image":
                images.add(messages.stamp_to_ns(messages.decode("sensor_msgs/msg/CompressedImage",
                                                                message.data).header.stamp))
            elif key == "camera/pose":
                msg = messages.decode("geometry_msgs/msg/PoseStamped", message.data)
                poses.append((messages.stamp_to_ns(msg.header.stamp), message.log_time, _pose(msg.pose)))
            elif key == "controller/joint_states":
                msg = messages.decode("sensor_msgs/msg/JointState", message.data)
                joint_states.append((message.log_time, messages.stamp_to_ns(msg.header.stamp),
                                     np.asarray(msg.position, dtype=float)))
    captures = [(stamp, log_time, pose) for stamp, log_time, pose in poses if stamp in images]
    joint_states.sort(key=lambda item: item[0])
    mount = _camera_yaml()["wrist"]
    mount_pose = _transform(mount["position"], mount["rpy"])
    names = world_joint_names()
    fk: dict[tuple[float, ...], np.ndarray] = {}  # the camera pose of each distinct joint state
    for _t, _stamp, q in joint_states:
        key = tuple(q)
        if key not in fk:
            fk[key] = urdf_fk(URDF, dict(zip(names, q, strict=True)), mount["parent_frame"]) @ mount_pose
    origin = np.array([0.6, -0.6, 0.75])  # config/table.yaml: near edge 0.6 m, 1.2 m wide, 0.75 m high
    views = [np.array(v["position"]) + origin for v in mount["views"]]
    at_views = 0
    for stamp, log_time, pose in captures:
        # the camera renders from the last joint state it has heard, which may be a moment old (the
        # cell takes such an image again): some state before the capture gives exactly this pose
        before = [tuple(q) for t, _s, q in joint_states if t <= log_time]
        errors = [float(np.abs(fk[key] - pose).max()) for key in dict.fromkeys(before)]
        assert errors and min(errors) <= POSE_TOLERANCE, f"no joint state gives this pose ({min(errors):.2e})"
        if min(np.linalg.norm(pose[:3, 3] - view) for view in views) < VIEW_TOLERANCE_M:
            at_views += 1
            # taken at a view, with the arm at rest there: a state the controller stamped in the moment
            # before the capture gives the pose (stamps, not the recorder's log times: a loaded recorder
            # logs late, and by then the arm may be on its way to the next view)
            recent = [tuple(q) for _t, s, q in joint_states if stamp - RECENT_NS <= s <= stamp]
            assert min(float(np.abs(fk[key] - pose).max()) for key in [*recent, before[-1]]) <= AT_REST_M
    # two views for each of 3 perceptions, but camera images are dropped when the link is congested, so
    # the log of a loaded machine may lack one: at least one view of each perception
    assert at_views >= 3


def _pose(pose) -> np.ndarray:
    from drivers.wire.poses import pose_matrix

    return pose_matrix(pose)
