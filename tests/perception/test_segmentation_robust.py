"""Segmentation on the simulated cell's hard cases: table-coloured garments on the bright,
partly clipped centre of the table (a camera exposed too brightly), and dark garments of the
wood's hue (the per-image light correction must not take them for the table in a shadow)."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from cell.perception.config import load_perception_config
from cell.perception.pipeline import load_table_model
from cell.perception.segmentation import light_correction, segment
from cell.perception.table_model import fit_table_model, ray_mahalanobis2
from drivers.sim.config import SimConfig, default_sim_config
from drivers.sim.dataset import build_world, recipe_folds

CFG = load_perception_config()


@pytest.fixture(scope="module")
def model():
    return load_table_model(config=CFG)


def _truth(world) -> np.ndarray:
    """The sim's true silhouette (union of the cloth layers) in image pixels."""
    m = np.zeros((1024, 1280), np.uint8)
    for layer in world.layers:
        px = world.camera.table_to_pixel(layer.polygon)
        cv2.fillPoly(m, [np.round(px * 16).astype(np.int32)], 1, shift=4)
    return m.astype(bool)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_ray_distance_ignores_brightness_and_finds_it() -> None:
    rng = np.random.default_rng(3)
    for _ in range(50):
        k = int(rng.integers(1, 4))
        means = rng.uniform(60, 220, (k, 3))
        covs = []
        for _c in range(k):
            a = rng.normal(0, 1, (3, 3))
            covs.append(a @ a.T + np.eye(3))
        covs = np.array(covs)
        x = rng.uniform(20, 250, (200, 3))
        m2, scale = ray_mahalanobis2(x, np.full(k, 1 / k), means, covs)
        s = rng.uniform(0.3, 3.0)
        m2s, scale_s = ray_mahalanobis2(x * s, np.full(k, 1 / k), means, covs)
        # light scales a colour: the distance does not change, the brightness scales with it
        # (float32: c - b^2/a cancels, hence the absolute tolerance)
        assert np.allclose(m2s, m2, rtol=1e-3, atol=0.05)
        # (the nearest component may switch between near ties; rays pointing away from every
        # mean have no brightness)
        best = np.isfinite(m2)
        if k == 1:
            assert np.allclose(scale_s[best], scale[best] * s, rtol=1e-3)
        # a component's mean at any brightness is at distance 0 with that brightness
        m0, s0 = ray_mahalanobis2(means * s, np.full(k, 1 / k), means, covs)
        assert np.all(m0 < 0.05) and np.allclose(s0, s, rtol=1e-3)
        # and no ray is closer than the direct Mahalanobis distance at scale 1 allows
        d = x[:, None, :] - means[None]
        direct = np.einsum("nkd,kde,nke->nk", d, np.linalg.inv(covs), d).min(axis=1)
        assert np.all(m2[best] <= direct[best] * (1 + 1e-3) + 0.05)


def _over_exposed() -> SimConfig:
    """The sim's camera exposed too brightly: the bright centre of the table clips its red channel."""
    cfg = default_sim_config()
    return replace(cfg, render=replace(cfg.render, light_gain=1.0, bright_gain=0.36))


@pytest.fixture(scope="module")
def over_exposed_model():
    """The table model of that camera, learned from empty tables as `foldcell table fit` does."""
    return fit_table_model([build_world(s, "towel", config=_over_exposed()).render_empty_table()
                            for s in range(3)], None, CFG)


# table-coloured cloth over the bright band where the table's red channel clips
@pytest.mark.parametrize("spec", ["pants/15", "towel/13"])
def test_pale_table_coloured_garment_on_the_bright_band(over_exposed_model, spec: str) -> None:
    cat, seed = spec.split("/")
    world = build_world(int(seed), cat, config=_over_exposed())
    img = world.render()
    assert ((img >= 250).sum(axis=2) >= 2).mean() > 0.02     # the centre really clips
    seg = segment(img, over_exposed_model, CFG.segmentation)
    assert _iou(seg.mask, _truth(world)) >= 0.95, spec


# dark garments of about the wood's hue: the light correction must not fit them as table
@pytest.mark.parametrize("spec", ["pants/2", "long-sleeve/2"])
def test_dark_wood_hued_garment_is_not_a_shadow(model, spec: str) -> None:
    cat, seed = spec.split("/")
    world = build_world(int(seed), cat)
    img = world.render()
    truth = _truth(world)
    w, h = CFG.segmentation.work_size
    small = cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
    corr = light_correction(small, model, CFG.segmentation)
    inside = cv2.resize(truth.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    # the correction is a light change, not the garment's darkness
    assert np.abs(corr).max() <= CFG.segmentation.light_max_log_change + 1e-6
    assert abs(float(np.median(corr[inside]))) < 0.3
    seg = segment(img, model, CFG.segmentation)
    assert _iou(seg.mask, truth) >= 0.95, spec


# a pale towel on pale wood, folded twice: its sure-garment pixels are speckles (no 5 px block of them)
@pytest.mark.parametrize("spec", ["towel/77"])
def test_a_small_folded_garment_close_to_the_table_colour_is_found(model, spec: str) -> None:
    cat, seed = spec.split("/")
    world = build_world(int(seed), cat)
    for moves in recipe_folds(world, 2):
        world.apply_fold(moves)
    truth = _truth(world)
    assert truth.mean() < 0.06          # a small garment: a quarter of a towel
    seg = segment(world.render(), model, CFG.segmentation)   # it was "no garment in the image"
    outline = np.zeros(truth.shape, np.uint8)
    cv2.fillPoly(outline, [np.round(seg.contour).astype(np.int32).reshape(-1, 1, 2)], 1)
    # its edge is speckled like the table, and the outline cuts into it (about 0.80 on this one)
    assert _iou(outline.astype(bool), truth) >= 0.75, spec
