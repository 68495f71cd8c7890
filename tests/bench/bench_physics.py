"""Benchmark of folds in the cloth physics: the recipe's first fold of each category, planned by the
cell's planner from the true landmarks and played into the physics world, its final silhouette's IoU
against the ideal fold and how far its crease falls short of the fold line, for several apex
heights (lift fraction = apex height / |grasp -> place|) and speeds (the planned timing played K times
faster). The recipe's own lift fraction is marked with *.

Then every fold of each recipe, each planned from the true landmarks: what the cloth does to a
recipe with perception left out.

Run: .venv/bin/python -m tests.bench physics   (or `foldcell sim fold --garment C [--lift-fraction F]
[--recipe]`)
"""

from __future__ import annotations

from cell.evaluation.sim_fold import run_first_fold, run_recipe
from cell.planning.folds import FoldPlanner, load_recipe
from drivers.common.garments import CATEGORIES
from tests.bench.targets import check

SEED = 1
SEEDS = (1, 2, 3)         # the recipe's own path, averaged over these scenes, is the target
LIFT_FRACTIONS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7)
RELEASE_HEIGHTS = (0.03, 0.06)   # m, besides the planner's own (config/planning.yaml grasp.release_height)
SPEEDS = (1.0, 2.0)


def main() -> None:
    planner = FoldPlanner()
    print(f"first fold of each recipe, seed {SEED}: IoU against the ideal fold / crease short of the fold "
          f"line (cm, < 0: beyond it)")
    print(f"  {'garment':<13} {'lift':>5}  " + "  ".join(f"{f'speed x{s:g}':>16}" for s in SPEEDS)
          + f"  {'wall s':>6}")
    at_recipe: dict[str, float] = {}
    for category in CATEGORIES:
        recipe_lift = load_recipe(category).folds[0].lift_fraction
        for lift in sorted({*LIFT_FRACTIONS, recipe_lift}):
            cells, wall = [], 0.0
            for speed in SPEEDS:
                result = run_first_fold(category, SEED, lift, speed, planner)
                cells.append(f"{result.iou:.3f} / {result.crease_offset * 100:5.1f}")
                wall += result.wall_time
                if lift == recipe_lift and speed == 1.0:
                    at_recipe[category] = result.iou
            mark = "*" if lift == recipe_lift else " "
            print(f"  {category:<13} {lift:>4.2f}{mark}  " + "  ".join(f"{c:>16}" for c in cells)
                  + f"  {wall / len(SPEEDS):>6.1f}", flush=True)
    own = planner.config.grasp.release_height
    print(f"first fold at the recipe's path, seeds {', '.join(map(str, SEEDS))}, released "
          f"{own * 100:g} cm (the planner's), then mean IoU released higher: "
          + ", ".join(f"{height * 100:g} cm" for height in RELEASE_HEIGHTS))
    for category in CATEGORIES:
        ious = [at_recipe[category] if seed == SEED
                else run_first_fold(category, seed, None, 1.0, planner).iou for seed in SEEDS]
        higher = [sum(run_first_fold(category, seed, None, 1.0, planner, release_height=height).iou
                      for seed in SEEDS) / len(SEEDS) for height in RELEASE_HEIGHTS]
        print(f"  {category:<13} " + "  ".join(f"{iou:.3f}" for iou in ious)
              + f"  mean {sum(ious) / len(ious):.3f}   higher: " + "  ".join(f"{iou:.3f}" for iou in higher),
              flush=True)
        check("physics", f"{category}: first fold IoU at the recipe's path, mean of {len(SEEDS)} scenes",
              sum(ious) / len(ious), ">=", 0.9)
    print(f"the whole recipe, each fold planned from the true landmarks (perfect perception), seeds "
          f"{', '.join(map(str, SEEDS))}: IoU after each fold against the perfect folds")
    for category in CATEGORIES:
        results = [run_recipe(category, seed, planner) for seed in SEEDS]
        print(f"  {category:<13} " + "   ".join(" ".join(f"{iou:.3f}" for iou in r.ious) for r in results)
              + f"   ({sum(r.wall_time for r in results) / len(results):.1f} s wall per garment)", flush=True)
        check("physics", f"{category}: whole recipe's final IoU, mean of {len(SEEDS)} scenes",
              sum(r.ious[-1] for r in results) / len(results), ">=", 0.9)


if __name__ == "__main__":
    main()
