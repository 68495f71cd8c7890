"""`replay --perceive` matches each logged image with the model the cell used: the flat model before
the first fold, after fold k the folded model of fold k (derived from the garment as matched before it)."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from cell.evaluation.replay_check import CellModels
from cell.perception.config import load_perception_config
from cell.perception.errors import ModelError
from cell.perception.folded import derive_folded_model, folded_polygon
from cell.perception.models import PolygonalModel
from cell.perception.pipeline import load_garment_models
from cell.planning.folds import fold_moves, load_recipe
from drivers.camera.model import default_camera_model
from drivers.common.plane import perimeter
from drivers.wire import messages

CAMERA = default_camera_model()
MERGE = load_perception_config().merge_fraction
FLAT = load_garment_models()["towel"]
RECIPE = load_recipe("towel")
# a towel lying a little turned on the table, m
TOWEL_TABLE = {"bottom-left": (-0.22, -0.12), "bottom-right": (0.24, -0.16), "top-right": (0.27, 0.16),
               "top-left": (-0.19, 0.2)}


def observation(folds_done: int, table: dict[str, tuple[float, float]]) -> Any:
    """A logged observation of these landmarks, seen by the configured camera."""
    pixels = CAMERA.table_to_pixel(np.array(list(table.values())))
    return messages.new(
        "foldcell_msgs/msg/GarmentObservation", category="towel", fold_index=folds_done,
        landmarks=[messages.new("foldcell_msgs/msg/Landmark", name=name, x_px=float(px[0]), y_px=float(px[1]),
                                x_table=xy[0], y_table=xy[1])
                   for (name, xy), px in zip(table.items(), pixels, strict=True)])


def expected_fold(model: PolygonalModel, table: dict[str, tuple[float, float]], fold_index: int
                  ) -> tuple[PolygonalModel, dict[str, tuple[float, float]]]:
    """The folded model and the folded outline on the table, placed with the camera itself."""
    pixels = CAMERA.table_to_pixel(np.array([table[n] for n in model.names]))
    grasp, place = fold_moves(table, RECIPE.folds[fold_index - 1])
    move_px = CAMERA.table_to_pixel(np.array([grasp[0], place[0]]))
    folded = derive_folded_model(model, pixels, (move_px[0], move_px[1]), fold_index, MERGE)
    outline_px, names = folded_polygon(pixels, model.names, move_px[0], move_px[1], fold_index,
                                       MERGE * perimeter(pixels))
    outline = CAMERA.pixel_to_table(np.asarray(outline_px))
    return folded, {n: (float(x), float(y)) for n, (x, y) in zip(names, outline, strict=True)}


def test_each_fold_is_matched_with_the_folded_model_of_that_fold() -> None:
    models = CellModels({"towel": FLAT}, MERGE)
    assert models.model_for("c1", observation(0, TOWEL_TABLE)) == FLAT
    after_1, table_1 = expected_fold(FLAT, TOWEL_TABLE, 1)
    got_1 = models.model_for("c1", observation(1, table_1))
    assert got_1 is not None and set(got_1.names) == {"top-left", "top-right", "fold1-from", "fold1-to"}
    assert got_1.names == after_1.names
    np.testing.assert_allclose(got_1.angle_mean, after_1.angle_mean, atol=1e-6)
    np.testing.assert_allclose(got_1.length_mean, after_1.length_mean, atol=1e-6)
    after_2, _ = expected_fold(after_1, table_1, 2)
    got_2 = models.model_for("c1", observation(2, table_1))  # where it lies does not matter: fold 1's does
    assert got_2 is not None and got_2.names == after_2.names and "fold2-from" in got_2.names
    np.testing.assert_allclose(got_2.angle_mean, after_2.angle_mean, atol=1e-6)


def test_a_fold_without_an_image_before_it_is_an_error_naming_the_fold() -> None:
    models = CellModels({"towel": FLAT}, MERGE)
    with pytest.raises(ModelError, match="before fold 1"):
        models.model_for("c1", observation(1, TOWEL_TABLE))
    models.model_for("c1", observation(0, TOWEL_TABLE))
    with pytest.raises(ModelError, match="before fold 1"):
        models.model_for("other", observation(1, TOWEL_TABLE))  # another cell's garment
    sock = messages.new("foldcell_msgs/msg/GarmentObservation", category="sock")
    assert models.model_for("c1", sock) is None
