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


def test_a_garment_in_the_border_ring_makes_the_fitted_model_doubtful(fitted_perception, caplog) -> None:
    """The ring's model was fitted to garment pixels too when the garment lies in the ring: the
    segmentation says so. A garment clear of the ring leaves no doubt."""
    from cell.perception.pipeline import segment_garment
    from tests.perception.scenes import ClothScene
    cfg, table, _ = fitted_perception
    scene = ClothScene(light_seed=3)
    clear = np.array([[300, 250], [900, 250], [900, 750], [300, 750]], float)
    in_ring = np.array([[25, 250], [900, 250], [900, 750], [25, 750]], float)   # the ring is 77 px wide
    assert segment_garment(_other_table(scene.render(clear)), table, cfg).doubt is None
    with caplog.at_level(logging.WARNING, logger="cell.perception.pipeline"):
        doubtful = segment_garment(_other_table(scene.render(in_ring)), table, cfg)
    assert doubtful.doubt is not None and "border" in doubtful.doubt
    assert "in doubt" in caplog.text


def test_a_table_unlike_its_border_makes_the_fitted_model_doubtful(fitted_perception) -> None:
    """Sure-garment pixels by the ring's model scattered over the table around the garment (another
    surface in the middle, light the correction cannot follow) are reported past
    `max_table_unexplained`; as many as a table the model explains has are not."""
    from cell.perception.pipeline import _ring_fit_doubt, border_ring
    from cell.perception.segmentation import Segmentation
    cfg, _, _ = fitted_perception
    fb = cfg.table_fallback
    w, h = cfg.segmentation.work_size
    ring = border_ring((h, w), fb.border_fraction)
    mask = np.zeros((1024, 1280), bool)
    mask[300:700, 400:900] = True
    rng = np.random.default_rng(0)
    for fraction, doubtful in ((0.5 * fb.max_table_unexplained, False), (2 * fb.max_table_unexplained, True)):
        trimap = np.where(rng.random((h, w)) < fraction, 2, 0).astype(np.uint8)
        trimap[75:175, 100:225] = 2       # the garment
        doubt = _ring_fit_doubt(Segmentation(np.zeros((0, 2), int), mask, trimap), ring, fb)
        assert (doubt is not None and "unlike the table" in doubt) == doubtful, (fraction, doubt)
