"""The job a cell is working on, kept in a small JSON file so a restarted cell daemon takes the garment up
after its last completed fold.

The file holds what the next fold needs and cannot see again: the model to match (the folded model of
the last completed fold, paper Sec. III-F) and where that fold left each landmark on the table. It is
written whole to a temporary file and renamed over the old one, so a crash leaves the old file or the
new one, never half of either. A file this code cannot read (corrupt, another version) is refused with
an error naming the file and the field.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cell.perception.models import PolygonalModel, model_from_fields
from drivers.common.configfile import ConfigError, Fields
from statemachine.machine import STATES

JOB_FILE_VERSION = 1
JOB_FIELDS = {"version", "category", "fold_count", "folds_done", "state", "attempt", "model",
              "expected_landmarks"}


class JobFileError(ConfigError):
    """The job file cannot be read or holds a wrong value: names the file, the field and the reason."""


@dataclass(frozen=True)
class JobRecord:
    category: str
    fold_count: int
    folds_done: int                      # the last completed fold (0: none yet)
    state: str                           # the cell's state when the record was written
    attempt: int                         # the attempt at the fold after `folds_done`
    model: PolygonalModel                # the model to match next: the garment after `folds_done` folds
    expected_landmarks: dict[str, tuple[float, float]] | None  # where that fold left them (table, m)

    def describe(self) -> str:
        return f"{self.category} after fold {self.folds_done}/{self.fold_count}"

    def to_dict(self) -> dict[str, Any]:
        expected = None if self.expected_landmarks is None else {
            name: [float(x), float(y)] for name, (x, y) in self.expected_landmarks.items()}
        return {"version": JOB_FILE_VERSION, "category": self.category, "fold_count": self.fold_count,
                "folds_done": self.folds_done, "state": self.state, "attempt": self.attempt,
                "model": self.model.to_dict(exact=True), "expected_landmarks": expected}


def record_from_fields(fields: Fields) -> JobRecord:
    version = fields.raw("version", None)
    if version != JOB_FILE_VERSION:
        raise JobFileError(fields.file, "version", f"{version!r} is not a job file version this cell reads "
                                                   f"({JOB_FILE_VERSION})")
    fields.reject_unknown(JOB_FIELDS)
    fold_count = fields.int("fold_count", min=1)
    try:
        model = model_from_fields(fields.sub("model"))
    except ConfigError as exc:  # a model that does not hold together names its vertices, not where they are
        field = exc.field if exc.field.startswith("model") else f"model.{exc.field}"
        raise JobFileError(fields.file, field, exc.reason) from exc
    category = fields.str("category")
    if model.category != category:
        raise JobFileError(fields.file, "model.category",
                           f"{model.category!r} is not the job's category {category!r}")
    expected = None
    if fields.raw("expected_landmarks", None) is not None:
        points = fields.sub("expected_landmarks")
        expected = {}
        for name in points.data:
            x, y = points.floats(name, length=2)
            expected[name] = (x, y)
    state = fields.str("state")
    if state not in STATES:
        raise JobFileError(fields.file, "state",
                           f"{state!r} is not a state of the cell ({', '.join(STATES)})")
    return JobRecord(category, fold_count, fields.int("folds_done", min=0, max=fold_count - 1), state,
                     fields.int("attempt", min=1), model, expected)


class JobFile:
    """The file at `path`: `save` a record, `load` it back (None when there is none), `clear` it."""

    def __init__(self, path: Path):
        self.path = Path(path)

    def save(self, record: JobRecord) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        temporary = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        # no fsync: it is written on every transition, a fault's among them, ahead of the robot's stop;
        # a crashed process (not machine) leaves its writes to the kernel, which the rename orders
        with open(temporary, "w") as f:
            json.dump(record.to_dict(), f, indent=1)
        os.replace(temporary, self.path)  # atomic: a reader sees the old record or the new one

    def load(self) -> JobRecord | None:
        """The persisted record; raises JobFileError naming the file and field when it cannot be used."""
        try:
            text = self.path.read_text()
        except FileNotFoundError:
            return None
        except OSError as exc:
            raise JobFileError(self.path, "", f"cannot read: {exc.strerror or exc}") from exc
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise JobFileError(self.path, "", f"not valid JSON: {exc}") from exc
        if not isinstance(data, dict):
            raise JobFileError(self.path, "", f"top level must be an object, got {type(data).__name__}")
        try:
            return record_from_fields(Fields(data, self.path))
        except JobFileError:
            raise
        except ConfigError as exc:
            raise JobFileError(exc.file, exc.field, exc.reason) from exc

    def clear(self) -> None:
        self.path.unlink(missing_ok=True)
