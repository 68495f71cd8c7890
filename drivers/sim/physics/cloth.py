"""A cloth on the table, folded by two grippers, in MuJoCo's flex cloth.

The table frame is MuJoCo's world frame: x, y on the table top, z up from it (metres). The cloth is
the garment's triangulated mesh (`mesh.cut_mesh`, flexcomp `direct`); the grippers are mocap bodies
without geometry that pinch the cloth by connect constraints made active at run time: closing pinches
the vertices under the fingers (every layer there), closing in the air or beside the cloth pinches
nothing, opening releases them.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import cv2
import mujoco
import numpy as np

from drivers.sim.physics.config import PhysicsConfig
from drivers.sim.physics.mesh import ClothMesh

GRIPPERS = 2

log = logging.getLogger(__name__)
# MuJoCo's warnings (an unstable step, too many contacts) go to the log, not to MUJOCO_LOG.TXT in the
# working directory
mujoco.set_mju_user_warning(lambda text: log.warning("MuJoCo: %s", text))


@dataclass(frozen=True)
class Silhouette:
    """The table area the cloth covers seen from above: `mask[row, col]` is the cell whose lower
    corner lies at `origin + (col, row) * resolution` in the table frame."""
    mask: np.ndarray                  # uint8 0/1, rows along y, columns along x
    origin: tuple[float, float]       # m, table x, y of mask[0, 0]'s corner
    resolution: float                 # m per pixel
    polygon: np.ndarray               # (N, 2) table x, y of the outline of the largest covered region


def cloth_xml(mesh: ClothMesh, config: PhysicsConfig, grippers: int = GRIPPERS) -> str:
    """MJCF of the flat cloth `mesh` lying on the table, `grippers` mocap grippers and `max_pinched`
    inactive connect constraints per gripper."""
    cloth = config.cloth
    mass = cloth.areal_density * mesh_area(mesh)
    radius = cloth.thickness / 2.0
    points = " ".join(f"{x:.6f} {y:.6f} {radius:.6f}" for x, y in mesh.points)
    elements = " ".join(str(int(v)) for v in mesh.triangles.reshape(-1))
    pinches = "".join(
        f'<connect name="pinch{gripper}_{slot}" body1="gripper{gripper}" body2="cloth_0" '
        f'anchor="0 0 0" active="false"/>'
        for gripper in range(grippers) for slot in range(config.gripper.max_pinched))
    bodies = "".join(f'<body name="gripper{gripper}" mocap="true" pos="0 0 0.5"/>'
                     for gripper in range(grippers))
    # explicit Euler: MuJoCo integrates flex elasticity explicitly, whatever the integrator; an
    # elliptic friction cone: the pyramidal one lets the lower layer creep under a pulled flap.
    # A contact takes the larger friction of its two sides: the table's is the cloth-on-table one,
    # the cloth's own (smaller) the cloth-on-cloth one
    return f"""
<mujoco model="cloth">
  <option timestep="{config.simulation.timestep}" integrator="Euler" solver="{config.simulation.solver}"
          cone="elliptic" tolerance="{config.simulation.tolerance}"
          iterations="{config.simulation.iterations}"/>
  <worldbody>
    <geom name="table" type="plane" size="5 5 0.1" friction="{cloth.friction} 0.005 0.0001"/>
    {bodies}
    <flexcomp name="cloth" type="direct" dim="2" point="{points}" element="{elements}"
              radius="{radius}" mass="{mass}">
      <contact condim="3" friction="{cloth.self_friction} 0.005 0.0001"
               selfcollide="{cloth.self_collision}"/>
      <edge equality="true" damping="{cloth.edge_damping}"/>
      <elasticity young="{cloth.young}" poisson="{cloth.poisson}" thickness="{cloth.thickness}"
                  damping="{cloth.elastic_damping}" elastic2d="bend"/>
    </flexcomp>
  </worldbody>
  <equality>{pinches}</equality>
</mujoco>"""


def mesh_area(mesh: ClothMesh) -> float:
    first, second, third = (mesh.points[mesh.triangles[:, k]] for k in range(3))
    cross = ((second - first)[:, 0] * (third - first)[:, 1] - (second - first)[:, 1] * (third - first)[:, 0])
    return float(np.abs(cross).sum() / 2.0)


def rectangle(width: float, length: float) -> np.ndarray:
    """A `width` (x) by `length` (y) rectangle centred at the origin, counter-clockwise."""
    half_x, half_y = width / 2.0, length / 2.0
    return np.array([[-half_x, -half_y], [half_x, -half_y], [half_x, half_y], [-half_x, half_y]])


def triangular_path(start: np.ndarray, end: np.ndarray, apex_height: float, spacing: float) -> np.ndarray:
    """Points from `start` up to the apex above the midpoint and down to `end`, `spacing` apart."""
    apex = (start + end) / 2.0 + np.array([0.0, 0.0, apex_height])
    legs = []
    for a, b in ((start, apex), (apex, end)):
        count = max(1, math.ceil(float(np.linalg.norm(b - a)) / spacing))
        legs.append(a + (b - a) * (np.arange(1, count + 1) / count)[:, None])
    return np.vstack(legs)


class ClothWorld:
    """One cloth on the table and its grippers, stepped by `physics.garment.GarmentCloth`."""

    def __init__(self, mesh: ClothMesh, config: PhysicsConfig, grippers: int = GRIPPERS):
        self.config = config
        self.mesh = mesh
        self.grippers = grippers
        self.model = mujoco.MjModel.from_xml_string(cloth_xml(mesh, config, grippers))
        self.data = mujoco.MjData(self.model)
        self.flex = 0
        self.gripper_mocap = [int(self.model.body_mocapid[self.model.body(f"gripper{gripper}").id])
                              for gripper in range(grippers)]
        self.pinch_slots = [[self.model.equality(f"pinch{gripper}_{slot}").id
                             for slot in range(config.gripper.max_pinched)]
                            for gripper in range(grippers)]
        start = int(self.model.flex_vertadr[self.flex])
        self.vertex_bodies = self.model.flex_vertbodyid[start:start + int(self.model.flex_vertnum[self.flex])]
        elem_start = int(self.model.flex_elemdataadr[self.flex])
        elem_count = int(self.model.flex_elemnum[self.flex])
        self.triangles = self.model.flex_elem[elem_start:elem_start + 3 * elem_count].reshape(-1, 3)
        mujoco.mj_forward(self.model, self.data)

    @property
    def vertices(self) -> np.ndarray:
        """(V, 3) cloth vertex positions, table frame."""
        return np.array(self.data.flexvert_xpos, copy=True)

    def step_for(self, seconds: float) -> None:
        for _ in range(max(0, round(seconds / self.config.simulation.timestep))):
            mujoco.mj_step(self.model, self.data)

    def move_grippers(self, positions: np.ndarray) -> None:
        """Place both grippers (rows of `positions`) and let one timestep pass."""
        for gripper, mocap in enumerate(self.gripper_mocap):
            self.data.mocap_pos[mocap] = positions[gripper]
        mujoco.mj_step(self.model, self.data)

    def close(self, gripper: int) -> tuple[int, ...]:
        """Pinch the vertices under the gripper's fingers: within `pinch_radius` across and
        `pinch_height` up or down. Returns the vertices held (none in the air or beside the cloth)."""
        settings = self.config.gripper
        mujoco.mj_forward(self.model, self.data)
        fingers = np.array(self.data.mocap_pos[self.gripper_mocap[gripper]])
        offsets = self.vertices - fingers
        across = np.linalg.norm(offsets[:, :2], axis=1)
        under = np.flatnonzero((across <= settings.pinch_radius)
                               & (np.abs(offsets[:, 2]) <= settings.pinch_height))
        held = under[np.argsort(across[under])][:settings.max_pinched]
        for slot, vertex in zip(self.pinch_slots[gripper], held, strict=False):
            # held at the fingers' point: the fingers bunch what they pinch, and a held point turns
            # over with the fold instead of keeping its offset from a gripper that does not rotate
            self.model.eq_obj2id[slot] = self.vertex_bodies[vertex]
            self.model.eq_data[slot, 0:6] = 0.0
            self.data.eq_active[slot] = 1
        return tuple(int(v) for v in held)

    def open(self, gripper: int) -> None:
        for slot in self.pinch_slots[gripper]:
            self.data.eq_active[slot] = 0

    def silhouette(self, origin: tuple[float, float], size: tuple[float, float]) -> Silhouette:
        """The cloth's triangles seen from above, on a mask covering `size` (x, y) from `origin`."""
        return silhouette_of(self.vertices, self.triangles, origin, size,
                             self.config.silhouette.resolution)


def silhouette_of(vertices: np.ndarray, triangles: np.ndarray, origin: tuple[float, float],
                  size: tuple[float, float], resolution: float) -> Silhouette:
    columns = math.ceil(size[0] / resolution)
    rows = math.ceil(size[1] / resolution)
    mask = np.zeros((rows, columns), np.uint8)
    pixels = np.round((vertices[:, :2] - np.asarray(origin)) / resolution).astype(np.int32)
    for triangle in triangles:
        cv2.fillConvexPoly(mask, pixels[triangle], 1)
    contours, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    polygon = np.zeros((0, 2))
    if contours:
        largest = max(contours, key=cv2.contourArea).reshape(-1, 2)
        polygon = largest * resolution + np.asarray(origin)
    return Silhouette(mask, (float(origin[0]), float(origin[1])), resolution, polygon)


def polygon_mask(polygon: np.ndarray, like: Silhouette) -> np.ndarray:
    """The mask of a table-frame polygon on `like`'s pixel grid."""
    mask = np.zeros_like(like.mask)
    pixels = np.round((np.asarray(polygon)[:, :2] - np.asarray(like.origin)) / like.resolution)
    cv2.fillPoly(mask, [pixels.astype(np.int32)], 1)
    return mask
