"""The cloth physics: a fold's result depends on its path, a grasp in the air holds nothing, and the
physics configuration names a wrong field."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from drivers.common.configfile import ConfigError, Fields, config_dir, load_yaml
from drivers.sim.physics.cloth import ClothWorld
from drivers.sim.physics.config import load_physics_config, physics_from_fields
from drivers.sim.physics.measure import fold_square_in_half

SIDE = 0.5
# the planner's grasp: 1.5 cm inside the corner, the fingers 5 mm above the table (config/planning.yaml)
INSET = 0.015
HEIGHT = 0.005


@pytest.fixture(scope="module")
def sensible_fold_iou() -> float:
    return fold_square_in_half(SIDE, 0.3, load_physics_config(), grasp_inset=INSET,
                               grasp_height=HEIGHT).iou


def test_a_flat_square_covers_its_area() -> None:
    world = ClothWorld(SIDE, SIDE, load_physics_config())
    world.step_for(0.5)
    silhouette = world.silhouette((-SIDE, -SIDE), (2 * SIDE, 2 * SIDE))
    covered = np.count_nonzero(silhouette.mask) * silhouette.resolution ** 2
    assert covered == pytest.approx(SIDE * SIDE, rel=0.03)
    xs, ys = silhouette.polygon[:, 0], silhouette.polygon[:, 1]
    assert (xs.min(), ys.min()) == pytest.approx((-SIDE / 2, -SIDE / 2), abs=0.005)
    assert (xs.max(), ys.max()) == pytest.approx((SIDE / 2, SIDE / 2), abs=0.005)


def test_a_fold_along_a_sensible_path_lands_on_the_ideal_half(sensible_fold_iou: float) -> None:
    assert sensible_fold_iou >= 0.9


def test_an_apex_far_too_low_drags_the_cloth(sensible_fold_iou: float) -> None:
    low = fold_square_in_half(SIDE, 0.05, load_physics_config(), grasp_inset=INSET, grasp_height=HEIGHT)
    assert low.iou < sensible_fold_iou - 0.05, (low.iou, sensible_fold_iou)


def test_a_grasp_3_cm_above_the_cloth_lifts_nothing() -> None:
    world = ClothWorld(SIDE, SIDE, load_physics_config())
    world.step_for(0.3)
    before = world.vertices
    half = SIDE / 2 - INSET
    result = world.fold(np.array([[-half, -half], [half, -half]]), np.array([[-half, half], [half, half]]),
                        0.3, grasp_height=float(before[:, 2].max()) + 0.03)
    assert result.pinched == ()
    assert np.linalg.norm(result.vertices - before, axis=1).max() < 0.01


def test_a_grasp_at_the_cloth_holds_the_corner_vertices() -> None:
    world = ClothWorld(SIDE, SIDE, load_physics_config())
    half = SIDE / 2 - INSET
    world.move_grippers(np.array([[-half, -half, HEIGHT], [half, -half, HEIGHT]]))
    held = world.close(0)
    corner = int(np.argmin(np.linalg.norm(world.vertices[:, :2] - [-SIDE / 2, -SIDE / 2], axis=1)))
    assert corner in held


@pytest.mark.parametrize(("section", "field", "value", "reason"), [
    ("cloth", "friction", -0.1, "must be >= 0"),
    ("cloth", "areal_density", 0, "must be > 0"),
    ("gripper", "max_pinched", 2.5, "must be an integer"),
    ("simulation", "timestep", "fast", "must be a finite number"),
    ("silhouette", "pixels", 3, "unknown field"),
])
def test_bad_physics_config_names_the_field(section: str, field: str, value: object, reason: str) -> None:
    shipped = load_yaml(config_dir() / "physics.yaml")
    data = {name: dict(fields) for name, fields in shipped.data.items()}
    data[section][field] = value
    with pytest.raises(ConfigError) as caught:
        physics_from_fields(Fields(data, "physics.yaml"))
    assert f"{section}.{field}" in str(caught.value) and reason in str(caught.value)


def test_the_shipped_config_is_frozen() -> None:
    config = load_physics_config()
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.cloth.friction = 0.1  # type: ignore[misc]
