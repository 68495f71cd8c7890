"""The cell camera's geometry: pinhole intrinsics, its pose in `world`, pixel <-> table-plane maps.

Frames: `world` (floor at the turn-table axis, z up), `table` (a table-top corner, axes parallel to
`world`), the camera optical frame (x right, y down, z forward, as OpenCV). Units: m and pixels.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from drivers.common.configfile import ConfigError, config_dir, load_fields, load_yaml, rule
from drivers.common.rotations import pose_matrix
from drivers.robot.table import TableConfig, default_table_config


@dataclass(frozen=True)
class CameraInfo:
    """What `sensor_msgs/CameraInfo` carries, as plain data (row-major K 3x3, P 3x4, D plumb_bob)."""

    width: int
    height: int
    k: tuple[float, ...]
    d: tuple[float, ...]
    p: tuple[float, ...]
    r: tuple[float, ...] = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
    distortion_model: str = "plumb_bob"
    frame_id: str = "camera_optical"
    # camera optical frame in `world` (4x4 row-major), so a client can map pixels to the table
    pose_in_world: tuple[float, ...] = field(default_factory=lambda: tuple(np.eye(4).ravel()))


MOUNTS = ("fixed", "wrist")


@dataclass(frozen=True)
class WristView:
    """One perceiving view of a wrist camera: its optical frame over the table and the turn-table
    angle the arm reaches it with."""

    position_table: tuple[float, float, float]   # table frame x, y (m) and height above the top (m)
    rpy: tuple[float, float, float]              # optical frame orientation in `world` (rad)
    turntable: float                             # ext_axis (rad)

    def pose_in_world(self, table: TableConfig) -> np.ndarray:
        """The optical frame in `world` (4x4)."""
        return pose_matrix(np.asarray(self.position_table) + table.origin_in_world, self.rpy)


@dataclass(frozen=True)
class TableImageConfig:
    """The wrist views merged into one top-down image of the table plane."""

    centre_table: tuple[float, float]   # table frame (m)
    resolution: float                   # m per pixel
    width: int
    height: int


@dataclass(frozen=True)
class CameraConfig:
    """config/camera.yaml: the fields with a rule are its top-level keys; the loader gives the others from
    its `fixed` and `wrist` sections."""
    width: int = rule(min=1)
    height: int = rule(min=1)
    fx: float = rule(positive=True)
    fy: float = rule(positive=True)
    cx: float = rule()
    cy: float = rule()
    distortion: tuple[float, ...] = rule(length=5)
    frame_id: str = rule()
    mount: str = rule(choices=MOUNTS)
    # 4x4 optical frame in world (mypy takes the rule() above for defaults: this one has none)
    fixed_pose_in_world: np.ndarray = field(compare=False)  # type: ignore[misc]
    wrist_parent_frame: str = "r1_tcp"
    wrist_pose_in_parent: np.ndarray = field(default_factory=lambda: np.eye(4), compare=False)
    wrist_views: tuple[WristView, ...] = ()
    table_image: TableImageConfig | None = None

    @property
    def k(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


def load_camera_config(path: str | Path | None = None) -> CameraConfig:
    path = Path(path) if path else config_dir() / "camera.yaml"
    f = load_yaml(path)
    fixed = f.sub("fixed")
    fixed.reject_unknown({"position", "rpy"})
    wrist = f.sub("wrist")
    wrist.reject_unknown({"parent_frame", "position", "rpy", "views", "table_image"})
    views = []
    for view in wrist.items("views"):
        view.reject_unknown({"position", "rpy", "turntable"})
        x, y, height = view.floats("position", length=3)
        if height <= 0:
            raise view.error("position", f"the height above the table (third value) must be > 0, "
                                         f"got {height}")
        roll, pitch, yaw = view.floats("rpy", length=3)
        views.append(WristView((x, y, height), (roll, pitch, yaw), view.float("turntable")))
    if not views:
        raise wrist.error("views", "must list at least one view")
    image = wrist.sub("table_image")
    image.reject_unknown({"centre", "resolution", "width", "height"})
    centre_x, centre_y = image.floats("centre", length=2)
    table_image = TableImageConfig((centre_x, centre_y), image.float("resolution", positive=True),
                                   image.int("width", min=1), image.int("height", min=1))
    return load_fields(
        CameraConfig, f.without("fixed", "wrist"),
        fixed_pose_in_world=pose_matrix(fixed.floats("position", length=3), fixed.floats("rpy", length=3)),
        wrist_parent_frame=wrist.str("parent_frame"),
        wrist_pose_in_parent=pose_matrix(wrist.floats("position", length=3), wrist.floats("rpy", length=3)),
        wrist_views=tuple(views),
        table_image=table_image,
    )


@lru_cache(maxsize=1)
def default_camera_config() -> CameraConfig:
    return load_camera_config()


class CameraModel:
    """A pinhole camera at a pose in `world`, mapping pixels to the table top and back."""

    def __init__(self, config: CameraConfig | None = None, pose_in_world: np.ndarray | None = None,
                 table: TableConfig | None = None):
        self.config = config or default_camera_config()
        self.table = table or default_table_config()
        if pose_in_world is None:
            if self.config.mount == "wrist":
                raise ValueError("pose_in_world: a wrist-mounted camera needs its world pose (4x4) from the "
                                 "arm's forward kinematics; see CameraModel.wrist_pose()")
            pose_in_world = self.config.fixed_pose_in_world
        pose = np.asarray(pose_in_world, dtype=float)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise ValueError(f"pose_in_world: must be a finite 4x4 matrix, got shape {pose.shape}")
        self.pose_in_world = pose
        self.k = self.config.k
        self.table_to_image = self._table_homography()
        self.image_to_table = np.linalg.inv(self.table_to_image)

    @classmethod
    def from_info(cls, info: CameraInfo, table: TableConfig | None = None) -> CameraModel:
        """The camera a `CameraInfo` describes (intrinsics and pose in `world`), e.g. one received on
        the wire."""
        k = np.asarray(info.k, dtype=float).reshape(3, 3)
        pose = np.asarray(info.pose_in_world, dtype=float).reshape(4, 4)
        config = CameraConfig(width=info.width, height=info.height, fx=float(k[0, 0]), fy=float(k[1, 1]),
                              cx=float(k[0, 2]), cy=float(k[1, 2]), distortion=tuple(info.d),
                              frame_id=info.frame_id, mount="fixed", fixed_pose_in_world=pose)
        return cls(config, pose_in_world=pose, table=table)

    @staticmethod
    def wrist_pose(flange_pose_in_world: np.ndarray, config: CameraConfig | None = None) -> np.ndarray:
        """Camera optical frame in `world` from the r1 TCP/flange pose in `world` (4x4)."""
        config = config or default_camera_config()
        return np.asarray(flange_pose_in_world, dtype=float) @ config.wrist_pose_in_parent

    def _table_homography(self) -> np.ndarray:
        # table-plane point (x, y, 0) in `table` -> world -> camera -> pixel, a 3x3 homography
        world_from_table = np.eye(4)
        world_from_table[:3, 3] = self.table.origin_in_world
        cam_from_table = np.linalg.inv(self.pose_in_world) @ world_from_table
        h = self.k @ cam_from_table[:3, [0, 1, 3]]
        if abs(np.linalg.det(h)) < 1e-12:
            raise ValueError("pose_in_world: the camera sees the table plane edge-on")
        return h / h[2, 2] if abs(h[2, 2]) > 1e-12 else h

    def table_to_pixel(self, points_xy: np.ndarray) -> np.ndarray:
        """(N, 2) table-frame points (m) -> (N, 2) pixel coordinates (x right, y down)."""
        pts = np.atleast_2d(np.asarray(points_xy, dtype=float))
        hom = np.column_stack([pts, np.ones(len(pts))]) @ self.table_to_image.T
        return hom[:, :2] / hom[:, 2:3]

    def pixel_to_table(self, pixels: np.ndarray) -> np.ndarray:
        """(N, 2) pixel coordinates -> (N, 2) table-frame points (m) on the table-top plane."""
        px = np.atleast_2d(np.asarray(pixels, dtype=float))
        hom = np.column_stack([px, np.ones(len(px))]) @ self.image_to_table.T
        return hom[:, :2] / hom[:, 2:3]

    def world_to_pixel(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 2) pixels (points must be in front of the camera)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        cam = (np.linalg.inv(self.pose_in_world) @ np.column_stack([pts, np.ones(len(pts))]).T)[:3]
        if np.any(cam[2] <= 0):
            raise ValueError("points: some points are behind the camera")
        uv = self.k @ cam
        return (uv[:2] / uv[2]).T

    def pixel_size_at_table(self) -> float:
        """Metres per pixel on the table at the image centre (for reports and tolerances)."""
        c = np.array([[self.config.cx, self.config.cy], [self.config.cx + 1.0, self.config.cy]])
        t = self.pixel_to_table(c)
        return float(np.linalg.norm(t[1] - t[0]))

    def camera_info(self) -> CameraInfo:
        k = self.k
        p = np.column_stack([k, np.zeros(3)])
        return CameraInfo(
            width=self.config.width, height=self.config.height,
            k=tuple(float(v) for v in k.ravel()), d=tuple(self.config.distortion),
            p=tuple(float(v) for v in p.ravel()), frame_id=self.config.frame_id,
            pose_in_world=tuple(float(v) for v in self.pose_in_world.ravel()),
        )


def default_camera_model() -> CameraModel:
    """The configured fixed camera (raises for a wrist mount, whose pose needs the arm's state)."""
    return CameraModel()


__all__ = ["MOUNTS", "CameraConfig", "CameraInfo", "CameraModel", "ConfigError", "TableImageConfig",
           "WristView", "default_camera_config", "default_camera_model", "load_camera_config"]
