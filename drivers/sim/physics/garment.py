"""A garment's cloth in the physics world, driven by the recorded motion of the grippers.

The world integrates lazily: gripper positions (robot time, table frame) and gripper events are
recorded as they arrive, and `catch_up` simulates what has been recorded when somebody looks (a
capture, the ground truth), so the simulation need not keep pace with the controller. Between a
grasp and the release that ends it the grippers follow the recorded positions, linearly
interpolated in robot time, so the result depends on the path and its timing, never on the wall
clock or the demo's time scale. While no gripper holds cloth it lies still and nothing is simulated.
"""

from __future__ import annotations

import bisect
import math
import threading
from dataclasses import dataclass, field

import cv2
import numpy as np

from drivers.common.plane import FoldLine
from drivers.sim.folding import Layer
from drivers.sim.physics.cloth import ClothWorld, Silhouette, silhouette_of, triangular_path
from drivers.sim.physics.config import PhysicsConfig
from drivers.sim.physics.mesh import cut_mesh


@dataclass(frozen=True)
class PinchResult:
    """What one gripper closing took: the vertices under its fingers (none: it missed)."""

    arm: str
    time: float
    position: np.ndarray          # table frame x, y, z of the fingers
    vertices: tuple[int, ...]


@dataclass(frozen=True)
class Episode:
    """One grasp-to-release: where each gripper that took cloth closed and opened (table x, y)."""

    moves: list[tuple[np.ndarray, np.ndarray]]
    pinches: list[PinchResult]
    peak_height: float | None   # m above the table: the highest a gripper holding cloth went (None:
                                # no path was heard while it held: the events alone)
    start_xy: np.ndarray        # (n, 2) m: the cloth's vertices (table x, y) when the first gripper closed


@dataclass
class _Recording:
    times: list[float] = field(default_factory=list)
    positions: list[np.ndarray] = field(default_factory=list)   # (arms, 3) per time
    events: list[tuple[float, str, bool, np.ndarray]] = field(default_factory=list)


class GarmentCloth:
    """The cloth of one garment (cut from `outline`, table frame) and the grippers of `arms`."""

    def __init__(self, outline: np.ndarray, config: PhysicsConfig, arms: tuple[str, ...],
                 corners: list[int] | None = None, creases: tuple[FoldLine, ...] = ()):
        """`corners`: indices of outline vertices the mesh keeps (landmarks); the rest of the outline
        is resampled about a vertex spacing apart. `creases`: lines the mesh has vertices along."""
        self.config = config
        self.arms = arms
        self.mesh = cut_mesh(outline, config.cloth.vertex_spacing, corners, creases)
        self.world = ClothWorld(self.mesh, config, len(arms))
        self.time: float | None = None           # robot time simulated up to (s), None: at rest
        self._recording = _Recording()
        # recording happens on the wire's threads while `catch_up` simulates on another
        self._lock = threading.Lock()
        self._closed: dict[str, PinchResult] = {}
        self._grasp_at: dict[str, np.ndarray] = {}
        self._episode_moves: list[tuple[np.ndarray, np.ndarray]] = []
        self._episode_pinches: list[PinchResult] = []
        self._episode_peak: float | None = None
        self._episode_start: np.ndarray | None = None    # the cloth's vertices (x, y) at the episode's start
        self.pinch_log: list[PinchResult] = []
        # arm -> the robot time up to which its gripper's events are all here: the joint states and
        # the gripper events come on different streams, and a release heard late must not let the
        # cloth be carried along the path after it (arms never heard from do not hold anything)
        self._heard: dict[str, float] = {}

    # --- recording ---------------------------------------------------------------------------
    def record_motion(self, time: float, positions: dict[str, np.ndarray]) -> None:
        """The grippers' positions (table frame x, y, z) at robot time `time` (s)."""
        rec = self._recording
        row = np.array([positions[arm] for arm in self.arms], dtype=float)
        with self._lock:
            if rec.times and time <= rec.times[-1]:
                return                               # late or repeated: the path is already known
            rec.times.append(time)
            rec.positions.append(row)
            if not rec.events and not self._closed:
                # at rest: only the recent path matters (a grasp may be heard after the arm moved on)
                stale = bisect.bisect_left(rec.times, time - self.config.simulation.path_memory)
                del rec.times[:stale]
                del rec.positions[:stale]

    def record_gripper(self, time: float, arm: str, closed: bool, position: np.ndarray) -> None:
        """Gripper `arm` closed or opened at robot time `time` with its fingers at `position`."""
        with self._lock:
            bisect.insort(self._recording.events, (time, arm, closed, np.asarray(position, dtype=float)),
                          key=lambda event: event[0])
            self._heard[arm] = max(self._heard.get(arm, time), time)

    def record_heard(self, arm: str, time: float) -> None:
        """Gripper `arm`'s events up to robot time `time` have all been recorded (its state was heard
        unchanged at `time`)."""
        with self._lock:
            self._heard[arm] = max(self._heard.get(arm, time), time)

    def _heard_until(self) -> float:
        with self._lock:
            return min(self._heard.values(), default=math.inf)

    # --- simulation --------------------------------------------------------------------------
    def busy(self) -> bool:
        """Cloth is held or an event waits to be simulated."""
        return bool(self._closed or self._recording.events)

    def holding(self) -> dict[str, np.ndarray]:
        """Arms holding cloth (as simulated so far) and where they closed (table x, y)."""
        return {arm: point.copy() for arm, point in self._grasp_at.items()}

    def catch_up(self) -> Episode | None:
        """Simulate the recorded motion up to the end of the first episode (grasp to release) it
        completes, or else up to the last recorded event and position; the episode completed."""
        rec = self._recording
        while rec.events:
            with self._lock:
                when, arm, closed, position = rec.events[0]
            if when > self._heard_until():
                break                                # another gripper's events up to then are on their way
            if self.time is None:
                self.time = when
                self._place_grippers(when)
            self._advance_to(when)
            with self._lock:
                rec.events.pop(0)
            self._set_gripper(arm, position)
            if closed:
                self._close(arm, when, position)
            elif arm in self._closed:
                self._open(arm, position)
                if not self._closed:
                    self.world.step_for(self.config.simulation.settle)
                    start = self._episode_start if self._episode_start is not None else self._xy()
                    episode = Episode(self._episode_moves, self._episode_pinches, self._episode_peak, start)
                    self._episode_moves, self._episode_pinches, self._episode_peak = [], [], None
                    self._episode_start = None
                    self.time = None
                    self._forget_until(when)
                    return episode
        if self._closed and rec.times:
            self._advance_to(min(rec.times[-1], self._heard_until()))
        return None

    def _xy(self) -> np.ndarray:
        return self.vertices[:, :2].copy()

    def _close(self, arm: str, when: float, position: np.ndarray) -> None:
        if arm in self._closed:
            return
        if self._episode_start is None:
            self._episode_start = self._xy()
        vertices = self.world.close(self.arms.index(arm))
        pinch = PinchResult(arm, when, position.copy(), vertices)
        self.pinch_log.append(pinch)
        self._episode_pinches.append(pinch)
        if vertices:
            self._closed[arm] = pinch
            self._grasp_at[arm] = position[:2].copy()

    def _open(self, arm: str, position: np.ndarray) -> None:
        self.world.open(self.arms.index(arm))
        self._closed.pop(arm)
        self._episode_moves.append((self._grasp_at.pop(arm), position[:2].copy()))

    def _forget_until(self, when: float) -> None:
        rec = self._recording
        with self._lock:
            keep = bisect.bisect_left(rec.times, when)
            del rec.times[:max(0, keep - 1)]
            del rec.positions[:max(0, keep - 1)]

    def _positions_at(self, when: float) -> np.ndarray | None:
        rec = self._recording
        if not rec.times:
            return None
        index = bisect.bisect_right(rec.times, when)
        if index == 0:
            return rec.positions[0]
        if index == len(rec.times):
            return rec.positions[-1]
        before, after = rec.times[index - 1], rec.times[index]
        weight = (when - before) / (after - before)
        return (1.0 - weight) * rec.positions[index - 1] + weight * rec.positions[index]

    def _place_grippers(self, when: float) -> None:
        positions = self._positions_at(when)
        if positions is not None:
            for gripper, mocap in enumerate(self.world.gripper_mocap):
                self.world.data.mocap_pos[mocap] = positions[gripper]

    def _set_gripper(self, arm: str, position: np.ndarray) -> None:
        self.world.data.mocap_pos[self.world.gripper_mocap[self.arms.index(arm)]] = position

    def _advance_to(self, when: float) -> None:
        """Step the cloth from `self.time` to `when`, the grippers on the recorded path."""
        assert self.time is not None
        timestep = self.config.simulation.timestep
        steps = math.floor((when - self.time) / timestep + 1e-9)
        if steps <= 0:
            return
        if not self._closed:
            self.time += steps * timestep            # nothing holds the cloth: it lies still
            return
        holding = [self.arms.index(arm) for arm in self._closed]
        for _ in range(steps):
            self.time += timestep
            positions = self._positions_at(self.time)
            if positions is not None:
                height = float(np.max(positions[holding, 2]))
                self._episode_peak = height if self._episode_peak is None else max(self._episode_peak, height)
                self.world.move_grippers(positions)
            else:
                self.world.step_for(timestep)

    # --- a whole fold along a triangular path (datasets, `sim fold`) --------------------------
    def fold_along(self, moves: list[tuple[np.ndarray, np.ndarray]], lift_fraction: float,
                   height: float) -> Episode | None:
        """Fold by `moves` (grasp, place, table x, y), the grippers on triangular paths at the
        configured speed `height` above the table, as a planner would send them."""
        settings = self.config.gripper
        step = 0.01                                  # s between recorded path points
        rec = self._recording
        start = rec.times[-1] + step if rec.times else 0.0
        starts = [np.array([*grasp, height]) for grasp, _ in moves]
        ends = [np.array([*place, height]) for _, place in moves]
        paths = [np.vstack([a, triangular_path(a, b, lift_fraction * float(np.linalg.norm(b - a)),
                                               settings.speed * step)])
                 for a, b in zip(starts, ends, strict=True)]
        count = max(len(path) for path in paths)
        resting = [self.world.data.mocap_pos[m].copy() for m in self.world.gripper_mocap][len(moves):]
        for arm, point in zip(self.arms, starts, strict=False):
            self.record_gripper(start, arm, True, point)
        for index in range(count):
            row = [path[index * len(path) // count] for path in paths] + resting
            self.record_motion(start + settings.dwell + index * step,
                               dict(zip(self.arms, row, strict=True)))
        end = start + 2 * settings.dwell + count * step
        for arm, point in zip(self.arms, ends, strict=False):
            self.record_gripper(end, arm, False, point)
        return self.catch_up()

    # --- what is seen ------------------------------------------------------------------------
    @property
    def vertices(self) -> np.ndarray:
        return self.world.vertices

    def silhouette(self, origin: tuple[float, float], size: tuple[float, float]) -> Silhouette:
        return silhouette_of(self.vertices, self.mesh.triangles, origin, size,
                             self.config.silhouette.resolution)

    def layer_count(self, origin: tuple[float, float], size: tuple[float, float]) -> int:
        """The most cloth layers over one point of the table (the triangles stacked there)."""
        resolution = self.config.silhouette.resolution
        columns, rows = math.ceil(size[0] / resolution), math.ceil(size[1] / resolution)
        count = np.zeros((rows, columns), np.uint8)
        pixels = (self.vertices[:, :2] - np.asarray(origin)) / resolution
        for triangle in self.mesh.triangles:
            # each triangle shrunk by 1.5 px towards its centre: neighbours in one layer share an edge,
            # which must not count twice
            corners = pixels[triangle]
            centre = corners.mean(axis=0)
            span = np.linalg.norm(corners - centre, axis=1, keepdims=True)
            shrink = np.clip(1.0 - 1.5 * 2.0 / np.maximum(span, 1e-9), 0.0, 1.0)
            corners = centre + (corners - centre) * shrink
            mask = np.zeros_like(count)
            cv2.fillConvexPoly(mask, np.round(corners).astype(np.int32), 1)
            count += mask
        # a count must cover some area: a crease stacks slivers of triangles on a line
        least = self.config.silhouette.layer_area / resolution ** 2
        return max((k for k in range(1, int(count.max()) + 1) if np.count_nonzero(count >= k) >= least),
                   default=0)

    def render_layers(self, resolution: float) -> list[Layer]:
        """The cloth as planar layers for the renderer, lowest first: connected pieces of triangles
        facing the same way (inside up or outside up), ordered by their height."""
        vertices = self.vertices
        triangles = self.mesh.triangles
        first, second, third = (vertices[triangles[:, k]] for k in range(3))
        normal_z = ((second - first)[:, 0] * (third - first)[:, 1]
                    - (second - first)[:, 1] * (third - first)[:, 0])
        flipped = normal_z < 0.0
        pieces = _connected_pieces(triangles, flipped)
        layers: list[tuple[float, Layer]] = []
        low = vertices[:, :2].min(axis=0) - 2 * resolution
        size = vertices[:, :2].max(axis=0) - low + 4 * resolution
        for piece in pieces:
            polygon = _outline(vertices, triangles[piece], tuple(low), tuple(size), resolution)
            if polygon is not None:
                height = float(vertices[triangles[piece]][:, :, 2].mean())
                layers.append((height, Layer(polygon, bool(flipped[piece[0]]))))
        layers.sort(key=lambda item: item[0])
        return [layer for _, layer in layers]


def _connected_pieces(triangles: np.ndarray, flipped: np.ndarray) -> list[np.ndarray]:
    """Triangles grouped into pieces connected through shared edges and facing alike."""
    parent = list(range(len(triangles)))

    def root(index: int) -> int:
        while parent[index] != index:
            parent[index] = parent[parent[index]]
            index = parent[index]
        return index

    owner: dict[tuple[int, int], int] = {}
    for index, triangle in enumerate(triangles):
        for a, b in ((0, 1), (1, 2), (2, 0)):
            edge = (int(min(triangle[a], triangle[b])), int(max(triangle[a], triangle[b])))
            other = owner.setdefault(edge, index)
            if other != index and flipped[other] == flipped[index]:
                parent[root(index)] = root(other)
    groups: dict[int, list[int]] = {}
    for index in range(len(triangles)):
        groups.setdefault(root(index), []).append(index)
    return [np.array(group) for group in groups.values()]


def _outline(vertices: np.ndarray, triangles: np.ndarray, origin: tuple[float, float],
             size: tuple[float, float], resolution: float) -> np.ndarray | None:
    seen = silhouette_of(vertices, triangles, origin, size, resolution)
    if len(seen.polygon) < 3 or cv2.contourArea(seen.polygon.astype(np.float32)) < 25 * resolution ** 2:
        return None
    return seen.polygon
