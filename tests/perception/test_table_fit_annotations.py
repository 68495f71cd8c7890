"""`foldcell table fit --annotations` on annotations written as the CloPeMa dataset writes them: a
folded garment's nodes (fold-line ends, carried corners) are no outline, and a table model fitted
from a mix of flat and folded dark garments still segments a black garment whole."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from numpy.typing import NDArray

from cell.perception.annotations import load_annotations, parse_annotation
from cell.perception.config import load_perception_config
from cell.perception.pipeline import load_table_model
from cell.perception.segmentation import segment, table_log_likelihood
from cell.perception.table_model import annotation_table_mask, fit_table_model
from drivers.sim import dataset as sim_dataset
from drivers.sim.dataset import build_world
from drivers.sim.render import Appearance, SceneRenderer
from drivers.sim.world import GarmentWorld
from tests.perception.scenes import ClothScene, truth_mask
from tools.perception_cli import register

BLACK = (24.0, 24.0, 27.0)
DARK = (48.0, 40.0, 36.0)
# (seed, category, folded, colour); None keeps the scene's own colour
TRAINING = ((301, "pants", True, BLACK), (302, "long-sleeve", True, BLACK), (303, "short-sleeve", True, DARK),
            (304, "towel", False, None), (305, "pants", False, BLACK), (306, "short-sleeve", False, None))
MIN_IOU = 0.95
DATASET_TYPE = {"towel": "towel", "pants": "pants", "short-sleeve": "tshirt", "long-sleeve": "sweater"}


def _render(world: GarmentWorld, colour: tuple[float, float, float] | None, seed: int) -> NDArray:
    """The world's garment, in `colour` if given, on the sim's one table under the light of `seed`."""
    if colour is None:
        return world.render()
    look = Appearance(bgr=colour, texture="twill", table_like=False, wrinkled=False, seed=seed)
    assert world.camera is not None
    return SceneRenderer(world.config.render, world.table, look, seed, world.camera).render(world.layers)


@pytest.fixture(scope="module")
def annotated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("annotated")
    for seed, category, folded, colour in TRAINING:
        world = build_world(seed, category, folded)
        image = f"cloC{seed:05d}.png"
        cv2.imwrite(str(folder / image), _render(world, colour, seed))
        record = sim_dataset.annotation(world, image, DATASET_TYPE[category])      # as the dataset writes it
        record["node_names"] = [[name.replace("right", "rigth")] for (name,) in record["node_names"]]
        (folder / f"cloA{seed:05d}.yaml").write_text(yaml.safe_dump(record))
    return folder


@pytest.fixture(scope="module")
def black_pants() -> tuple[NDArray, NDArray]:
    """A flat black garment none of the training images holds, and its true mask."""
    world = GarmentWorld(seed=310, category="pants")
    assert world.camera is not None
    return _render(world, BLACK, 310), truth_mask(world.camera.table_to_pixel(world.layers[0].polygon))


def _iou(table_model, image: NDArray, truth: NDArray) -> float:
    mask = segment(image, table_model, load_perception_config().segmentation).mask
    return float((mask & truth).sum() / (mask | truth).sum())


def test_folded_nodes_are_no_outline(annotated: Path) -> None:
    """The folded annotations written here are what the dataset's are: their node polygon leaves
    garment out (else this test would not test the folded case)."""
    folded = [a for _, a in load_annotations(annotated) if a.shape == "folded"]
    assert len(folded) == 3 and all(a.fold_lines for a in folded)
    for annotation in folded:
        world = build_world(int(annotation.image[4:9]), annotation.category, True)
        assert world.camera is not None
        garment = np.zeros((1024, 1280), bool)
        for layer in world.layers:
            garment |= truth_mask(world.camera.table_to_pixel(layer.polygon))
        filled = np.zeros(garment.shape, np.uint8)
        cv2.fillPoly(filled, [np.round(annotation.polygon).astype(np.int32)], 1)
        assert (garment & (filled == 0)).sum() > 0.05 * garment.sum()
        # the table mask keeps clear of all of it
        table = annotation_table_mask(annotation, garment.shape, load_perception_config().table)
        assert (table & garment).sum() < 0.001 * garment.sum()


def test_flat_mask_is_the_grown_polygon() -> None:
    square = [[100.0, 100.0], [300.0, 100.0], [300.0, 300.0], [100.0, 300.0]]
    flat = parse_annotation({"path_c": "a.png", "type": "towel", "shape": "flat",
                             "node_names": [["bottom-left"], ["bottom-right"], ["top-right"], ["top-left"]],
                             "poly_c": square})
    fit = load_perception_config().table
    table = annotation_table_mask(flat, (400, 400), fit)
    margin = fit.annotation_margin_px
    assert not table[200, 300 + margin - 1] and table[200, 300 + margin + 2]
    # the same nodes with a fold line are a folded garment: the hull, grown by the folded margin
    folded = parse_annotation({"path_c": "a.png", "type": "towel", "shape": "wrinkled",
                               "node_names": [["fold_1"], ["bottom-left"], ["top-left"], ["fold_1"]],
                               "poly_c": [[300.0, 100.0], [100.0, 300.0], [100.0, 100.0], [300.0, 300.0]]})
    table = annotation_table_mask(folded, (400, 400), fit)
    assert not table[200, 300 + fit.folded_margin_px - 1] and table[10, 10]


def test_fit_from_flat_and_folded_segments_a_black_garment_whole(annotated: Path, black_pants,
                                                                 tmp_path: Path) -> None:
    out = tmp_path / "table.yaml"
    ap = argparse.ArgumentParser(prog="foldcell")
    register(ap.add_subparsers())
    args = ap.parse_args(["table", "fit", "--annotations", str(annotated), "--output", str(out)])
    assert args.func(args) == 0
    provenance = yaml.safe_load(out.read_text())["provenance"]
    assert str(annotated) in provenance["data"] and provenance["command"].startswith("foldcell table fit")
    image, truth = black_pants
    assert _iou(load_table_model(out), image, truth) >= MIN_IOU


def _not_sure_garment(table_model, image: NDArray, truth: NDArray) -> float:
    """The part of the garment (work size) the table model does not call surely garment."""
    w, h = load_perception_config().segmentation.work_size
    small = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    garment = cv2.resize(truth.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    return float(np.mean(table_log_likelihood(small, table_model)[garment] >= table_model.threshold_fg))


def test_naive_polygon_fill_is_worse(annotated: Path, black_pants) -> None:
    """The node polygons filled as masks (the way a folded annotation must not be used) and one
    plain fit: black garment pixels become table, so the model no longer calls a black garment
    surely garment (GrabCut then has to win it back, and on real photographs it lost the legs)."""
    cfg = load_perception_config()
    images, masks, kept = [], [], []
    for path, annotation in load_annotations(annotated):
        image = cv2.imread(str(path.parent / annotation.image))
        filled = np.zeros(image.shape[:2], np.uint8)
        cv2.fillPoly(filled, [np.round(annotation.polygon).astype(np.int32)], 1)
        size = 2 * cfg.table.annotation_margin_px + 1
        masks.append(cv2.dilate(filled, np.ones((size, size), np.uint8)) == 0)
        kept.append(annotation_table_mask(annotation, image.shape[:2], cfg.table))
        images.append(image)
    plain = replace(cfg.table, trim_fraction=0.0, outlier_mahalanobis=0.0)
    naive = fit_table_model(images, masks, cfg, fit=plain)
    image, truth = black_pants
    robust = _not_sure_garment(fit_table_model(images, kept, cfg), image, truth)
    assert robust < 0.01
    # how much the naive fit loses depends on how much garment the node polygons leave out (0.3 % to
    # 32 % on the scenes tried): never less than the robust fit
    assert _not_sure_garment(naive, image, truth) > robust


def test_robust_fit_rejects_garment_inside_the_mask() -> None:
    """Garment pixels a mask lets through (a dark strip, ~4 % of them) do not become table."""
    cfg = load_perception_config()
    scene = ClothScene(light_seed=5)
    strip = np.array([[200.0, 400.0], [1100.0, 430.0], [1100.0, 500.0], [200.0, 470.0]])
    image = scene.render(strip, BLACK)
    truth = truth_mask(strip)
    plain = fit_table_model([image], None, cfg, fit=replace(cfg.table, trim_fraction=0.0,
                                                            outlier_mahalanobis=0.0))
    assert _not_sure_garment(plain, image, truth) > 0.5
    assert _not_sure_garment(fit_table_model([image], None, cfg), image, truth) < 0.01
