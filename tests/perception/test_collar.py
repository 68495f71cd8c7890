"""Shirts whose collar stands out above the neckline with corners as sharp as a shoulder's, the
wearer's-left shoulder sagging beside it, as the dataset's wrinkled polo cloA01158 lies: the shipped
shirt models name the shoulders, not the collar's corners. The ground truth is the real annotation's
nodes, and the nodes of collared garments of the simulated world with that shoulder made to sag, each
outline traced as a segmentation would."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from numpy.typing import NDArray

from cell.perception.config import PerceptionConfig, load_perception_config
from cell.perception.models import PolygonalModel
from cell.perception.pipeline import load_garment_models, match_outline, outline_of_contour
from drivers.common.garments import mirror_name
from drivers.sim.config import default_sim_config
from drivers.sim.garments import make_garment
from tests.perception import real_shapes
from tests.perception.scenes import CAMERA, VIEW

SHOULDERS = ("left-shoulder", "right-shoulder")
MAX_ERROR_CM = 1.0
CM_PER_PX = 100.0 * CAMERA.pixel_size_at_table()


@pytest.fixture(scope="module")
def shipped():
    cfg = load_perception_config()
    return cfg, load_garment_models(cfg)


def shoulder_errors_px(contour: NDArray, truth: dict[str, NDArray], model: PolygonalModel,
                       cfg: PerceptionConfig) -> list[float]:
    observation = match_outline(outline_of_contour(contour, cfg, [model]), {model.category: model}, cfg)
    return [float(np.linalg.norm(np.asarray(observation.landmarks[name]) - truth[name]))
            for name in SHOULDERS]


def test_the_real_wrinkled_polo_s_shoulders_are_not_its_collar_s_corners(shipped) -> None:
    cfg, models = shipped
    rng = np.random.default_rng(28)
    polo = real_shapes.CLOPEMA_POLO - real_shapes.CLOPEMA_POLO.mean(axis=0)
    for turn in range(8):
        mirrored, scale = bool(turn % 2), float(rng.uniform(0.6, 1.2))
        points = real_shapes.posed(polo, float(rng.uniform(0, 2 * np.pi)), mirrored, scale, (900.0, 900.0))
        # perception names the garment as if it lay face up: a mirrored one by its mirrored names
        truth = {(mirror_name(n) if mirrored else n): p
                 for n, p in zip(real_shapes.CLOPEMA_POLO_NAMES, points, strict=True)}
        errors = shoulder_errors_px(real_shapes.traced(points), truth, models["short-sleeve"], cfg)
        assert max(errors) * real_shapes.CLOPEMA_CM_PER_PX / scale <= MAX_ERROR_CM, (turn, errors)


def sagging(names: list[str], points: NDArray, fraction: float) -> NDArray:
    """The nodes with the wearer's-left shoulder moved `fraction` of the way towards the line from the
    neckline's end to the sleeve's outer corner (a wrinkled shoulder, nearly straight)."""
    out = points.copy()
    shoulder = names.index("left-shoulder")
    start, end = out[names.index("neckline-left")], out[names.index("left-sleeve-outer")]
    along = end - start
    foot = start + np.dot(out[shoulder] - start, along) / np.dot(along, along) * along
    out[shoulder] += fraction * (foot - out[shoulder])
    return out


@pytest.mark.parametrize("category", ["short-sleeve", "long-sleeve"])
def test_collared_shirts_with_a_sagging_shoulder_get_their_shoulders(shipped, category: str) -> None:
    """Collars as wide as the simulated world draws them (corners pulled out towards the shoulders)."""
    cfg, models = shipped
    sim = default_sim_config()
    wide = replace(sim, edges=replace(sim.edges, collar_corners=(0.8, sim.edges.collar_corners[1])))
    rng = np.random.default_rng(28)
    for index in range(20):
        garment = make_garment(category, rng, wide, VIEW, shape="wrinkled", collared=True)
        names = list(garment.node_names)
        points = sagging(names, CAMERA.table_to_pixel(garment.nodes()), 0.7)
        seen = names if garment.facing == "front" else [mirror_name(name) for name in names]
        errors = shoulder_errors_px(real_shapes.traced(points), dict(zip(seen, points, strict=True)),
                                    models[category], cfg)
        assert max(errors) * CM_PER_PX <= MAX_ERROR_CM, (index, errors)
