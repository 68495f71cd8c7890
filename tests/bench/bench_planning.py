"""Benchmark of planning: IK, collision checking (python-fcl vs coal), RRT-Connect, and whole folds.

Prints medians over repeated runs; fold planning over 200 random garment placements (50 per
category) inside the reachable area, each garment folded through its whole recipe.

Run: .venv/bin/python -m tests.bench.bench_planning
"""

from __future__ import annotations

import contextlib
import time

import numpy as np

from cell.planning.errors import PlanningError
from cell.planning.folds import FoldPlanner
from cell.planning.motion import MotionPlanner
from drivers.common.garments import CATEGORIES
from drivers.sim.garments import place_garment
from tests.bench.targets import check

PLACEMENTS_PER_CATEGORY = 50
# the planner's targets: planning time of one fold, and garments planned through their whole recipe
MAX_PLANNING_PER_FOLD_MS = 150.0
MIN_PLAN_SUCCESS_PERCENT = 99.0


def ms(a: list[float]) -> str:
    x = np.array(a) * 1000.0
    return f"median {np.median(x):8.3f} ms   p95 {np.percentile(x, 95):8.3f} ms   (n={len(x)})"


def bench_ik(mp: MotionPlanner) -> None:
    rng = np.random.default_rng(1)
    times, ok = [], 0
    for i in range(300):
        arm = ("r1", "r2")[i % 2]
        idx = mp.arm_indices[arm]
        q_true = mp.perceive.copy()
        seed = mp.config.ik_seeds[rng.integers(len(mp.config.ik_seeds))]
        q_true[idx] = np.array(seed) + rng.uniform(-0.4, 0.4, 6)
        target = mp.kin.tcp_pose(np.clip(q_true, mp.robot.lower, mp.robot.upper), arm)
        seeds = []
        for s in mp.config.ik_seeds:
            q = mp.perceive.copy()
            q[idx] = s
            seeds.append(q)
        t = time.perf_counter()
        r = mp.ik.solve_multi(arm, target, seeds)
        times.append(time.perf_counter() - t)
        ok += r.success
    print(f"IK, cold (configured seeds), random reachable targets: {ms(times)}  success {ok}/300")
    # warm: the case of Cartesian interpolation, seeded from the previous point 1 cm away
    times = []
    for _ in range(300):
        q = mp.perceive.copy()
        q[mp.arm_indices["r1"]] = mp.config.ik_seeds[0]
        T = mp.kin.tcp_pose(q, "r1")
        T[:3, 3] += rng.normal(size=3) * 0.006
        t = time.perf_counter()
        mp.ik.solve("r1", T, q)
        times.append(time.perf_counter() - t)
    print(f"IK, warm (seed 1 cm away, Cartesian step):        {ms(times)}")


def bench_collision(mp: MotionPlanner) -> None:
    rng = np.random.default_rng(2)
    qs = []
    while len(qs) < 300:   # collision-free configurations: every pair is checked
        q = np.clip(mp.perceive + rng.uniform(-1.0, 1.0, 13), mp.robot.lower, mp.robot.upper)
        if not mp.collision.in_collision(q):
            qs.append(q)
    res = {}
    for backend in ("fcl", "coal"):
        times = []
        for _ in range(3):
            for q in qs:
                t = time.perf_counter()
                mp.collision.in_collision(q, backend=backend)
                times.append(time.perf_counter() - t)
        res[backend] = float(np.median(times))
        print(f"collision check, full cell ({len(mp.collision.pairs)} pairs), {backend:>4}: {ms(times)}")
    print(f"python-fcl / coal time ratio: {res['fcl'] / res['coal']:.1f}  "
          f"(planner uses: {mp.config.collision.backend})")


def bench_rrt(mp: MotionPlanner) -> None:
    rng = np.random.default_rng(3)
    times = []
    tries = 0
    while len(times) < 20 and tries < 5000:
        tries += 1
        a = np.clip(mp.perceive + rng.uniform(-1.5, 1.5, 13), mp.robot.lower, mp.robot.upper)
        b = np.clip(mp.perceive + rng.uniform(-1.5, 1.5, 13), mp.robot.lower, mp.robot.upper)
        if not (mp.valid(a) and mp.valid(b)) or mp.segment_free(a, b):
            continue
        t = time.perf_counter()
        with contextlib.suppress(PlanningError):   # a failed search is timed as well
            mp.rrt_connect(a, b)
        times.append(time.perf_counter() - t)
    print(f"RRT-Connect (13 joints, straight path blocked), incl. simplify + re-check: {ms(times)}")


def reach_map(fp: FoldPlanner) -> None:
    """How many of 8 approach directions reach each table point (pre-grasp and grasp, collision-free,
    any arm and turn-table angle); the radius of the all-direction area backs `folds.reach_radius`."""
    mp, g = fp.motion, fp.config.grasp
    xs, ys = np.arange(0.05, 0.8, 0.1), np.arange(0.05, 1.2, 0.1)
    full_r: list[float] = []
    part_r: list[float] = []
    print("reach map: approach directions (of 8) reachable at table (x down, y across)")
    print("      " + " ".join(f"{y:4.2f}" for y in ys))
    for x in xs:
        row = []
        for y in ys:
            G = np.array([x, y])
            count = 0
            for d in range(8):
                P = G + 0.3 * np.array([np.cos(d * np.pi / 4), np.sin(d * np.pi / 4)])
                count += any(_reaches(fp, mp, G, P, th, arm)
                             for th in g.turntable_angles for arm in ("r1", "r2"))
            row.append(count)
            r = float(np.linalg.norm(fp.table.table_to_world(G)[0][:2]))
            (full_r if count == 8 else part_r).append(r)
        print(f"{x:5.2f} " + " ".join(f"{c:4d}" for c in row))
    nearest_missing = min(part_r) if part_r else float("nan")
    print(f"all 8 directions reachable up to {max(full_r):.3f} m from the turn-table axis; nearest point "
          f"missing one: {nearest_missing:.3f} m (config reach_radius {fp.config.reach_radius} m)")


def _reaches(fp: FoldPlanner, mp: MotionPlanner, G: np.ndarray, P: np.ndarray, theta: float,
             arm: str) -> bool:
    q = mp.perceive.copy()
    q[mp.ext_index] = theta
    poses = fp._key_poses(G, P, 0.4, 0.0)
    idx = mp.arm_indices[arm]
    for s in mp.config.ik_seeds:
        seed = q.copy()
        seed[idx] = s
        r = mp.ik.solve(arm, poses["pregrasp"], seed)
        if r.success and not mp.collision.in_collision(r.q):
            r2 = mp.ik.solve(arm, poses["grasp"], r.q)
            if r2.success and not mp.collision.in_collision(r2.q, allow_finger_contact=True):
                return True
    return False


def bench_folds(fp: FoldPlanner) -> None:
    for cat in CATEGORIES:
        rng = np.random.default_rng(1000 + CATEGORIES.index(cat))
        times: list[float] = []
        robot: dict[int, list[float]] = {}
        ok_garments = 0
        folds_ok = folds_tried = 0
        failures: list[str] = []
        n_folds = len(fp.recipe(cat).folds)
        for _ in range(PLACEMENTS_PER_CATEGORY):
            lm = place_garment(cat, fp.table, rng, reach_radius=fp.config.reach_radius)
            q = fp.motion.perceive.copy()
            good = True
            for k in range(n_folds):
                folds_tried += 1
                t = time.perf_counter()
                try:
                    plan = fp.plan_fold(cat, k, lm, q)
                except PlanningError as exc:
                    times.append(time.perf_counter() - t)
                    failures.append(f"fold {k}: {exc}")
                    good = False
                    break
                times.append(time.perf_counter() - t)
                folds_ok += 1
                robot.setdefault(k, []).append(plan.robot_time)
                lm, q = plan.expected_outline, plan.final_positions
            ok_garments += good
        success_percent = 100.0 * ok_garments / PLACEMENTS_PER_CATEGORY
        print(f"{cat:>12}: planning per fold {ms(times)}")
        print(f"{'':>12}  success: garments {ok_garments}/{PLACEMENTS_PER_CATEGORY} "
              f"({success_percent:.1f} %), folds {folds_ok}/{folds_tried}")
        rt = "  ".join(f"fold {k + 1}: {np.median(v):.1f} s" for k, v in sorted(robot.items()))
        print(f"{'':>12}  robot time per fold (median, incl. move to perceive): {rt}")
        for f in failures[:3]:
            print(f"{'':>12}  failed: {f}")
        check("planning", f"{cat} planning per fold, median", float(np.median(times)) * 1000.0, "<=",
              MAX_PLANNING_PER_FOLD_MS, "ms")
        check("planning", f"{cat} garments planned through the recipe", success_percent, ">=",
              MIN_PLAN_SUCCESS_PERCENT, "%")


def main() -> None:
    t = time.perf_counter()
    mp = MotionPlanner()
    fp = FoldPlanner(mp)
    print(f"planner set-up (model, collision pairs, IK): {1000 * (time.perf_counter() - t):.0f} ms")
    bench_ik(mp)
    bench_collision(mp)
    bench_rrt(mp)
    bench_folds(fp)
    reach_map(fp)


if __name__ == "__main__":
    main()
