"""Category recognition (cell/perception/recognition.py) with the shipped recogniser and garment
models, on outlines of real proportions built in `real_shapes` (not by the simulated world), at any
rotation, either side up and any size; a real CloPeMa annotation; the recogniser's file and its
learning settings checked with errors naming the field."""

from __future__ import annotations

import shutil
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import yaml

from cell.perception.config import load_perception_config
from cell.perception.pipeline import load_garment_models, match_outline, outline_of_contour
from cell.perception.recognition import load_recogniser, recogniser_from_fields, shape_features
from drivers.common.configfile import ConfigError, config_dir, load_yaml
from tests.perception import real_shapes

CATEGORIES = tuple(real_shapes.SHAPES)


@pytest.fixture(scope="module")
def shipped():
    cfg = load_perception_config()
    return cfg, load_garment_models(cfg), load_recogniser(cfg.recognition.model)


def recognised(contour: np.ndarray, shipped) -> tuple[str, dict[str, float]]:
    cfg, models, recogniser = shipped
    observation = match_outline(outline_of_contour(contour, cfg, models.values()), models, cfg,
                                recogniser=recogniser)
    return observation.category, observation.probabilities


@pytest.mark.parametrize("category", CATEGORIES)
def test_shape_features_do_not_depend_on_pose(category: str) -> None:
    shape = real_shapes.SHAPES[category](np.random.default_rng(4))
    reference = shape_features(real_shapes.traced(real_shapes.posed(shape, 0.0, False, 800.0, (600, 600))))
    for angle, mirrored, scale in ((0.7, False, 800.0), (2.4, True, 500.0), (4.0, True, 1100.0)):
        posed = real_shapes.posed(shape, angle, mirrored, scale, (900, 700))
        features = shape_features(real_shapes.traced(posed))
        # rasterisation moves the border by a pixel (a towel's tiny defects are pixel noise)
        np.testing.assert_allclose(features, reference, atol=0.08)


@pytest.mark.parametrize("category", CATEGORIES)
def test_each_category_recognised_at_any_rotation_mirror_and_scale(category: str, shipped) -> None:
    shape = real_shapes.SHAPES[category](np.random.default_rng(11))
    for angle in np.linspace(0.0, 2 * np.pi, 6, endpoint=False) + 0.3:
        for mirrored in (False, True):
            for scale in (450.0, 1000.0):
                contour = real_shapes.traced(real_shapes.posed(shape, angle, mirrored, scale, (800, 800)))
                category_seen, probabilities = recognised(contour, shipped)
                assert category_seen == category, (angle, mirrored, scale, probabilities)
                assert set(probabilities) == set(CATEGORIES)
                assert sum(probabilities.values()) == pytest.approx(1.0)
                assert next(iter(probabilities)) == category_seen


def test_accuracy_on_real_proportions(shipped) -> None:
    rng = np.random.default_rng(2024)
    outcomes = Counter()
    for index in range(60):
        category = CATEGORIES[index % len(CATEGORIES)]
        outcomes[category == recognised(real_shapes.random_outline(category, rng), shipped)[0]] += 1
    folded = [recognised(real_shapes.random_outline("pants", rng, folded=True), shipped)[0]
              for _ in range(10)]
    assert outcomes[True] >= 0.95 * 60, outcomes
    assert Counter(folded)["pants"] >= 9, folded


def test_real_clopema_pants_are_pants(shipped) -> None:
    category, probabilities = recognised(real_shapes.traced(real_shapes.CLOPEMA_PANTS), shipped)
    assert category == "pants", probabilities
    assert probabilities["pants"] > 0.5


def test_shipped_recogniser_records_its_provenance(shipped) -> None:
    provenance = shipped[2].provenance
    assert {"data", "date", "command", "seed", "samples"} <= set(provenance)
    assert provenance["command"].startswith("foldcell models learn-recognition")


def _own_config(tmp_path: Path, edit) -> Path:
    cfg = tmp_path / "config"
    shutil.copytree(config_dir(), cfg)
    data = yaml.safe_load((cfg / "perception.yaml").read_text())
    edit(data)
    (cfg / "perception.yaml").write_text(yaml.safe_dump(data))
    return cfg / "perception.yaml"


@pytest.mark.parametrize(("edit", "field"), [
    (lambda d: d["recognition"]["augment"].update(stretch=[1.8, 0.9]), "recognition.augment.stretch"),
    (lambda d: d["recognition"].update(augmentations=-1), "recognition.augmentations"),
    (lambda d: d["recognition"].update(regularisation="much"), "recognition.regularisation"),
    (lambda d: d["recognition"].update(unknown=1), "recognition"),
])
def test_bad_learning_settings_name_the_field(tmp_path: Path, edit, field: str) -> None:
    path = _own_config(tmp_path, edit)
    with pytest.raises(ConfigError) as raised:
        load_perception_config(path)
    assert raised.value.field.startswith(field)
    assert str(path) in str(raised.value)


def test_bad_recogniser_file_names_the_field(tmp_path: Path) -> None:
    data = yaml.safe_load((config_dir() / "perception" / "recognition.yaml").read_text())
    data["classes"][1]["shape_weights"] = data["classes"][1]["shape_weights"][:-1]
    path = tmp_path / "recognition.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"classes\[1\]\.shape_weights: has \d+ entries"):
        recogniser_from_fields(load_yaml(path))
    data = yaml.safe_load((config_dir() / "perception" / "recognition.yaml").read_text())
    data["features"][0]["scale"] = 0.0
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"features\[0\]\.scale"):
        recogniser_from_fields(load_yaml(path))
