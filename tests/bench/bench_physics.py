"""Benchmark of the cloth physics: a 0.5 m square folded in half along the planner's triangular path,
the final silhouette's IoU against the ideal half for several apex heights (lift fraction = apex
height / |grasp -> place|), and the wall time per fold.

Run: .venv/bin/python -m tests.bench.bench_physics
"""

from __future__ import annotations

from cell.planning.config import default_planning_config
from drivers.sim.physics.config import load_physics_config
from drivers.sim.physics.measure import fold_square_in_half
from tests.bench.targets import check

SIDE = 0.5
LIFT_FRACTIONS = (0.05, 0.1, 0.2, 0.3, 0.5)


def main() -> None:
    config = load_physics_config()
    grasp = default_planning_config().grasp
    print(f"{SIDE} m square folded in half, grasp {grasp.depth} m inside the corners, "
          f"{grasp.height} m above the table")
    print(f"  {'lift fraction':>13}  {'IoU':>6}  {'wall s':>7}  {'sim s':>6}  {'x real time':>11}")
    best = 0.0
    for lift_fraction in LIFT_FRACTIONS:
        fold = fold_square_in_half(SIDE, lift_fraction, config, grasp_inset=grasp.depth,
                                   grasp_height=grasp.height)
        best = max(best, fold.iou)
        print(f"  {lift_fraction:>13.2f}  {fold.iou:>6.3f}  {fold.wall_time:>7.2f}  "
              f"{fold.simulated_time:>6.2f}  {fold.simulated_time / fold.wall_time:>11.2f}", flush=True)
    check("physics", "half-fold IoU at the best lift fraction", best, ">=", 0.9)


if __name__ == "__main__":
    main()
