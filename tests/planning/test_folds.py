"""Fold geometry, recipes, and whole fold plans checked as the controller emulator checks them."""

import copy
import dataclasses

import numpy as np
import pytest

from cell.planning.errors import PlanningInputError, Unreachable
from cell.planning.folds import (
    FoldPlanner,
    FoldSpec,
    GripperAction,
    fold_line,
    fold_moves,
    fold_outline,
    load_recipe,
)
from cell.planning.motion import MotionPlanner, interpolate_poses
from cell.planning.trajectory import PlannedTrajectory
from drivers.common.configfile import ConfigError, config_dir
from drivers.common.garments import CATEGORIES
from drivers.controller.acceptance import check_trajectory
from drivers.controller.codes import OK
from drivers.robot.table import TableConfig
from drivers.sim.garments import TEMPLATES, place_garment


@pytest.fixture(scope="module")
def fp() -> FoldPlanner:
    return FoldPlanner(MotionPlanner())


def test_fold_outline_of_a_towel_in_half():
    # square, model order (top-left, top-right, bottom-right, bottom-left); bottom onto top
    lm = {"top-left": (1.0, 0.0), "top-right": (1.0, 1.0), "bottom-right": (0.0, 1.0),
          "bottom-left": (0.0, 0.0)}
    spec = load_recipe("towel").folds[0]
    G, P = fold_moves(lm, spec)
    np.testing.assert_allclose(G, [[0.0, 0.0], [0.0, 1.0]])
    np.testing.assert_allclose(P, [[1.0, 0.0], [1.0, 1.0]])
    line = fold_line(G, P)
    np.testing.assert_allclose(line.point, [0.5, 0.5])
    np.testing.assert_allclose(line.normal, [-1.0, 0.0])     # towards the side that moves
    out = fold_outline(list(lm), np.array(list(lm.values())), line, 1, 0.02)
    # walking top-left -> top-right -> (enter moving part on the right edge) ... (leave on the left edge)
    assert out.names == ("top-left", "top-right", "fold1-from", "fold1-to")
    np.testing.assert_allclose(out.points, [[1, 0], [1, 1], [0.5, 1], [0.5, 0]])


def test_fold_outline_merges_vertices_near_the_fold_ends():
    pts = np.array([[1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [0.0, 0.0], [0.51, 0.0]])
    names = ["a", "b", "c", "d", "e"]
    line = fold_line(np.array([[0.0, 0.5]]), np.array([[1.0, 0.5]]))
    out = fold_outline(names, pts, line, 2, 0.02)   # merge distance 0.08 m: "e" merges into the fold end
    assert out.names == ("a", "b", "fold2-from", "fold2-to")


def test_recipes_follow_the_issue_and_replay_by_name():
    counts = {"towel": 2, "pants": 2, "short-sleeve": 3, "long-sleeve": 3}
    for cat in CATEGORIES:
        recipe = load_recipe(cat)
        assert len(recipe.folds) == counts[cat]
        names = [t[0] for t in TEMPLATES[cat]]
        lm = {n: (float(x), float(y)) for n, x, y in TEMPLATES[cat]}
        for k, spec in enumerate(recipe.folds):
            for n in spec.grasp + spec.toward + spec.hold:
                assert n in lm, (cat, k, n, names)
            G, P = fold_moves(lm, spec)
            out = fold_outline(list(lm), np.array(list(lm.values())), fold_line(G, P), k + 1, 0.02)
            lm = out
            assert f"fold{k + 1}-from" in lm and f"fold{k + 1}-to" in lm


def test_held_points_land_on_their_mirror_images_across_the_line_the_grasp_points_set():
    """A fold whose grippers hold other landmarks (a sleeve's end) than those that set its line."""
    lm = {"a": (0.0, 0.0), "b": (0.0, 0.4), "c": (1.0, 0.0), "d": (1.0, 0.4), "cuff": (-0.3, 0.5)}
    line_only = FoldSpec("half", ("a", "b"), ("c", "d"), (0.5, 0.5), 0.4, 0.0)
    held = dataclasses.replace(line_only, hold=("a", "cuff"))
    G, P = fold_moves(lm, held)
    # the grasps a, b go half way to c, d: the line x = 0.25; a mirror across it is x -> 0.5 - x
    np.testing.assert_allclose(G, [[0.0, 0.0], [-0.3, 0.5]])
    np.testing.assert_allclose(P, [[0.5, 0.0], [0.8, 0.5]], atol=1e-12)
    line = fold_line(G, P)
    assert abs(line.point[0] - 0.25) < 1e-12 and abs(abs(line.normal[0]) - 1.0) < 1e-12
    assert held.held == ("a", "cuff") and line_only.held == ("a", "b")


# a short-sleeved shirt whose right sleeve lies where the arms cannot carry it over (placed by
# `place_garment`): the right side's fold holds its corners instead
SHIRT_BY_THE_EDGE = {
    "bottom-right": (0.1041, 0.8265), "right-armpit": (0.4041, 0.8096),
    "right-sleeve-inner": (0.3375, 0.8993), "right-sleeve-outer": (0.4265, 0.9516),
    "right-shoulder": (0.5315, 0.7809), "left-shoulder": (0.5162, 0.5094),
    "left-sleeve-outer": (0.3927, 0.3515), "left-sleeve-inner": (0.3101, 0.4135),
    "left-armpit": (0.3864, 0.4952), "bottom-left": (0.0863, 0.5121)}


def test_a_fold_holds_the_sleeve_and_falls_back_to_the_side_when_the_sleeve_is_out_of_reach(fp):
    recipe = fp.recipe("short-sleeve")
    assert recipe.folds[0].hold == ("bottom-left", "left-sleeve-outer")
    assert recipe.folds[1].hold == ("bottom-right", "right-sleeve-outer")
    first = fp.plan_fold("short-sleeve", 0, SHIRT_BY_THE_EDGE, fp.motion.perceive.copy())
    held = {tuple(np.round(p, 4)) for p in first.grasp_points}
    assert held == {SHIRT_BY_THE_EDGE["bottom-left"], SHIRT_BY_THE_EDGE["left-sleeve-outer"]}
    q = _check_plan(fp, first, fp.motion.perceive.copy())
    second = fp.plan_fold("short-sleeve", 1, first.expected_outline, q)
    held = {tuple(np.round(p, 4)) for p in second.grasp_points}
    assert held == {SHIRT_BY_THE_EDGE["bottom-right"], SHIRT_BY_THE_EDGE["right-shoulder"]}
    # the same fold line either way: the side's corners land on their mirror images across it
    G = np.array([SHIRT_BY_THE_EDGE["bottom-right"], SHIRT_BY_THE_EDGE["right-shoulder"]])
    line = second.fold_line
    normal = np.asarray(line.normal) / np.linalg.norm(line.normal)
    mirrors = G - 2.0 * ((G - np.asarray(line.point)) @ normal)[:, None] * normal
    placed = np.asarray(second.place_points)
    assert np.allclose(sorted(map(tuple, mirrors)), sorted(map(tuple, placed)), atol=1e-6)


@pytest.mark.parametrize("hold, reason", [
    ("[bottom-left]", "one landmark per grasp landmark"),
    ("[bottom-left, '']", "must be a list of non-empty strings"),
])
def test_a_bad_hold_is_named_with_its_file_and_field(tmp_path, hold, reason):
    text = (config_dir() / "garments" / "short-sleeve.yaml").read_text()
    bad = tmp_path / "short-sleeve.yaml"
    bad.write_text(text.replace("  hold:\n  - bottom-left\n  - left-sleeve-outer\n", f"  hold: {hold}\n", 1))
    assert bad.read_text() != text
    with pytest.raises(ConfigError, match=rf"short-sleeve.yaml: recipe\[0\]\.hold: {reason}"):
        load_recipe("short-sleeve", bad)


def _check_plan(fp: FoldPlanner, plan, q_start: np.ndarray) -> np.ndarray:
    mp = fp.motion
    q = q_start
    arms_closed: set[str] = set()
    for step in plan.steps:
        if isinstance(step, GripperAction):
            assert step.action in ("open", "close")
            (arms_closed.add if step.action == "close" else arms_closed.discard)(step.arm)
            continue
        assert isinstance(step, PlannedTrajectory)
        reply = check_trajectory(step, q, mp.robot, mp.controller_config)
        assert reply == OK, (step.label, reply)
        dense = step.dense_positions(mp.controller_config.interpolation_period)
        assert np.all(dense >= mp.robot.lower) and np.all(dense <= mp.robot.upper)
        for x in dense:
            assert not mp.collision.in_collision(x, step.allow_finger_contact), step.label
        # the grasping arm keeps the cloth only during the fold
        assert (step.label == "fold") == bool(arms_closed), step.label
        q = step.positions[-1]
    labels = [s.label if isinstance(s, PlannedTrajectory) else s.action for s in plan.steps]
    k = len(plan.arms)
    assert labels == ["open"] * k + ["to-pregrasp", "approach"] + ["close"] * k + ["fold"] + ["open"] * k + [
        "retreat", "perceive"]
    return q


@pytest.mark.parametrize("category", CATEGORIES)
def test_plans_for_random_placements_pass_the_controller_rules(fp, category):
    rng = np.random.default_rng(100 + CATEGORIES.index(category))
    for _ in range(3):
        lm = place_garment(category, fp.table, rng, reach_radius=fp.config.reach_radius)
        q = fp.motion.perceive.copy()
        for k in range(len(fp.recipe(category).folds)):
            plan = fp.plan_fold(category, k, lm, q)
            assert len(plan.grasp_points) == len(plan.arms) == len(plan.place_points)
            # grasped points end at the place points (laid the recipe's crease allowance beyond):
            # TCP at the end of the fold segment
            fold = next(s for s in plan.steps if isinstance(s, PlannedTrajectory) and s.label == "fold")
            allowance = fp.recipe(category).folds[k].crease_allowance
            for arm, place in zip(plan.arms, plan.place_points, strict=True):
                tcp = fp.motion.kin.tcp_pose(fold.positions[-1], arm)[:3, 3]
                xy = fp.table.world_to_table(tcp)[0]
                assert np.linalg.norm(xy - place) < fp.config.grasp.depth + allowance + 1e-3
            q = _check_plan(fp, plan, q)
            lm = plan.expected_outline


def test_out_of_reach_garment_is_reported_with_the_point(fp):
    # a long table: the far end is on the table but out of reach of both arms
    big = TableConfig(size_x=2.5, size_y=1.2, height=0.75, thickness=0.04, near_edge_x=0.6)
    planner = FoldPlanner(fp.motion, table=big)
    lm = {"top-left": (2.3, 0.4), "top-right": (2.3, 0.8), "bottom-right": (2.0, 0.8),
          "bottom-left": (2.0, 0.4)}
    with pytest.raises(Unreachable) as exc:
        planner.plan_fold("towel", 0, lm, fp.motion.perceive.copy())
    err = exc.value
    assert err.point in {(2.0, 0.4), (2.0, 0.8), (2.3, 0.4), (2.3, 0.8)}
    assert "reach" in err.reason
    assert f"({err.point[0]:.3f}, {err.point[1]:.3f})" in str(err)


def test_garment_off_the_table_is_unreachable(fp):
    lm = {"top-left": (0.5, 1.5), "top-right": (0.5, 1.9), "bottom-right": (0.2, 1.9),
          "bottom-left": (0.2, 1.5)}
    with pytest.raises(Unreachable, match="outside the table"):
        fp.plan_fold("towel", 0, lm, fp.motion.perceive.copy())


def test_bad_input_is_named(fp):
    q = fp.motion.perceive.copy()
    lm = {"top-left": (0.4, 0.4), "top-right": (0.4, 0.8), "bottom-right": (0.1, 0.8),
          "bottom-left": (0.1, 0.4)}
    with pytest.raises(PlanningInputError, match="fold_index"):
        fp.plan_fold("towel", 5, lm, q)
    with pytest.raises(PlanningInputError, match="q_current"):
        fp.plan_fold("towel", 0, lm, q[:5])
    with pytest.raises(PlanningInputError, match="bottom-left"):
        fp.plan_fold("towel", 0, {k: v for k, v in lm.items() if k != "bottom-left"}, q)
    with pytest.raises(PlanningInputError, match="category"):
        fp.plan_fold("socks", 0, lm, q)


def test_the_grippers_open_at_the_release_height(fp):
    # the fold ends with the TCPs `release_height` above the table top (forward kinematics of the
    # fold's last point), where they open; the grasp stays at `height`
    motion = copy.copy(fp.motion)
    motion.config = dataclasses.replace(motion.config,
                                        grasp=dataclasses.replace(motion.config.grasp, release_height=0.05))
    planner = FoldPlanner(motion)
    lm = place_garment("towel", planner.table, np.random.default_rng(7),
                       reach_radius=planner.config.reach_radius)
    plan = planner.plan_fold("towel", 0, lm, motion.perceive.copy())
    fold = next(s for s in plan.steps if isinstance(s, PlannedTrajectory) and s.label == "fold")
    for arm in plan.arms:
        start = motion.kin.tcp_pose(fold.positions[0], arm)[2, 3] - planner.table.height
        end = motion.kin.tcp_pose(fold.positions[-1], arm)[2, 3] - planner.table.height
        assert start == pytest.approx(planner.config.grasp.height, abs=1e-3)
        assert end == pytest.approx(0.05, abs=1e-3)


def test_a_straight_lift_has_as_many_poses_for_every_arm_wherever_it_starts():
    """The lift out of a stopped fold moves both arms the same distance: for any start height the
    poses come the same count, spaced no more than a step, ending at the start + the lift."""
    lift, step = 0.08, 0.01
    counts = set()
    for z in np.linspace(0.0, 1.5, 301):
        start, end = np.eye(4), np.eye(4)
        start[2, 3], end[2, 3] = z, z + lift
        poses = interpolate_poses(start, end, step)
        counts.add(len(poses))
        heights = np.array([z, *(p[2, 3] for p in poses)])
        assert np.diff(heights).max() <= step + 1e-12
        assert poses[-1][2, 3] == end[2, 3]
    assert counts == {round(lift / step)}


def test_the_lift_out_of_a_stopped_fold_plans_with_the_arms_at_different_heights(fp):
    """Both TCPs rise by the configured lift (forward kinematics of the plan's last point)."""
    motion = fp.motion
    lower_arm, upper_arm = motion.arm_indices["r1"][1:3]
    for lower, upper in ((0.0, 0.0), (0.1, 0.25), (0.3, -0.75), (0.5, -0.5), (0.4, -1.0)):
        q0 = motion.perceive.copy()
        q0[lower_arm] += lower   # R1's TCP at another height than R2's
        q0[upper_arm] += upper
        planned = motion.lift_move(q0)
        before, after = motion.kin.tcp_poses(q0), motion.kin.tcp_poses(planned.positions[-1])
        for arm in before:
            rise = after[arm][2, 3] - before[arm][2, 3]
            assert rise == pytest.approx(motion.config.grasp.retreat_lift, abs=1e-3), (lower, upper, arm)
