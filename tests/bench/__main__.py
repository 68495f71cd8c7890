"""`make bench`: every benchmark module's figures, one after another.

Exits non-zero when a benchmark breaks or a target it prints (`tests.bench.targets.check`) is missed,
and lists them at the end.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
import time
from pathlib import Path

from tests.bench import targets


def main(argv: list[str]) -> int:
    wanted = set(argv)
    here = Path(__file__).parent
    names = sorted(m.name for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))
    failed = []
    for name in names:
        if wanted and name not in wanted and name.removeprefix("bench_") not in wanted:
            continue
        print(f"\n=== {name} ===", flush=True)
        start = time.monotonic()
        try:
            importlib.import_module(f"tests.bench.{name}").main()
        except Exception as exc:  # one broken benchmark must not hide the others' figures
            failed.append(name)
            print(f"{name} failed: {type(exc).__name__}: {exc}", flush=True)
        print(f"({name}: {time.monotonic() - start:.1f} s)", flush=True)
    if failed:
        print(f"\nbenchmarks that broke: {', '.join(failed)}")
    missed = targets.missed()
    if missed:
        print(f"\ntargets missed ({len(missed)} of {len(targets.RESULTS)}):")
        for target in missed:
            print(f"  {target.describe()}")
    elif targets.RESULTS:
        print(f"\nall {len(targets.RESULTS)} targets met")
    return 1 if failed or missed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
