"""Fuzz cases per endpoint: random property-based cases (tests/wire/live_fuzz.py) at every queryable of
a running split cell, counted by how they were answered; the targets are no case left unanswered and no
process dead. `FOLDCELL_FUZZ_EXAMPLES` sets the cases per endpoint (default 300).

    .venv/bin/python -m tests.bench fuzz
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from tempfile import TemporaryDirectory

from tests.bench.targets import check
from tests.wire.live_fuzz import ENDPOINTS, Tally, fuzz_endpoint, live_cell

EXAMPLES = int(os.environ.get("FOLDCELL_FUZZ_EXAMPLES", "300"))


def main() -> None:
    tally = Tally()
    with TemporaryDirectory() as tmp, live_cell(Path(tmp)) as cell:
        for key in ENDPOINTS:
            fuzz_endpoint(cell, key, EXAMPLES, False, tally)
            counts = tally.outcomes.get(key, Counter())
            print(f"  {key:<30} {sum(counts.values()):>5} cases: {counts.get('refused', 0)} refused, "
                  f"{counts.get('answered', 0)} answered, {counts.get('unanswered', 0)} unanswered",
                  flush=True)
        dead = cell.dead()
        flowing = cell.joint_states_flow()
    print(f"  processes dead afterwards: {dead or 'none'}; joint stream {'on' if flowing else 'STOPPED'}")
    check("fuzz", "cases unanswered", len(tally.unanswered), "<=", 0)
    check("fuzz", "processes crashed", len(dead) + (0 if flowing else 1), "<=", 0)


if __name__ == "__main__":
    main()
