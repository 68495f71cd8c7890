"""Coordinated stops of the split master/slave processes (`foldcell controller serve --role master|slave`):
for each stop kind during a two-arm motion, the largest distance of a recorded configuration from the
commanded path (the trajectory's points interpolated by scipy, every joint), the ticks from the first
braked tick to rest, and the two arms' rest ticks (equal when coordinated).

    .venv/bin/python -m tests.bench stops
"""

from __future__ import annotations

from pathlib import Path
from tempfile import TemporaryDirectory

from tests.bench.targets import check
from tests.emulator.stop_runs import KINDS, master_and_slave, run_stop

DEVIATION_TARGET_MRAD = 1.0


def main() -> None:
    with TemporaryDirectory() as tmp, master_and_slave(Path(tmp)) as (ep, ctl, rec, _):
        print(f"  {'stop':<11} {'deviation mrad':>15} {'ticks to stop':>14} {'R1 - R2 rest ticks':>19} "
              f"{'peak |a|/limit':>15}")
        for kind in KINDS:
            run = run_stop(kind, ep, ctl, rec)
            deviation = run.deviation() * 1e3
            rest_r1, rest_r2 = run.stop_tick("R1"), run.stop_tick("R2")
            ticks = rest_r1 - run.brake_tick()
            accel = "brakes" if kind == "e-stop" else f"{run.worst_acceleration():.3f}"
            print(f"  {kind:<11} {deviation:>15.3f} {ticks:>14d} {rest_r1 - rest_r2:>19d} {accel:>15}")
            check("stops", f"{kind}: deviation from the coordinated path", round(deviation, 3), "<=",
                  DEVIATION_TARGET_MRAD, "mrad")
            check("stops", f"{kind}: |rest tick of R1 - rest tick of R2|", abs(rest_r1 - rest_r2), "<=", 0,
                  "ticks")


if __name__ == "__main__":
    main()
