"""A cell's garments and folds from its state machine's transitions (`cell/state` history). Pure.

Shared by the monitor (elapsed time of each fold, live) and the session report (per-fold timings).
A garment is taken up by `start` (or `restore`); `verified` ends a fold, and the next one begins at
the same stamp unless the garment is done; going to `failed` or a `reset` ends fold and garment.
Folds are numbered from 1 in the order seen; `GarmentSpan.renumbered` aligns them with the cell's
own `fold_index` (a restored garment goes on after its last checked fold, a long history may have
lost a garment's first folds).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from typing import Any

from drivers.wire import messages

GARMENT_STARTS = ("start", "restore")  # transitions that take up a garment
GARMENT_ENDS = ("done", "failed")      # states in which a garment's clock stops
FOLD_CHECKED = "verified"
GARMENT_CLEARED = "reset"


@dataclass(frozen=True)
class Transition:
    stamp_ns: int
    trigger: str
    source: str
    dest: str


@dataclass
class FoldSpan:
    fold: int
    start_ns: int | None                 # None: began before the first transition given
    end_ns: int | None = None            # None: still in work
    outcome: str = ""                    # done | failed | reset; "" while in work
    stages_ns: dict[str, int] = field(default_factory=dict)  # state -> time spent in it
    last_ns: int | None = None           # the fold's latest transition

    def seconds(self, now_ns: int) -> float | None:
        """How long the fold took (to `now_ns` while in work); None when its start is unknown."""
        if self.start_ns is None:
            return None
        return ((now_ns if self.end_ns is None else self.end_ns) - self.start_ns) / 1e9


@dataclass
class GarmentSpan:
    start_ns: int | None
    trigger: str                          # start | restore | "" (began before the transitions given)
    folds: list[FoldSpan] = field(default_factory=list)
    end_ns: int | None = None
    outcome: str = ""

    def renumbered(self, last_fold: int) -> GarmentSpan:
        """The same garment with its folds numbered so that the last one is `last_fold`."""
        shift = last_fold - self.folds[-1].fold if self.folds else 0
        return replace(self, folds=[replace(f, fold=f.fold + shift) for f in self.folds])


def transitions_of(history: Iterable[Any]) -> list[Transition]:
    """`foldcell_msgs/CellTransition` messages -> Transitions."""
    return [Transition(messages.stamp_to_ns(t.stamp), t.trigger, t.source, t.dest) for t in history]


def split_garments(transitions: Iterable[Transition]) -> list[GarmentSpan]:
    """Garments with their folds, in order. Transitions before the first `start` or `restore` that
    are not `reset` belong to a garment (and a fold) whose start is unknown. Duplicates (the same
    transition in several histories) count once."""
    garments: list[GarmentSpan] = []
    current: GarmentSpan | None = None
    for t in sorted(set(transitions), key=lambda t: t.stamp_ns):
        if current is None and not garments and t.trigger not in (*GARMENT_STARTS, GARMENT_CLEARED) \
                and t.source != "idle":
            current = GarmentSpan(None, "", [FoldSpan(1, None)])
            garments.append(current)
        fold = current.folds[-1] if current is not None and current.folds else None
        if fold is not None and fold.end_ns is None:
            since = fold.last_ns if fold.last_ns is not None else fold.start_ns
            if since is not None:
                fold.stages_ns[t.source] = fold.stages_ns.get(t.source, 0) + t.stamp_ns - since
            fold.last_ns = t.stamp_ns
        if t.trigger in GARMENT_STARTS:
            if current is not None and current.end_ns is None:
                _end(current, t.stamp_ns, "interrupted")
            current = GarmentSpan(t.stamp_ns, t.trigger, [FoldSpan(1, t.stamp_ns, last_ns=t.stamp_ns)])
            garments.append(current)
        elif current is None or current.end_ns is not None:
            continue
        elif t.trigger == FOLD_CHECKED:
            if t.dest == "done":
                _end(current, t.stamp_ns, "done")
            else:
                assert fold is not None
                fold.end_ns, fold.outcome = t.stamp_ns, "done"
                current.folds.append(FoldSpan(fold.fold + 1, t.stamp_ns, last_ns=t.stamp_ns))
        elif t.dest == "failed":
            _end(current, t.stamp_ns, "failed")
        elif t.trigger == GARMENT_CLEARED:
            _end(current, t.stamp_ns, "reset")
    return garments


def _end(garment: GarmentSpan, stamp_ns: int, outcome: str) -> None:
    garment.end_ns, garment.outcome = stamp_ns, outcome
    fold = garment.folds[-1]
    if fold.end_ns is None:
        fold.end_ns, fold.outcome = stamp_ns, outcome
