"""The targets a benchmark prints, checked: `make bench` exits non-zero and names every one missed."""

from __future__ import annotations

import operator
from dataclasses import dataclass

_COMPARE = {"<=": operator.le, ">=": operator.ge, "<": operator.lt, ">": operator.gt}


@dataclass(frozen=True)
class Target:
    bench: str
    name: str
    value: float
    relation: str
    limit: float
    unit: str

    @property
    def met(self) -> bool:
        return bool(_COMPARE[self.relation](self.value, self.limit))

    def describe(self) -> str:
        return (f"{self.bench}: {self.name} {self.value:g} {self.unit} "
                f"(target {self.relation} {self.limit:g} {self.unit})")


RESULTS: list[Target] = []


def check(bench: str, name: str, value: float, relation: str, limit: float, unit: str = "") -> bool:
    """Record one target and print whether it is met; returns whether it is."""
    if relation not in _COMPARE:
        raise ValueError(f"relation: must be one of {', '.join(_COMPARE)}, got {relation!r}")
    target = Target(bench, name, float(value), relation, float(limit), unit)
    RESULTS.append(target)
    print(f"  target {'met   ' if target.met else 'MISSED'}  {target.describe()}", flush=True)
    return target.met


def missed() -> list[Target]:
    return [t for t in RESULTS if not t.met]
