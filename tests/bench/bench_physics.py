"""Sweep tables of the fold path in the cloth physics: the recipe's first fold of each category,
planned by the cell's planner from the true landmarks and played into the physics world, judged by
the fold-success measure (cell/evaluation/fold_success.py) on several scenes, for

- apex heights (lift fraction = apex height / |grasp -> place|) against crease allowances (how far
  beyond its mirror point each grasped point is laid: the crease's bend draws the flap back that much
  when the grippers open),
- the planned timing played K times faster, and release heights above the table,

each cell "successes/scenes, median of the largest landmark error (cm)". The recipe's own values
(config/garments/<category>.yaml, config/planning.yaml) are marked with *: the tables are what they
were chosen from. The physics speed (simulated robot seconds per wall second) is printed last.

Run: .venv/bin/python -m tests.bench physics   (or `foldcell sim fold --garment C --seed S
[--lift-fraction F] [--crease-allowance M] [--speed K] [--release-height M]`)
"""

from __future__ import annotations

import os
import statistics

from cell.evaluation.sim_fold import SimFoldResult, run_first_fold
from cell.planning.folds import FoldPlanner, load_recipe
from drivers.common.garments import CATEGORIES
from tests.bench.targets import check

SEEDS = tuple(range(1, int(os.environ.get("FOLDCELL_BENCH_SEEDS", "4")) + 1))
LIFT_FRACTIONS = (0.05, 0.2, 0.4, 0.6)
CREASE_ALLOWANCES = (0.0, 0.02, 0.04)    # m
SPEEDS = (1.0, 2.0)
RELEASE_HEIGHTS = (0.005, 0.03)          # m above the table
TOWEL_TARGET = 0.95                      # share of towel first folds that succeed at the recipe's path


def cell(results: list[SimFoldResult]) -> str:
    done = sum(r.score.success for r in results)
    worst = statistics.median(r.score.max_error_m * 100 for r in results)
    return f"{done}/{len(results)} {worst:4.1f}"


def main() -> None:
    planner = FoldPlanner()
    seeds = ", ".join(map(str, SEEDS))
    print(f"first fold of each recipe, scenes {seeds}: successes / median largest landmark error (cm)")
    print(f"  {'garment':<13} {'lift':>5}  "
          + "  ".join(f"{f'laid +{a * 100:g} cm':>12}" for a in CREASE_ALLOWANCES))
    robot_s = wall_s = 0.0
    at_recipe: dict[str, list[SimFoldResult]] = {}
    for category in CATEGORIES:
        first = load_recipe(category).folds[0]
        for lift in sorted({*LIFT_FRACTIONS, first.lift_fraction}):
            cells = []
            for allowance in sorted({*CREASE_ALLOWANCES, first.crease_allowance}):
                results = [run_first_fold(category, seed, lift, planner=planner, crease_allowance=allowance)
                           for seed in SEEDS]
                robot_s += sum(r.robot_time for r in results)
                wall_s += sum(r.physics_wall_time for r in results)
                mark = "*" if (lift, allowance) == (first.lift_fraction, first.crease_allowance) else " "
                cells.append(f"{cell(results)}{mark}")
                if mark == "*":
                    at_recipe[category] = results
            print(f"  {category:<13} {lift:>5.2f}  " + "  ".join(f"{c:>12}" for c in cells), flush=True)
    own_height = planner.config.grasp.release_height
    print(f"the recipe's first fold played faster and released higher, scenes {seeds}")
    print(f"  {'garment':<13} " + "  ".join(f"{f'speed x{s:g}':>12}" for s in SPEEDS) + "  "
          + "  ".join(f"{f'release {h * 100:g} cm':>15}" for h in RELEASE_HEIGHTS))
    for category in CATEGORIES:
        cells = []
        for speed in SPEEDS:
            results = at_recipe[category] if speed == 1.0 else \
                [run_first_fold(category, seed, speed=speed, planner=planner) for seed in SEEDS]
            cells.append(cell(results) + ("*" if speed == 1.0 else " "))
        line = "  ".join(f"{c:>12}" for c in cells)
        for height in RELEASE_HEIGHTS:
            results = at_recipe[category] if height == own_height else \
                [run_first_fold(category, seed, planner=planner, release_height=height) for seed in SEEDS]
            line += f"  {cell(results) + ('*' if height == own_height else ' '):>15}"
        print(f"  {category:<13} {line}", flush=True)
    towel = at_recipe["towel"]
    check("physics", f"towel: first folds that succeed at the recipe's path, scenes {seeds}",
          sum(r.score.success for r in towel) / len(towel), ">=", TOWEL_TARGET)
    check("physics", "physics speed: simulated robot seconds per wall second (one core)",
          robot_s / wall_s, ">=", 2.0)


if __name__ == "__main__":
    main()
