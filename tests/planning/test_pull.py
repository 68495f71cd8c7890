"""A fold out of the arms' reach is preceded by a pull: the garment dragged towards the turn-table.

The scenes lie on a table deeper than the cell's (1.8 m), the garment at its far end, 1.6-2.2 m from
the turn-table axis, where no MA1400 reaches; the reference for "within reach" is the planner's own
IK (a fold that plans), and the distances are measured from the world origin here, not by the code.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cell.planning.errors import Unreachable
from cell.planning.folds import FoldPlanner, GripperAction, fold_moves, load_recipe
from drivers.robot.config import load_robot_config
from drivers.robot.table import default_table_config

DEEP_TABLE = dataclasses.replace(default_table_config(), size_x=1.8)

# a towel (0.5 m x 0.35 m) at the deep table's far end, turned 0.4 rad; a smaller one near the robot
_CORNERS = np.array([[-0.25, -0.175], [0.25, -0.175], [0.25, 0.175], [-0.25, 0.175]])
_TURN = np.array([[np.cos(0.4), -np.sin(0.4)], [np.sin(0.4), np.cos(0.4)]])
FAR_TOWEL = {name: tuple(float(v) for v in point)
             for name, point in zip(("bottom-left", "bottom-right", "top-right", "top-left"),
                                    _CORNERS @ _TURN.T + np.array([1.3, 0.55]), strict=True)}
NEAR_TOWEL = {name: tuple(float(v) for v in point)
              for name, point in zip(FAR_TOWEL, 0.6 * _CORNERS @ _TURN.T + np.array([0.3, 0.6]), strict=True)}


@pytest.fixture(scope="module")
def planner() -> FoldPlanner:
    return FoldPlanner(table=DEEP_TABLE)


@pytest.fixture(scope="module")
def home() -> np.ndarray:
    return np.asarray(load_robot_config().home, dtype=float)


def _from_axis(planner: FoldPlanner, points_xy: np.ndarray) -> np.ndarray:
    return np.linalg.norm(planner.table.table_to_world(np.asarray(points_xy))[:, :2], axis=1)


def test_far_towel_is_pulled_into_reach_and_then_folds(planner: FoldPlanner, home: np.ndarray) -> None:
    with pytest.raises(Unreachable):
        planner.plan_fold("towel", 0, FAR_TOWEL, home, include_perceive=False)
    pull = planner.plan_pull("towel", 0, FAR_TOWEL, home)
    offset = np.asarray(pull.offset)
    # towards the turn-table axis, by at most max_pull, the garment still on the table
    centre = np.mean(list(FAR_TOWEL.values()), axis=0)
    came = _from_axis(planner, centre[None])[0] - _from_axis(planner, (centre + offset)[None])[0]
    assert came > 0.9 * pull.distance
    assert pull.distance <= planner.config.max_pull + 1e-9
    moved = {name: (x + offset[0], y + offset[1]) for name, (x, y) in FAR_TOWEL.items()}
    assert np.all(DEEP_TABLE.contains(np.array(list(moved.values()))))
    # it grips the garment's outline (closes, drags, opens) and comes back to perceive
    closes = [s for s in pull.steps if isinstance(s, GripperAction) and s.action == "close"]
    assert len(closes) == len(pull.arms) >= 1
    for grasp in np.asarray(pull.grasp_points):
        corners = np.array(list(FAR_TOWEL.values()))
        edges = [abs(float((b - a)[0] * (grasp - a)[1] - (b - a)[1] * (grasp - a)[0])) / np.linalg.norm(b - a)
                 for a, b in zip(corners, np.roll(corners, -1, axis=0), strict=True)]
        assert min(edges) < 1e-6
    # a fold still out of reach is pulled again (max_pulls), and then it plans
    q = pull.final_positions
    for _ in range(planner.config.max_pulls):
        try:
            plan = planner.plan_fold("towel", 0, moved, q, include_perceive=False)
            break
        except Unreachable:
            again = planner.plan_pull("towel", 0, moved, q)
            moved = {name: (x + again.offset[0], y + again.offset[1]) for name, (x, y) in moved.items()}
            q = again.final_positions
    else:
        plan = planner.plan_fold("towel", 0, moved, q, include_perceive=False)
    assert len(plan.arms) >= 1


def _long_towel_at_near_edge(gap: float) -> dict[str, tuple[float, float]]:
    """A 1.2 m x 0.3 m towel lying along x, its near edge `gap` from the table's near edge: its far
    corners lie beyond reach, its near edge within."""
    corners = np.array([[0.0, 0.45], [1.2, 0.45], [1.2, 0.75], [0.0, 0.75]]) + np.array([gap, 0.0])
    names = ("bottom-left", "bottom-right", "top-right", "top-left")
    return {name: (float(x), float(y)) for name, (x, y) in zip(names, corners, strict=True)}


def test_pull_stops_at_the_near_edge_of_the_table(planner: FoldPlanner, home: np.ndarray) -> None:
    towel = _long_towel_at_near_edge(0.10)
    pull = planner.plan_pull("towel", 0, towel, home)
    moved = np.array(list(towel.values())) + np.asarray(pull.offset)
    assert np.all(DEEP_TABLE.contains(moved, margin=-1e-9))
    assert pull.distance <= 0.10 / abs(np.asarray(pull.offset)[0] / pull.distance) + 1e-9
    with pytest.raises(Unreachable, match="table's edge"):
        planner.plan_pull("towel", 0, _long_towel_at_near_edge(0.01), home)


def test_no_pull_for_a_fold_within_reach(planner: FoldPlanner, home: np.ndarray) -> None:
    G, P = fold_moves(NEAR_TOWEL, load_recipe("towel").folds[0])
    assert np.all(_from_axis(planner, np.vstack([G, P])) < planner.config.reach_radius)
    with pytest.raises(Unreachable, match="cannot help"):
        planner.plan_pull("towel", 0, NEAR_TOWEL, home)
