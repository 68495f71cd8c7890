"""CloPeMa annotation files as the dataset writes them: misspelt names, a shirt's collar nodes, a
folded garment's fold-line pairs, the facing, and clear errors for what is wrong."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from cell.perception.annotations import AnnotationError, load_annotations, parse_annotation
from drivers.common.garments import LANDMARKS

# Written in the dataset's own form (keys in its order, misspellings as its files have them); the
# coordinates are made up.
PANTS = """
path_c: cloC00001.png
path_d: cloD00001.png
facing: front
shape: flat
type: pants
node_names:
- [left-leg-outer]
- [left-leg-inner]
- [crotch]
- [right-leg-inner]
- [rigth-leg-outer]
- [top-right]
- [top-left]
poly_c:
- [790.5, 66.0]
- [875.0, 124.5]
- [497.0, 628.0]
- [1132.5, 465.5]
- [1172.0, 571.0]
- [345.0, 936.0]
- [171.0, 668.5]
moves: []
"""

POLO = """
path_c: cloC00002.png
path_d: cloD00002.png
facing: front
shape: wrinkled
type: polo
node_names:
- [bottom-left]
- [bottom-right]
- [right-armpit]
- [right-sleave-inner]
- [right-sleave-outer]
- [right-shoulder]
- [neckline-right]
- [collar-rigth]
- [collar-left]
- [neckline-left]
- [left-shoulder]
- [left-sleave-outer]
- [left-sleave-inner]
- [left-armpit]
poly_c:
- [800.0, 875.0]
- [526.0, 637.0]
- [680.0, 345.0]
- [678.5, 337.5]
- [616.0, 184.0]
- [831.0, 133.0]
- [949.0, 190.0]
- [998.0, 174.0]
- [1116.0, 294.0]
- [1100.0, 336.0]
- [1159.0, 459.0]
- [1210.0, 629.0]
- [1056.5, 644.5]
- [1013.5, 595.0]
moves:
- [534.0, 802.0, 1209.7, 1051.0]
"""

FOLDED = """
path_c: cloC00003.png
path_d: cloD00003.png
facing: front
type: pants
shape: folded
node_names:
- [fold_1]
- [left-leg-outer]
- [left-leg-inner]
- [fold_1]
- [crotch]
- [fold_2]
- [right-leg-inner]
- [rigth-leg-outer]
- [fold_2]
- [top-right]
- [top-left]
poly_c:
- [520.0, 975.0]
- [596.5, 862.0]
- [483.0, 778.5]
- [395.5, 877.0]
- [805.5, 357.5]
- [530.5, 473.5]
- [896.0, 256.0]
- [832.0, 162.5]
- [461.0, 332.5]
- [882.5, 105.0]
- [1093.5, 329.5]
"""


def parsed(text: str, **changes: object):
    data = yaml.safe_load(text)
    data.update(changes)
    return parse_annotation(data)


def test_misspelt_names_are_read_as_the_design_spells_them() -> None:
    pants = parsed(PANTS)
    assert pants.category == "pants" and pants.facing == "front" and pants.shape == "flat"
    assert "right-leg-outer" in pants.landmarks and "rigth-leg-outer" not in pants.landmarks
    assert pants.landmarks["right-leg-outer"] == (1172.0, 571.0)
    polo = parsed(POLO)
    assert {"right-sleeve-inner", "left-sleeve-outer", "collar-right"} <= set(polo.landmarks)


def test_a_shirt_s_model_points_leave_the_collar_out_in_model_order() -> None:
    polo = parsed(POLO)
    points = polo.model_points()
    assert points.shape == (10, 2)
    for name, point in zip(LANDMARKS["short-sleeve"], points, strict=True):
        assert tuple(point) == polo.landmarks[name]
    assert len(polo.nodes) == 14 and polo.polygon.shape == (14, 2)


def test_a_folded_garment_keeps_every_node_and_its_fold_lines() -> None:
    folded = parsed(FOLDED)
    assert folded.shape == "folded" and len(folded.nodes) == 11
    assert [n for n, _ in folded.nodes].count("fold_1") == 2
    assert set(folded.landmarks) == {"left-leg-outer", "left-leg-inner", "crotch", "right-leg-inner",
                                     "right-leg-outer", "top-right", "top-left"}
    assert folded.fold_lines == {1: ((520.0, 975.0), (395.5, 877.0)), 2: ((530.5, 473.5), (461.0, 332.5))}
    assert folded.moves == ()


def test_a_garment_lying_face_down_is_named_as_perception_sees_it() -> None:
    front = parsed(PANTS)
    back = parsed(PANTS, facing="back")
    assert back.mirrored and not front.mirrored
    # face down, the wearer's left leg is on the image's left: perception (which assumes face up)
    # calls that point the right leg
    assert back.landmarks_as_seen()["right-leg-outer"] == front.landmarks["left-leg-outer"]
    assert back.landmarks_as_seen()["crotch"] == front.landmarks["crotch"]
    assert front.landmarks_as_seen() == front.landmarks
    assert parsed(PANTS, facing=None).facing is None


@pytest.mark.parametrize(("change", "field"), [
    ({"facing": "up"}, "facing"),
    ({"shape": "crumpled"}, "shape"),
    ({"type": "scarf"}, "type"),
    ({"poly_c": [[1.0, 2.0]] * 6}, "poly_c"),
    ({"poly_c": [[1.0, float("nan")]] * 7}, "poly_c[0]"),
    ({"node_names": [["a", "b"]] * 7}, "node_names[0]"),
    ({"moves": [[1, 2, 3]]}, "moves[0]"),
    ({"path_c": ""}, "path_c"),
])
def test_what_is_wrong_is_named(change: dict, field: str) -> None:
    with pytest.raises(AnnotationError, match=field.replace("[", r"\[").replace("]", r"\]")):
        parsed(PANTS, **change)


def test_a_folder_reads_what_it_can(tmp_path) -> None:
    (tmp_path / "cloA00001.yaml").write_text(PANTS)
    (tmp_path / "cloA00002.yaml").write_text(POLO.replace("type: polo", "type: scarf"))
    (tmp_path / "other.yaml").write_text("just: config\n")
    read = load_annotations(tmp_path)
    assert [p.name for p, _ in read] == ["cloA00001.yaml"]
    assert np.allclose(read[0][1].polygon[0], [790.5, 66.0])
