"""`foldcell plan ...`: check the planner on random garment placements, query reachability."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Mapping
from typing import Any

from tools.common import UsageError, error_exit


def _guard(fn):
    def run(args: argparse.Namespace) -> int:
        from cell.planning.errors import PlanningError, PlanningInputError
        from drivers.common.configfile import ConfigError
        try:
            return fn(args)
        except (UsageError, ConfigError, PlanningInputError) as exc:
            return error_exit(str(exc), 2)
        except PlanningError as exc:
            return error_exit(str(exc), 1)
    return run


def cmd_check(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from cell.planning.errors import PlanningError
    from cell.planning.folds import FoldPlanner
    from drivers.common.garments import CATEGORIES
    from drivers.sim.garments import place_garment

    if args.placements < 1:
        raise UsageError(f"--placements must be >= 1, got {args.placements}")
    if args.seed < 0:
        raise UsageError(f"--seed must be >= 0, got {args.seed}")
    categories = CATEGORIES if args.category == "all" else (args.category,)
    fp = FoldPlanner()
    rng = np.random.default_rng(args.seed)
    report: dict[str, Any] = {}
    total = args.placements * len(categories)
    with tqdm(total=total, desc="planning", unit="garment", file=sys.stderr, disable=args.quiet) as bar:
        for cat in categories:
            times, robot, failures, ok = [], [], [], 0
            for _ in range(args.placements):
                lm: Mapping[str, tuple[float, float]] = place_garment(
                    cat, fp.table, rng, reach_radius=fp.config.reach_radius)
                q = fp.motion.perceive.copy()
                good = True
                for k in range(len(fp.recipe(cat).folds)):
                    t = time.perf_counter()
                    try:
                        plan = fp.plan_fold(cat, k, lm, q)
                    except PlanningError as exc:
                        failures.append({"fold": k, "error": str(exc)})
                        good = False
                        break
                    finally:
                        times.append(time.perf_counter() - t)
                    for step in plan.trajectories:   # the controller's rules and a dense collision check
                        fp.motion.validate(step, q, fp.motion.controller_config.interpolation_period)
                        q = step.positions[-1]
                    robot.append(plan.robot_time)
                    lm = plan.expected_outline
                ok += good
                bar.update(1)
            report[cat] = {
                "garments": args.placements, "succeeded": ok, "success_rate": ok / args.placements,
                "planning_ms_median": float(np.median(times) * 1000),
                "planning_ms_p95": float(np.percentile(times, 95) * 1000),
                "robot_s_per_fold_median": float(np.median(robot)) if robot else None,
                "failures": failures[:5],
            }
    if args.json:
        json.dump(report, sys.stdout)
        print()
    else:
        for cat, r in report.items():
            print(f"{cat:>12}: {r['succeeded']}/{r['garments']} garments folded "
                  f"({100 * r['success_rate']:.1f} %), "
                  f"planning per fold median {r['planning_ms_median']:.0f} ms, "
                  f"p95 {r['planning_ms_p95']:.0f} ms, "
                  f"robot time per fold {r['robot_s_per_fold_median'] or 0:.1f} s")
            for f in r["failures"]:
                print(f"{'':>14}fold {f['fold']}: {f['error']}")
    return 0 if all(r["succeeded"] == r["garments"] for r in report.values()) else 1


def cmd_reach(args: argparse.Namespace) -> int:
    from cell.planning.folds import FoldPlanner

    if not (math.isfinite(args.x) and math.isfinite(args.y)):
        raise UsageError(f"x, y: must be finite numbers (m), got {args.x:g} {args.y:g}")
    fp = FoldPlanner()
    ok = fp.reachable((args.x, args.y), arm=args.arm)
    if args.json:
        print(json.dumps({"x": args.x, "y": args.y, "arm": args.arm, "reachable": ok}))
    else:
        who = args.arm or "either arm"
        print(f"table ({args.x:.3f}, {args.y:.3f}) m: {'reachable' if ok else 'NOT reachable'} by {who}")
    return 0 if ok else 1


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("plan", help="motion and fold planning tools",
                              description="Check the fold planner offline (no Zenoh, no controller needed).")
    sub = p.add_subparsers(dest="plan_command", required=True)
    c = sub.add_parser("check", help="plan every fold of random garment placements and check each trajectory "
                       "against the controller's rules and for collisions")
    c.add_argument("--category", default="all",
                   choices=("all", "towel", "pants", "short-sleeve", "long-sleeve"), help="garment category")
    c.add_argument("--placements", type=int, default=20, help="random placements per category (default 20)")
    c.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    c.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    c.set_defaults(func=_guard(cmd_check))
    r = sub.add_parser("reach", help="can an arm grasp at a point of the table (table frame, m)?")
    r.add_argument("x", type=float, help="table x (m, from the near edge, away from the robot)")
    r.add_argument("y", type=float, help="table y (m, from the right-hand corner)")
    r.add_argument("--arm", choices=("r1", "r2"), help="only this arm")
    r.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    r.set_defaults(func=_guard(cmd_reach))


__all__ = ["register"]
