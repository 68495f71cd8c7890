"""Polygonal models: learning, symmetry sharing, files (recipe kept, missing field named)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from cell.perception.config import load_perception_config
from cell.perception.models import PolygonalModel, learn_model, model_from_fields, symmetry_groups
from cell.perception.pipeline import load_garment_model
from drivers.common.configfile import ConfigError, load_yaml
from drivers.common.garments import CATEGORIES, LANDMARKS
from tests.perception.scenes import landmark_polygons


def test_symmetry_groups() -> None:
    ag, lg = symmetry_groups(LANDMARKS["short-sleeve"])
    names = LANDMARKS["short-sleeve"]
    i = {n: k for k, n in enumerate(names)}
    assert ag[i["left-armpit"]] == ag[i["right-armpit"]] != ag[i["bottom-left"]]
    assert len(set(ag)) == 5
    # edge bottom-right -> right-armpit mirrors left-armpit -> bottom-left
    assert lg[i["bottom-right"]] == lg[i["left-armpit"]]
    assert len(set(lg)) == 6   # a..f as in the paper's Fig. 4
    tg, te = symmetry_groups(LANDMARKS["towel"])
    assert len(set(tg)) == 1 and len(set(te)) == 2 and te[0] == te[2] and te[1] == te[3]


def test_learned_models_are_clockwise_with_sensible_angles() -> None:
    rng = np.random.default_rng(0)
    for c in CATEGORIES:
        m = learn_model(c, landmark_polygons(c, 40, rng), LANDMARKS[c], 14)
        # a simple polygon's inner angles sum to (M - 2) pi when clockwise
        assert sum(m.angle_mean) == pytest.approx((m.size - 2) * np.pi, rel=0.02)
        assert sum(m.length_mean) == pytest.approx(1.0, rel=1e-6)
        assert set(m.names) == set(LANDMARKS[c])
        assert m.names == LANDMARKS[c]     # the dataset's order, clockwise on screen face up


@pytest.mark.parametrize("category", CATEGORIES)
def test_shipped_models_load(category: str) -> None:
    m = load_garment_model(category)
    assert m.category == category and 10 <= m.simplify_vertices <= 20
    assert set(m.names) == set(LANDMARKS[category])


def test_loader_ignores_recipe_and_names_missing_field(tmp_path: Path) -> None:
    src = load_perception_config().garments_dir / "towel.yaml"
    data = yaml.safe_load(src.read_text())
    data["recipe"] = {"folds": [{"grasp": ["bottom-left"], "place": ["top-left"]}]}
    f = tmp_path / "towel.yaml"
    f.write_text(yaml.safe_dump(data))
    assert load_garment_model("towel", path=f).names == model_from_fields(load_yaml(src)).names
    del data["vertices"][1]["angle_var"]
    f.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"vertices\[1\]\.angle_var: missing"):
        load_garment_model("towel", path=f)


def test_model_validation() -> None:
    from cell.perception.errors import ModelError
    with pytest.raises(ModelError, match="angle_var"):
        PolygonalModel("x", ("a", "b", "c"), (1, 1, 1), (0.1, 0.0, 0.1), (0.3, 0.3, 0.4), (0.01,) * 3,
                       (0, 1, 2), (0, 1, 2), 10)


def test_annotation_parsing_reads_misspellings_and_types() -> None:
    from cell.perception.annotations import AnnotationError, parse_annotation
    data = {"path_c": "a.png", "path_d": "", "type": "polo", "facing": "front", "shape": "flat",
            "node_names": [["left-sleave-outer"], ["rigth-armpit"], ["neckline-left"]],
            "poly_c": [[1, 2], [3, 4], [5, 6]], "moves": [[1, 2, 3, 4]]}
    ann = parse_annotation(data)
    assert ann.category == "short-sleeve"
    assert set(ann.landmarks) == {"left-sleeve-outer", "right-armpit", "neckline-left"}
    assert ann.moves == ((1.0, 2.0, 3.0, 4.0),)
    with pytest.raises(AnnotationError, match="landmarks missing"):
        ann.model_points()
    with pytest.raises(AnnotationError, match="unknown garment type"):
        parse_annotation({**data, "type": "hat"})
    with pytest.raises(AnnotationError, match="missing field 'poly_c'"):
        parse_annotation({k: v for k, v in data.items() if k != "poly_c"})


@pytest.mark.parametrize("category", ["short-sleeve", "long-sleeve"])
def test_shipped_shirt_models_carry_a_collared_variant_that_reads_back(category: str, tmp_path: Path) -> None:
    from drivers.common.garments import ANNOTATED_NODES
    model = load_garment_model(category)
    assert model.collared is not None and model.collared.names == ANNOTATED_NODES[category]
    f = tmp_path / f"{category}.yaml"
    f.write_text(yaml.safe_dump(model.to_dict(exact=True)))
    assert load_garment_model(category, path=f) == model


def test_a_collared_variant_missing_a_landmark_is_named(tmp_path: Path) -> None:
    data = yaml.safe_load((load_perception_config().garments_dir / "short-sleeve.yaml").read_text())
    data["collared"]["vertices"] = [v for v in data["collared"]["vertices"] if v["name"] != "left-armpit"]
    f = tmp_path / "short-sleeve.yaml"
    f.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"short-sleeve.yaml: collared: .*must hold the vertices"):
        load_garment_model("short-sleeve", path=f)
