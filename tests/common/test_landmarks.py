"""Landmarks: named points with their frame stated, read as a mapping, refused when malformed; the
planner takes table-frame landmarks only."""

from __future__ import annotations

import numpy as np
import pytest

from cell.planning.errors import PlanningInputError
from cell.planning.folds import FoldPlanner
from drivers.common.landmarks import IMAGE, TABLE, Landmarks

SQUARE = {"top-left": (0.1, 0.3), "top-right": (0.5, 0.3), "bottom-right": (0.5, -0.1),
          "bottom-left": (0.1, -0.1)}


def test_read_as_the_mapping_it_was_made_from_in_its_order() -> None:
    lm = Landmarks.of(TABLE, SQUARE)
    assert lm == SQUARE and list(lm) == list(SQUARE) and lm.frame == TABLE
    assert lm["bottom-right"] == (0.5, -0.1)
    assert lm.array(["bottom-left", "top-left"]).tolist() == [[0.1, -0.1], [0.1, 0.3]]
    with pytest.raises(KeyError):
        lm["crotch"]


@pytest.mark.parametrize(("frame", "names", "points", "says"), [
    ("world", ["a"], [[0, 0]], "frame must be one of"),
    (TABLE, ["a", "b"], [[0, 0]], "2 names need (2, 2) points"),
    (TABLE, ["a", "a"], [[0, 0], [1, 1]], "a name is given twice"),
    (TABLE, ["a"], [[np.nan, 0]], "not finite"),
])
def test_malformed_landmarks_are_refused_saying_why(frame: str, names: list[str], points: list,
                                                   says: str) -> None:
    with pytest.raises(ValueError) as err:
        Landmarks(frame, names, points)
    assert says in str(err.value)


def test_image_landmarks_are_not_taken_for_table_ones() -> None:
    image = Landmarks(IMAGE, list(SQUARE), [[100, 300], [500, 300], [500, 700], [100, 700]])
    with pytest.raises(ValueError, match="in the image frame, table needed"):
        Landmarks.of(TABLE, image)
    planner = FoldPlanner()
    with pytest.raises(PlanningInputError, match="image frame"):
        planner.plan_fold("towel", 0, image, planner.motion.perceive)
