"""`foldcell sim fold`: one fold of the recipe in the cloth-physics world along the planner's path."""

from __future__ import annotations

import argparse
import sys
from typing import TYPE_CHECKING

from drivers.common.garments import CATEGORIES
from tools.common import UsageError, error_exit, print_json

if TYPE_CHECKING:
    from cell.evaluation.fold_success import FoldScore


def cmd_fold(args: argparse.Namespace) -> int:
    from cell.evaluation.sim_fold import run_first_fold, run_recipe  # planner and physics load slowly

    if args.seed < 0:
        raise UsageError(f"--seed: must be >= 0, got {args.seed}")
    if args.lift_fraction is not None and not 0.0 <= args.lift_fraction <= 2.0:
        raise UsageError(f"--lift-fraction: must be within 0..2, got {args.lift_fraction}")
    if args.crease_allowance is not None and not 0.0 <= args.crease_allowance <= 0.1:
        raise UsageError(f"--crease-allowance: must be within 0..0.1 m, got {args.crease_allowance}")
    if not args.speed > 0.0:
        raise UsageError(f"--speed: must be positive, got {args.speed}")
    if args.oracle and not args.recipe:
        raise UsageError("--oracle: folds the whole recipe; give --recipe too")
    if args.recipe:
        if (args.lift_fraction is not None or args.speed != 1.0 or args.release_height is not None
                or args.crease_allowance is not None):
            raise UsageError("--recipe: plays the recipe's own paths; --lift-fraction, --crease-allowance, "
                             "--speed and --release-height are for the first fold")
        whole = run_recipe(args.garment, args.seed, oracle=args.oracle)
        if args.json:
            print_json(whole.as_dict())
            return 0 if whole.success else 1
        hands = "the oracle's grippers placed exactly" if args.oracle else \
            "every fold planned from the true landmarks"
        print(f"{whole.category} seed {whole.seed}, {hands}:")
        for pull in whole.pulls:
            print(f"  before {whole.folds[pull.fold_index]!r}: pulled {pull.distance:.2f} m nearer "
                  f"({pull.why})")
        for name, iou, score in zip(whole.folds, whole.ious, whole.scores, strict=False):
            print(f"  after {name!r}: {_verdict(score)}; IoU {iou:.3f}")
        if len(whole.scores) > len(whole.ious):
            print(f"  {whole.folds[len(whole.ious)]!r}: {_verdict(whole.scores[-1])}")
        if whole.recipe is not None:
            print(f"  after the recipe: {_verdict(whole.recipe)}")
        print(f"  {'success' if whole.success else 'failure: ' + str(whole.cause)}")
        print(f"  robot time {whole.robot_time:.1f} s, wall time {whole.wall_time:.1f} s", file=sys.stderr)
        return 0 if whole.success else 1
    if args.release_height is not None and not 0.0 <= args.release_height <= 0.3:
        raise UsageError(f"--release-height: must be within 0..0.3 m, got {args.release_height}")
    result = run_first_fold(args.garment, args.seed, args.lift_fraction, args.speed,
                            release_height=args.release_height, crease_allowance=args.crease_allowance)
    if args.json:
        print_json(result.as_dict())
        return 0 if result.score.success else 1
    corners = ", ".join(f"{name} {error * 100:.1f} cm" for name, error in result.corner_errors.items())
    grasped = ", ".join(f"{arm} {'took cloth' if took else 'took nothing'}"
                        for arm, took in result.grasped.items())
    print(f"{result.category} seed {result.seed}, fold {result.fold!r}: "
          f"lift fraction {result.lift_fraction:g}, laid {result.crease_allowance * 100:g} cm beyond "
          f"the mirror points, speed x{result.speed:g}, "
          f"released {result.release_height * 100:g} cm above the table")
    print(f"  {_verdict(result.score)}")
    print(f"  IoU against the ideal fold: {result.iou:.3f}")
    placed = ", ".join(f"{arm} {error * 100:.1f} cm" for arm, error in result.place_errors.items())
    print(f"  held cloth from its ideal place: {placed}")
    print(f"  crease {result.crease_offset * 100:.1f} cm short of the fold line")
    print(f"  grasped corners from their ideal place: {corners}")
    print(f"  grippers: {grasped}")
    print(f"  robot time {result.robot_time:.1f} s, wall time {result.wall_time:.1f} s", file=sys.stderr)
    return 0 if result.score.success else 1


def _verdict(score: FoldScore) -> str:
    """The fold-success measure in a line."""
    if score.cause == "unreachable" or score.cause == "grasp lost":
        return f"failure: {score.cause} ({score.detail})"
    figures = (f"landmarks {score.max_error_m * 100:.1f} cm max, {score.mean_error_m * 100:.1f} cm mean; "
               f"drift {score.max_drift_m * 100:.1f} cm; area {score.area_ratio:.2f} of the ideal")
    return ("success: " if score.success else f"failure: {score.cause} ({score.detail}): ") + figures


def _guarded(args: argparse.Namespace) -> int:
    from cell.planning.errors import PlanningError

    try:
        return cmd_fold(args)
    except UsageError as exc:
        return error_exit(str(exc), 2)
    except PlanningError as exc:
        return error_exit(f"the fold cannot be planned: {exc}", 1)


def register(subparsers: argparse._SubParsersAction) -> None:
    sim = subparsers.add_parser("sim", help="the simulated world on its own (cloth physics)",
                                description="The simulated world without processes or wire.")
    group = sim.add_subparsers(dest="sim_command", required=True, metavar="COMMAND")
    p = group.add_parser(
        "fold", help="the recipe's first fold (or all: --recipe) in the cloth-physics world; prints the "
                     "fold-success measure (exit 1 when it misses)",
        description="Plans the recipe's first fold of the garment of --seed from its true landmarks, plays "
                    "the planned arm motion into the cloth-physics world (config/physics.yaml) and prints "
                    "the fold-success measure (every landmark the fold moves within 3 cm of its ideal "
                    "place, 2 cm mean; the rest moved at most 2 cm; the area within 15 %%: "
                    "config/evaluation.yaml), the IoU against the ideal fold and how far the grasped "
                    "corners landed. Exit status 0: the fold (or recipe) succeeded; 1: it missed.")
    p.add_argument("--garment", choices=CATEGORIES, default="towel", help="garment category (default towel)")
    p.add_argument("--seed", type=int, default=1, help="scene seed (default 1)")
    p.add_argument("--lift-fraction", type=float, metavar="F",
                   help="the fold path's apex height as a fraction of |grasp -> place| "
                        "(default: the recipe's)")
    p.add_argument("--crease-allowance", type=float, metavar="M",
                   help="lay the grasped points this far beyond their mirror points (m; default: the "
                        "recipe's)")
    p.add_argument("--speed", type=float, default=1.0, metavar="K",
                   help="play the planned timing K times faster (default 1)")
    p.add_argument("--release-height", type=float, metavar="M",
                   help="open the grippers this high above the table (m; default config/planning.yaml's)")
    p.add_argument("--recipe", action="store_true",
                   help="fold the whole recipe, each fold planned from the true landmarks, and print the "
                        "IoU after each fold against the perfect folds (as the demo scores)")
    p.add_argument("--oracle", action="store_true",
                   help="with --recipe: no planner and no robot, grippers that close exactly where the "
                        "recipe grasps and lay it across the ideal fold line (what the cloth allows at best)")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object: success, cause, landmark_error_cm {max, mean, each}, "
                        "drift_cm, area_ratio, iou, ...; with --recipe: per_fold, recipe, ious")
    p.set_defaults(func=_guarded)
