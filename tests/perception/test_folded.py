"""Folded polygons and folded models (Sec. III-F) by the shared fold convention."""

from __future__ import annotations

import numpy as np
import pytest

from cell.perception.errors import ModelError
from cell.perception.folded import derive_folded_model, folded_polygon
from cell.perception.matching import match
from cell.perception.pipeline import load_garment_model
from drivers.common.garments import LANDMARKS
from drivers.common.plane import signed_area
from tests.perception.scenes import random_garment

TOWEL = np.array([[0, 0], [100, 0], [100, 50], [0, 50]], float)  # clockwise: TL, TR, BR, BL
NAMES = ("top-left", "top-right", "bottom-right", "bottom-left")


def test_towel_half_fold() -> None:
    poly, names = folded_polygon(TOWEL, NAMES, (100, 25), (0, 25), 1, 1.0)
    assert names == ("bottom-left", "top-left", "fold1-from", "fold1-to")
    assert np.allclose(poly, [[0, 50], [0, 0], [50, 0], [50, 50]])
    assert signed_area(poly) > 0


def test_input_order_and_merge() -> None:
    # counter-clockwise input is made clockwise; a vertex near F merges into it
    poly, names = folded_polygon(TOWEL[::-1], NAMES[::-1], (0, 25), (98, 25), 2, 5.0)
    assert "fold2-from" in names and "fold2-to" in names
    assert "bottom-left" not in names and "top-left" not in names   # the moving part is removed
    assert names == ("top-right", "bottom-right", "fold2-from", "fold2-to")
    assert np.allclose(poly, [[100, 0], [100, 50], [49, 50], [49, 0]])
    _, merged = folded_polygon(TOWEL, NAMES, (100, 25), (4, 25), 1, 5.0)
    # fold line at x = 52: top-left/bottom-left stay; no stationary vertex within 5 px of F or T
    assert merged == ("bottom-left", "top-left", "fold1-from", "fold1-to")
    _, merged = folded_polygon(TOWEL, NAMES, (100, 25), (2, 25), 1, 60.0)
    assert "top-left" not in merged and "bottom-left" not in merged


def test_fold_errors() -> None:
    with pytest.raises(ModelError, match="does not cross"):
        folded_polygon(TOWEL, NAMES, (300, 25), (290, 25), 1, 1.0)
    with pytest.raises(ModelError, match="coincide"):
        folded_polygon(TOWEL, NAMES, (1, 1), (1, 1), 1, 1.0)


def test_derived_model_matches_the_folded_outline() -> None:
    rng = np.random.default_rng(4)
    model = load_garment_model("short-sleeve")
    for _ in range(5):
        landmarks = random_garment("short-sleeve", rng, upright=True).truth()
        pts = np.array([landmarks[n] for n in model.names])
        # fold the left sleeve onto the body: grasp its outer point, place it across a line just
        # inside the armpit (the wearer's left is on the image's right of a face-up shirt)
        G = landmarks["left-sleeve-outer"]
        inward = np.sign(landmarks["right-armpit"][0] - landmarks["left-armpit"][0])
        x_line = landmarks["left-armpit"][0] + 5 * inward
        P = np.array([2 * x_line - G[0], G[1]])
        folded = derive_folded_model(model, pts, (G, P), 1)
        assert "fold1-from" in folded.names and "left-sleeve-outer" not in folded.names
        fi = folded.names.index("fold1-from")
        assert folded.angle_var[fi] == pytest.approx(2 * min(model.angle_var))
        assert min(folded.angle_var) == pytest.approx(min(model.angle_var))
        # the expected folded outline is matched back with every landmark in place
        poly, names = folded_polygon(pts, model.names, G, P, 1, 0.02 * 3000)
        res = match(poly, folded)
        for n, p in zip(names, poly, strict=True):
            assert np.allclose(res.landmarks[n], p)
    assert LANDMARKS["short-sleeve"][0] == "bottom-left"
