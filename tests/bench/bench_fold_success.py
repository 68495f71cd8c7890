"""Benchmark of the fold-success measure (cell/evaluation/fold_success.py) in the cloth-physics world:
every category's whole recipe on many seeds, folded by the oracle (grippers placed exactly where the
recipe grasps and laid across the ideal fold line: no robot, no planner, no perception) and by the
planner (each fold planned from the true landmarks and played as the controller moves the arms).
Per category: the share that succeeded, every failure's cause, the landmark errors and the robot
time. The oracle calibrates the measure: what it cannot pass, the cloth or the recipe cannot do.

Run: .venv/bin/python -m tests.bench fold_success   (FOLDCELL_BENCH_SEEDS=N for fewer seeds; or
`foldcell sim fold --garment C --seed S --recipe [--oracle]`)
"""

from __future__ import annotations

import collections
import os
import statistics

from cell.evaluation.sim_fold import SimRecipeResult, run_recipe
from cell.planning.folds import FoldPlanner
from drivers.common.garments import CATEGORIES
from tests.bench.targets import check

SEEDS = tuple(range(1, int(os.environ.get("FOLDCELL_BENCH_SEEDS", "20")) + 1))
TARGET = 0.95          # share of garments folded with success (the figure)


def summary(category: str, hands: str, results: list[SimRecipeResult]) -> float:
    done = sum(r.success for r in results)
    # the garment in place after its recipe (every landmark within 5 cm), whatever each fold's own score
    in_place = sum(r.recipe is not None and r.recipe.success for r in results)
    causes = collections.Counter(f"{r.cause}@{_first_miss(r)}" for r in results if not r.success)
    finals = [r.recipe.max_error_m * 100 for r in results if r.recipe is not None]
    per_fold_mean = [statistics.mean(s.mean_error_m * 100 for s in r.scores if s.landmark_errors_m)
                     for r in results if any(s.landmark_errors_m for s in r.scores)]
    print(f"  {category:<13} {hands:<8} {done:>3}/{len(results):<3} {in_place:>3}/{len(results):<3} "
          f"{statistics.median(per_fold_mean) if per_fold_mean else float('nan'):>10.1f} "
          f"{statistics.median(finals) if finals else float('nan'):>10.1f} "
          f"{statistics.mean(r.robot_time for r in results):>8.1f}  "
          + ", ".join(f"{cause} x{n}" for cause, n in causes.most_common()), flush=True)
    return done / len(results)


def _first_miss(result: SimRecipeResult) -> str:
    for score in result.scores:
        if not score.success:
            return f"fold {score.fold}"
    return "recipe"


def main() -> None:
    planner = FoldPlanner()
    print(f"whole recipes in the cloth world, seeds {SEEDS[0]}..{SEEDS[-1]}: success by the fold-success "
          "measure (config/evaluation.yaml)")
    print(f"  {'garment':<13} {'hands':<8} {'done':>7} {'in place':>8} {'fold cm':>10} {'recipe cm':>10} "
          f"{'robot s':>8}  causes (at the first miss)")
    print("  (done: every fold and the recipe by the measure; in place: the recipe's end alone; fold cm: "
          "median of the mean landmark error per fold; recipe cm: median of the largest landmark error "
          "after the recipe)")
    for category in CATEGORIES:
        for oracle in (True, False):
            results = [run_recipe(category, seed, planner, oracle=oracle) for seed in SEEDS]
            share = summary(category, "oracle" if oracle else "planner", results)
            check("fold_success", f"{category}: {'oracle' if oracle else 'planner'} folds that succeed",
                  share, ">=", TARGET)


if __name__ == "__main__":
    main()
