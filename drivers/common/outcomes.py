"""How a fold and a garment end: typed, so summaries and reports count them instead of reading text.

The values are what `foldcell_msgs/FoldReport.outcome` carries on the wire; the cause travels beside
them (`FoldReport.cause`), in an operator's words.
"""

from __future__ import annotations

from enum import Enum


class _Outcome(str, Enum):
    """A str whose text is its value, in f-strings and JSON alike (enum.StrEnum from Python 3.11)."""

    def __str__(self) -> str:
        return self.value

    def __format__(self, spec: str) -> str:
        return format(self.value, spec)


class FoldOutcome(_Outcome):
    DONE = "done"                   # the outline after is the one planned
    IMPERFECT = "imperfect"         # the cloth moved, not as planned: the cell goes on from what it sees
    DID_NOT_TAKE = "did not take"   # the outline is unchanged (a grasp took no cloth): tried again
    FAILED = "failed"               # given up, and the garment with it

    @property
    def completed(self) -> bool:
        """The fold happened (perfectly or not): the garment goes on to the next fold."""
        return self in (FoldOutcome.DONE, FoldOutcome.IMPERFECT)

    @staticmethod
    def of_wire(text: str) -> FoldOutcome | None:
        """The outcome a FoldReport carries; None for a text that names none (another version's)."""
        try:
            return FoldOutcome(text)
        except ValueError:
            return None


class GarmentOutcome(_Outcome):
    DONE = "done"                   # every fold of the recipe completed
    FAILED = "failed"               # a fold was given up
    FAULT = "fault"                 # the cell faulted (a lost process, a controller alarm...)
    TIMEOUT = "timeout"             # nothing ended it in the time allowed
    INTERRUPTED = "interrupted"     # the operator stopped it
    REJECTED = "rejected"           # the cell refused to begin it
    ERROR = "error"                 # a process of the cell did not start or died

    @property
    def ends_the_run(self) -> bool:
        """Nothing after it can be folded: the cell's processes are not all there."""
        return self is GarmentOutcome.ERROR
