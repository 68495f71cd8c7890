"""The job a cell is working on, kept in a small JSON file so a restarted cell daemon takes the garment up
after its last completed fold.

The file holds what the next fold needs and cannot see again: the model to match (the folded model of
the last completed fold, paper Sec. III-F) and where that fold left each landmark on the table; and,
written as they change, which gripper is closed on the cloth (in which fold and phase, and where its
plan carries the cloth) and what the check of a fold whose grippers closed needs. It is
written whole to a temporary file and renamed over the old one, so a crash leaves the old file or the
new one, never half of either. A file this code cannot read (corrupt, another version) is refused with
an error naming the file and the field.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cell.fold_check import FoldExpectation, FoldToCheck
from cell.perception.models import PolygonalModel, model_from_fields
from cell.planning.release import Carry
from drivers.common.configfile import ConfigError, Fields
from drivers.common.landmarks import TABLE, Landmarks
from drivers.common.plane import FoldLine
from statemachine.machine import STATES

log = logging.getLogger(__name__)

JOB_FILE_VERSION = 2
JOB_FIELDS = {"version", "category", "fold_count", "folds_done", "state", "attempt", "model",
              "expected_landmarks", "held", "to_check"}
HOLDING_PHASES = ("grasping", "folding", "pulling")   # the steps a gripper closes on cloth in


class JobFileError(ConfigError):
    """The job file cannot be read or holds a wrong value: names the file, the field and the reason."""


@dataclass(frozen=True)
class HeldCloth:
    """A gripper closed on the cloth: in fold `fold` (1-based), last written in step `phase`, and where
    its plan carries the cloth (None: unknown)."""

    arm: str
    fold: int
    phase: str
    carry: Carry | None


@dataclass(frozen=True)
class JobRecord:
    category: str
    fold_count: int
    folds_done: int                      # the last completed fold (0: none yet)
    state: str                           # the cell's state when the record was written
    attempt: int                         # the attempt at the fold after `folds_done`
    model: PolygonalModel                # the model to match next: the garment after `folds_done` folds
    expected_landmarks: dict[str, tuple[float, float]] | None  # where that fold left them (table, m)
    held: tuple[HeldCloth, ...] = ()     # the grippers closed on the cloth
    to_check: FoldToCheck | None = None  # the fold after `folds_done`, once its grippers closed

    def describe(self) -> str:
        return f"{self.category} after fold {self.folds_done}/{self.fold_count}"

    def to_dict(self) -> dict[str, Any]:
        return {"version": JOB_FILE_VERSION, "category": self.category, "fold_count": self.fold_count,
                "folds_done": self.folds_done, "state": self.state, "attempt": self.attempt,
                "model": self.model.to_dict(exact=True),
                "expected_landmarks": _points_dict(self.expected_landmarks),
                "held": [{"arm": h.arm, "fold": h.fold, "phase": h.phase,
                          "carry": None if h.carry is None else {
                              "apex": None if h.carry.apex is None else list(h.carry.apex),
                              "place": list(h.carry.place)}} for h in self.held],
                "to_check": None if self.to_check is None else _check_dict(self.to_check)}


def _points_dict(points: Mapping[str, Any] | None) -> dict[str, list[float]] | None:
    return None if points is None else {name: [float(x), float(y)] for name, (x, y) in points.items()}


def _check_dict(check: FoldToCheck) -> dict[str, Any]:
    return {"model": check.expectation.model.to_dict(exact=True),
            "expected_landmarks": _points_dict(check.expectation.landmarks_table),
            "before_outline": [[float(x), float(y)] for x, y in check.before_outline],
            "before_landmarks": _points_dict(check.before_landmarks),
            # the file's normal points to the side that stays (version 2), the FoldLine's the other way
            "line": {"point": [float(v) for v in check.line.point],
                     "normal": [0.0 - float(v) for v in check.line.normal]}}


def _points_from_fields(fields: Fields, name: str) -> dict[str, tuple[float, float]] | None:
    if fields.raw(name, None) is None:
        return None
    points = fields.sub(name)
    out = {}
    for point in points.data:
        x, y = points.floats(point, length=2)
        out[point] = (x, y)
    return out


def _model_from_fields(fields: Fields, name: str, category: str) -> PolygonalModel:
    try:
        model = model_from_fields(fields.sub(name))
    except ConfigError as exc:  # a model that does not hold together names its vertices, not where they are
        field = exc.field if exc.field.startswith(fields.path(name)) else f"{fields.path(name)}.{exc.field}"
        raise JobFileError(fields.file, field, exc.reason) from exc
    if model.category != category:
        raise JobFileError(fields.file, f"{fields.path(name)}.category",
                           f"{model.category!r} is not the job's category {category!r}")
    return model


def _held_from_fields(item: Fields, fold_count: int) -> HeldCloth:
    item.reject_unknown({"arm", "fold", "phase", "carry"})
    carry = None
    if item.raw("carry", None) is not None:
        where = item.sub("carry")
        where.reject_unknown({"apex", "place"})
        apex = None if where.raw("apex", None) is None else where.floats("apex", length=3)
        place = where.floats("place", length=3)
        carry = Carry(None if apex is None else (apex[0], apex[1], apex[2]), (place[0], place[1], place[2]))
    return HeldCloth(item.str("arm"), item.int("fold", min=1, max=fold_count),
                     item.str("phase", choices=HOLDING_PHASES), carry)


def _check_from_fields(fields: Fields, category: str) -> FoldToCheck:
    fields.reject_unknown({"model", "expected_landmarks", "before_outline", "before_landmarks", "line"})
    model = _model_from_fields(fields, "model", category)
    expected = _points_from_fields(fields, "expected_landmarks")
    outline = fields.raw("before_outline")
    if not isinstance(outline, list) or len(outline) < 3:
        raise fields.error("before_outline", "must be a list of at least 3 points [x, y]")
    before_outline = np.array([Fields({"point": p}, fields.file, fields.path(f"before_outline[{i}]"))
                               .floats("point", length=2) for i, p in enumerate(outline)])
    before_landmarks = _points_from_fields(fields, "before_landmarks")
    if before_landmarks is None:
        raise fields.error("before_landmarks", "missing")
    line = fields.sub("line")
    line.reject_unknown({"point", "normal"})
    normal = np.array(line.floats("normal", length=2))
    if abs(float(np.linalg.norm(normal)) - 1.0) > 1e-6:
        raise line.error("normal", f"must be a unit vector, got length {float(np.linalg.norm(normal)):.6f}")
    expectation = FoldExpectation(model, None if expected is None else Landmarks.of(TABLE, expected))
    return FoldToCheck(expectation, before_outline, before_landmarks,
                       FoldLine(np.array(line.floats("point", length=2)), -normal))


def record_from_fields(fields: Fields) -> JobRecord:
    version = fields.raw("version", None)
    if version != JOB_FILE_VERSION:
        raise JobFileError(fields.file, "version", f"{version!r} is not a job file version this cell reads "
                                                   f"({JOB_FILE_VERSION})")
    fields.reject_unknown(JOB_FIELDS)
    fold_count = fields.int("fold_count", min=1)
    category = fields.str("category")
    model = _model_from_fields(fields, "model", category)
    expected = _points_from_fields(fields, "expected_landmarks")
    held = tuple(_held_from_fields(item, fold_count) for item in fields.items("held"))
    arms = [h.arm for h in held]
    if len(set(arms)) != len(arms):
        raise fields.error("held", f"an arm is named twice: {', '.join(arms)}")
    to_check = None if fields.raw("to_check", None) is None else _check_from_fields(fields.sub("to_check"),
                                                                                     category)
    state = fields.str("state")
    if state not in STATES:
        raise JobFileError(fields.file, "state",
                           f"{state!r} is not a state of the cell ({', '.join(STATES)})")
    return JobRecord(category, fold_count, fields.int("folds_done", min=0, max=fold_count - 1), state,
                     fields.int("attempt", min=1), model, expected, held, to_check)


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

    def keep(self, record: JobRecord | None) -> None:
        """Save `record`, or clear the file when there is no job to keep. A failed write is logged: the
        cell goes on folding, and only a restart would lose the garment."""
        try:
            if record is None:
                self.clear()
            else:
                self.save(record)
        except OSError as exc:
            log.error("job file %s not written: %s", self.path, exc)

    def load_fitting(self, recipes: Mapping[str, int]) -> JobRecord | None:
        """The persisted record, checked against this cell's garments (`recipes`: category -> its number
        of folds): the config may have changed since it was written. JobFileError names what does not fit."""
        record = self.load()
        if record is None:
            return None
        if record.category not in recipes:
            raise JobFileError(self.path, "category", f"unknown garment category {record.category!r} "
                               f"(known: {', '.join(sorted(recipes))})")
        if record.fold_count != recipes[record.category]:
            raise JobFileError(self.path, "fold_count", f"{record.fold_count}, but the {record.category} "
                               f"recipe has {recipes[record.category]} fold(s)")
        return record
