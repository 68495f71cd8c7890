"""Images of the simulated world for the perception tests, with their ground truth in image pixels.

Garments, their landmarks and the rendering all come from `drivers.sim`, as the cell sees them:
`garment_scene` is scene `seed` of a `dataset generate` run, `ClothScene` lays a cloth outline of
the test's own (pixels) on the sim's table in a colour the test chooses.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from drivers.camera.model import CameraModel
from drivers.common.garments import CATEGORIES, mirror_name
from drivers.robot.table import default_table_config
from drivers.sim.config import SimConfig, default_sim_config
from drivers.sim.dataset import build_world
from drivers.sim.folding import Layer
from drivers.sim.garments import Garment, make_garment
from drivers.sim.render import Appearance, SceneRenderer
from drivers.sim.world import GarmentWorld

CAMERA = CameraModel()   # the fixed camera of the sim's datasets
IMAGE_SIZE = (CAMERA.config.width, CAMERA.config.height)
VIEW = CAMERA.pixel_to_table([[0, 0], [IMAGE_SIZE[0] - 1, 0], [IMAGE_SIZE[0] - 1, IMAGE_SIZE[1] - 1],
                              [0, IMAGE_SIZE[1] - 1]])


@dataclass(frozen=True)
class GarmentPixels:
    """A flat garment in image pixels: its landmarks (in `names` order) and its rippled border."""

    category: str
    names: tuple[str, ...]
    landmarks: NDArray               # (N, 2)
    outline: NDArray                 # (M, 2), through every landmark
    landmark_index: tuple[int, ...]  # index of each landmark in `outline`

    def truth(self) -> dict[str, NDArray]:
        return dict(zip(self.names, self.landmarks, strict=True))


def in_pixels(garment: Garment) -> GarmentPixels:
    return GarmentPixels(garment.category, garment.names, CAMERA.table_to_pixel(garment.landmarks),
                         CAMERA.table_to_pixel(garment.outline), garment.landmark_index)


def random_garment(category: str, rng: np.random.Generator, upright: bool = False,
                   config: SimConfig | None = None) -> GarmentPixels:
    """A garment of the sim's shapes placed in the camera's view (`upright`: not turned)."""
    config = config or default_sim_config()
    if upright:
        config = replace(config, pose=replace(config.pose, rotation=0.0))
    return in_pixels(make_garment(category, rng, config, VIEW))


def landmark_polygons(category: str, count: int, rng: np.random.Generator) -> list[NDArray]:
    """The landmarks (pixels, design order) of `count` random garments: what models are learned from."""
    return [random_garment(category, rng).landmarks for _ in range(count)]


def landmarks_and_neckline(garment: GarmentPixels) -> NDArray:
    """The landmarks and, for a shirt, three points of the neckline between the shoulders (on the
    border, not landmarks, as in real data): a polygon whose vertices are not all landmarks."""
    index = list(garment.landmark_index)
    if "left-shoulder" in garment.names:
        start = index[garment.names.index("left-shoulder")]
        end = index[garment.names.index("right-shoulder")]
        index += [start + (end - start) * k // 4 for k in (1, 2, 3)]
    return garment.outline[sorted(index)]


@dataclass(frozen=True)
class Scene:
    image: NDArray
    garment: GarmentPixels
    world: GarmentWorld


def as_seen(world: GarmentWorld) -> GarmentPixels:
    """The world's flat garment in pixels, named as perception names it: as if it lay face up
    (mirrored when it lies face down)."""
    names, points = world.flat_polygon()
    own = list(world.garment.names)
    face_down = world.garment.facing == "back"
    index = tuple(world.garment.landmark_index[own.index(mirror_name(name) if face_down else name)]
                  for name in names)
    return GarmentPixels(world.garment.category, tuple(names), CAMERA.table_to_pixel(points),
                         CAMERA.table_to_pixel(world.garment.outline), index)


def garment_scene(category: str, seed: int, config: SimConfig | None = None) -> Scene:
    """Scene `seed` of `category` as the cell's camera draws it, with its flat garment in pixels."""
    world = build_world(seed, category, config=config)
    return Scene(world.render(), as_seen(world), world)


def empty_table(seed: int, config: SimConfig | None = None) -> NDArray:
    """The sim's empty table under the light of scene `seed`."""
    world = GarmentWorld(seed=seed, category=CATEGORIES[0], config=config or default_sim_config())
    return world.render_empty_table()


def truth_mask(outline_px: NDArray) -> NDArray:
    """The pixels inside an outline (bool, image size)."""
    mask = np.zeros(IMAGE_SIZE[::-1], np.uint8)
    cv2.fillPoly(mask, [np.round(np.asarray(outline_px) * 16).astype(np.int32)], 1, shift=4)
    return mask.astype(bool)


class ClothScene:
    """The sim's table under the light of `light_seed`; `render` lays cloth of a given colour and
    outline (pixels) on it, with the sim's fabric, shading, shadow, noise and blur."""

    def __init__(self, light_seed: int = 0, config: SimConfig | None = None, fabric_seed: int = 0):
        self.config = config or default_sim_config()
        self.light_seed = light_seed
        self.fabric_seed = fabric_seed
        self._renderers: dict[tuple[float, float, float], SceneRenderer] = {}

    def _renderer(self, colour: tuple[float, float, float]) -> SceneRenderer:
        if colour not in self._renderers:
            look = Appearance(bgr=colour, texture="knit", table_like=False, wrinkled=False,
                              seed=self.fabric_seed)
            self._renderers[colour] = SceneRenderer(self.config.render, default_table_config(), look,
                                                    self.light_seed, CAMERA)
        return self._renderers[colour]

    def render(self, outline_px: NDArray | None,
               colour: tuple[float, float, float] = (40, 40, 170)) -> NDArray:
        """The image of the cloth (None: the empty table)."""
        layers = [] if outline_px is None else [Layer(CAMERA.pixel_to_table(np.asarray(outline_px, float)))]
        return self._renderer(colour).render(layers)
