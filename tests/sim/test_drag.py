"""A grasp-to-release that never lifts the cloth slides the garment (the cell's pull into reach); one
that lifts it folds. Both worlds: the geometric one (events and heights) and the cloth physics (the
cloth's own vertices are the reference for where the garment went)."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.sim.world import GarmentWorld


def _world_point(world: GarmentWorld, xy: np.ndarray, height: float) -> np.ndarray:
    return world.table.table_to_world(np.asarray(xy, dtype=float)[None])[0] + np.array([0.0, 0.0, height])


def _drag(world: GarmentWorld, grasps: dict[str, np.ndarray], shift: np.ndarray, height: float,
          duration: float = 1.0, period: float = 0.01) -> None:
    """Close each arm at its grasp point `height` above the table, move all by `shift` (straight, at
    that height; lifted in the middle when `height` is a fold's), open."""
    for arm, xy in grasps.items():
        world.gripper_event(arm, True, _world_point(world, xy, 0.005), robot_time=0.0)
    parked = {arm: _world_point(world, np.zeros(2), 0.5) for arm in ("r1", "r2") if arm not in grasps}
    for t in np.arange(period, duration + period / 2, period):
        share = t / duration
        lift = 0.005 + (height - 0.005) * np.sin(np.pi * share)
        world.gripper_motion(t, {**parked, **{arm: _world_point(world, xy + share * shift, lift)
                                              for arm, xy in grasps.items()}})
        for arm in ("r1", "r2"):
            world.gripper_heard(arm, t)
    for arm, xy in grasps.items():
        world.gripper_event(arm, False, _world_point(world, xy + shift, 0.005), robot_time=duration + period)
    for arm in ("r1", "r2"):
        world.gripper_heard(arm, duration + 2 * period)
    world.catch_up()


@pytest.mark.parametrize("seed", [1, 2])
def test_geometric_drag_moves_the_garment_and_folds_nothing(seed: int) -> None:
    world = GarmentWorld(seed=seed, category="towel")
    before = world.truth_landmarks()
    shift = np.array([-0.12, 0.05])
    _drag(world, {"r1": before["bottom-left"], "r2": before["bottom-right"]}, shift, height=0.005)
    assert world.history == []
    after = world.truth_landmarks()
    for name, point in before.items():
        np.testing.assert_allclose(after[name], point + shift, atol=1e-9)
    laid = GarmentWorld(seed=seed, category="towel").garment.outline
    np.testing.assert_allclose(world.garment.outline, laid + shift, atol=1e-9)


def test_geometric_lifted_move_still_folds() -> None:
    world = GarmentWorld(seed=1, category="towel")
    lm = world.truth_landmarks()
    _drag(world, {"r1": lm["bottom-left"], "r2": lm["bottom-right"]}, lm["top-left"] - lm["bottom-left"],
          height=0.15)
    assert len(world.history) == 1


def test_events_without_motion_fold_as_before() -> None:
    """A caller that sends only the events (datasets, the geometric camera of old) still folds."""
    world = GarmentWorld(seed=1, category="towel")
    lm = world.truth_landmarks()
    for arm, name in (("r1", "bottom-left"), ("r2", "bottom-right")):
        world.gripper_event(arm, True, _world_point(world, lm[name], 0.005))
    for arm, name in (("r1", "top-left"), ("r2", "top-right")):
        world.gripper_event(arm, False, _world_point(world, lm[name], 0.005))
    assert len(world.history) == 1


@pytest.mark.slow
def test_cloth_dragged_by_one_gripper_is_slid_not_folded() -> None:
    world = GarmentWorld(seed=3, category="towel", folding="physics")
    before = world.landmark_vertices()
    truth_before = world.truth_landmarks()
    names = list(truth_before)
    # the middle of the edge nearest the robot, dragged 0.15 m along it
    edge = min(zip(names, names[1:] + names[:1], strict=True),
               key=lambda e: truth_before[e[0]][0] + truth_before[e[1]][0])
    middle = (truth_before[edge[0]] + truth_before[edge[1]]) / 2.0
    shift = np.array([-0.15, 0.0])
    _drag(world, {"r1": middle}, shift, height=0.005, duration=2.0)
    assert world.history == []
    after = world.landmark_vertices()
    cloth_moved = np.mean([after[n][:2] - before[n][:2] for n in names], axis=0)
    # the cloth went along (one gripper off its centre turns it a little, so not all the way)
    assert cloth_moved @ shift > 0.5 * shift @ shift, cloth_moved
    truth = world.truth_landmarks()
    for name in names:                                                     # and the world says where
        assert np.linalg.norm(truth[name] - after[name][:2]) < 0.03, (name, truth[name], after[name])
