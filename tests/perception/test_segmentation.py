"""Table colour model and segmentation on rendered images, including strong uneven light."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cell.perception.config import PerceptionConfig
from cell.perception.errors import GarmentTouchesBorder, ImageError, NoGarmentFound
from cell.perception.segmentation import segment
from cell.perception.synthetic import IMAGE_SIZE, illumination, random_garment, render
from cell.perception.table_model import (
    binary_split_init,
    fit_gmm,
    fit_table_model,
    gaussian_log_likelihood,
    table_model_from_fields,
)
from drivers.common.configfile import ConfigError, Fields

CFG = PerceptionConfig()


def _gradient_light(strength: float = 0.8) -> np.ndarray:
    """A strong ramp (dark left, bright right) times a bright spot: 0.5x to 1.5x."""
    w, h = IMAGE_SIZE
    ramp = np.linspace(1 - strength / 2, 1 + strength / 2, w, dtype=np.float32)[None, :].repeat(h, 0)
    return ramp * illumination(IMAGE_SIZE, 0.3, (0.7, 0.3))


@pytest.fixture(scope="module")
def lit() -> tuple[np.ndarray, object]:
    light = _gradient_light()
    rng = np.random.default_rng(0)
    tables = [render(None, rng, light=light) for _ in range(3)]
    return light, fit_table_model(tables, None, CFG)


def _truth_mask(g) -> np.ndarray:  # noqa: ANN001
    m = np.zeros(IMAGE_SIZE[::-1], np.uint8)
    cv2.fillPoly(m, [np.round(g.outline * 16).astype(np.int32)], 1, shift=4)
    return m.astype(bool)


def test_binary_split_and_em() -> None:
    rng = np.random.default_rng(1)
    centres = ([50, 60, 70], [120, 100, 90], [200, 210, 190])
    x = np.concatenate([rng.normal(c, 2.0, (400, 3)) for c in centres])
    labels = binary_split_init(x, 3)
    # each true cluster ends up in one initial cell
    for block in range(3):
        assert len(set(labels[block * 400:(block + 1) * 400])) == 1
    w, mu, cov = fit_gmm(x, 3, 50, 1e-3)
    assert np.allclose(np.sort(w), 1 / 3, atol=0.01)
    assert np.allclose(sorted(mu[:, 0]), [50, 120, 200], atol=1.0)
    ll = gaussian_log_likelihood(x, w, mu, cov)
    # EM never does worse than its initial state (the split clusters with unit responsibilities)
    init_mu = np.array([x[labels == c].mean(0) for c in range(3)])
    init_cov = np.array([np.cov(x[labels == c].T) for c in range(3)])
    init_w = np.bincount(labels) / len(x)
    assert ll.mean() >= gaussian_log_likelihood(x, init_w, init_mu, init_cov).mean() - 1e-9


@pytest.mark.parametrize("category", ["towel", "short-sleeve", "pants"])
def test_segmentation_under_strong_light_gradient(lit, category: str) -> None:  # noqa: ANN001
    light, model = lit
    rng = np.random.default_rng(7)
    for colour in [(40, 40, 170), (70, 70, 70), (235, 235, 235)]:
        g = random_garment(category, rng)
        img = render(g, rng, light=light, colour=colour)
        seg = segment(img, model, CFG.segmentation)
        truth = _truth_mask(g)
        iou = (seg.mask & truth).sum() / (seg.mask | truth).sum()
        assert iou > 0.97, (category, colour, iou)
        # the contour is the border of the full-resolution mask
        assert seg.contour[:, 0].max() < IMAGE_SIZE[0] and len(seg.contour) > 100


def test_gain_grid_learns_the_light(lit) -> None:  # noqa: ANN001
    _, model = lit
    assert model.gain[:, -1].mean() / model.gain[:, 0].mean() > 2.0   # the ramp: right much brighter


def test_no_garment_and_border_and_bad_images(lit) -> None:  # noqa: ANN001
    light, model = lit
    rng = np.random.default_rng(9)
    with pytest.raises(NoGarmentFound):
        segment(render(None, rng, light=light), model, CFG.segmentation)
    g = random_garment("towel", rng)
    shifted = type(g)(g.category, g.names, g.landmarks, g.outline - g.outline.min(axis=0) + [-30, 200])
    with pytest.raises(GarmentTouchesBorder):
        segment(render(shifted, rng, light=light, colour=(40, 40, 170)), model, CFG.segmentation)
    with pytest.raises(ImageError):
        segment(np.zeros((0, 0, 3), np.uint8), model, CFG.segmentation)
    with pytest.raises(ImageError):
        segment(np.zeros((10, 10), np.uint8), model, CFG.segmentation)


def test_table_model_yaml_round_trip_and_errors(lit) -> None:  # noqa: ANN001
    _, model = lit
    back = table_model_from_fields(Fields(model.to_dict(), "t.yaml"))
    assert np.allclose(back.means, model.means) and back.threshold_fg == pytest.approx(model.threshold_fg)
    broken = model.to_dict()
    del broken["covariances"]
    with pytest.raises(ConfigError, match="covariances: missing"):
        table_model_from_fields(Fields(broken, "t.yaml"))


def test_changed_light_and_glare_are_absorbed() -> None:
    """Trained under one light; tested with a moved, brighter spot that clips the table (glare)."""
    rng = np.random.default_rng(31)
    model = fit_table_model([render(None, rng) for _ in range(3)], None, CFG)
    light = illumination(IMAGE_SIZE, 0.7, (0.62, 0.38)) * 1.12
    cases = [("short-sleeve", (60, 130, 40)), ("towel", (140, 50, 120)), ("pants", (70, 70, 70))]
    for category, colour in cases:
        g = random_garment(category, rng)
        img = render(g, rng, light=light, colour=colour)
        assert (img.max(axis=2) >= 250).mean() > 0.01      # the glare really clips
        seg = segment(img, model, CFG.segmentation)
        truth = _truth_mask(g)
        iou = (seg.mask & truth).sum() / (seg.mask | truth).sum()
        assert iou > 0.95, (category, iou)
