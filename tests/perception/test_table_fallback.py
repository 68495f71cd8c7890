"""A table model that does not describe the image is replaced by one fitted to the image itself."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from cell.perception.pipeline import describes_border, perceive
from tests.perception.scenes import garment_scene


def _other_table(img: np.ndarray) -> np.ndarray:
    """The same scene under another light and on another table: every channel rescaled, rotated."""
    gains = np.array([1.25, 0.8, 0.55])
    return np.clip(img[..., [1, 2, 0]].astype(float) * gains, 0, 255).astype(np.uint8)


def test_matching_table_keeps_the_model(fitted_perception) -> None:
    cfg, table, _ = fitted_perception
    img = garment_scene("towel", 11).image
    assert describes_border(img, table, cfg) >= cfg.table_fallback.min_table_fraction
    assert describes_border(_other_table(img), table, cfg) < cfg.table_fallback.min_table_fraction


def test_other_table_is_fitted_from_the_image(fitted_perception, caplog) -> None:
    cfg, table, models = fitted_perception
    errors = []
    for category in ("towel", "pants", "short-sleeve"):
        scene = garment_scene(category, 12)
        with caplog.at_level(logging.WARNING, logger="cell.perception.pipeline"):
            obs = perceive(_other_table(scene.image), table, models, cfg, category)
        assert "fitting one to this image" in caplog.text
        truth = scene.garment.truth()
        errors += [np.linalg.norm(np.subtract(obs.landmarks[n], truth[n])) for n in scene.garment.names]
    assert np.median(errors) < 2.0   # 1.2 px


def test_fallback_can_be_switched_off(fitted_perception) -> None:
    from dataclasses import replace

    from cell.perception.errors import PerceptionError
    cfg, table, models = fitted_perception
    cfg = replace(cfg, table_fallback=replace(cfg.table_fallback, enabled=False))
    with pytest.raises(PerceptionError):
        perceive(_other_table(garment_scene("towel", 13).image), table, models, cfg, "towel")


def test_a_table_of_another_laminate_is_fitted_from_the_image(fitted_perception, caplog) -> None:
    """The sim's table drawn as a grey laminate under its own light (planks, grain, seams kept):
    the fitted wooden table's model does not describe it; the image's own border does."""
    from dataclasses import replace

    from drivers.sim.config import default_sim_config
    cfg, table, models = fitted_perception
    sim = default_sim_config()
    grey = replace(sim.render.table_look, seed=4242, wood_bgr=((170.0, 172.0, 172.0), (190.0, 192.0, 192.0)))
    sim = replace(sim, render=replace(sim.render, table_look=grey))
    errors = []
    for category in ("pants", "long-sleeve"):
        scene = garment_scene(category, 14, sim)
        assert describes_border(scene.image, table, cfg) < cfg.table_fallback.min_table_fraction
        with caplog.at_level(logging.WARNING, logger="cell.perception.pipeline"):
            obs = perceive(scene.image, table, models, cfg, category)
        assert "fitting one to this image" in caplog.text
        truth = scene.garment.truth()
        errors += [np.linalg.norm(np.subtract(obs.landmarks[n], truth[n])) for n in scene.garment.names]
    assert np.median(errors) < 3.0
