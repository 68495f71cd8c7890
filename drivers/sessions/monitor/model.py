"""The monitor's model: per cell, what the samples and liveliness tokens say, as a JSON-able snapshot.

Pure: fed `on_sample(key, payload, encoding_type, receive_s)`, `on_alive(full_key, alive, now_s)`
and asked `snapshot(now_s)`. Thread-safe (samples arrive on one lane thread per key). Aggregates;
the cost per sample is one decode and a few dict updates, so a 250 Hz stream is cheap.
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from drivers.sessions.folds import GARMENT_ENDS, GARMENT_STARTS, split_garments, transitions_of
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import spec_for, split_key

from .config import MonitorConfig

CELL_STATE = "cell/state"
JOINT_STATES = "controller/joint_states"
STATUS = "controller/status"
CELL_LOG = "cell/log"
OBSERVATION = "perception/observation"
GRIPPER_PREFIX = "controller/gripper/"
TRISTATE = {-1: None, 0: False, 1: True}
MODES = {-1: "unknown", 1: "teach", 2: "play"}


@dataclass(frozen=True)
class JointLimit:
    lower: float
    upper: float


@dataclass
class TopicStats:
    type_name: str
    count: int = 0
    bad: int = 0
    last_s: float = 0.0
    times: collections.deque = field(default_factory=collections.deque)


@dataclass(frozen=True)
class GarmentClock:
    """When the current garment was taken up (and ended), in the monitor's clock."""

    garment: str
    start_stamp_ns: int  # the cell's stamp of the transition that took it up; 0 when not seen
    started_s: float
    ended_s: float | None = None


@dataclass(frozen=True)
class FoldClock:
    """One fold of the current garment: its cell stamps, and its start in the monitor's clock."""

    start_ns: int
    end_ns: int | None
    outcome: str
    started_s: float

    def elapsed_s(self, now: float) -> float:
        return (self.end_ns - self.start_ns) / 1e9 if self.end_ns is not None else now - self.started_s


@dataclass
class CellView:
    cell: str
    processes: dict[str, bool] = field(default_factory=dict)  # name -> alive now (gone ones pruned)
    lost_at_s: dict[str, float] = field(default_factory=dict)  # name -> when its token went
    # the processes the cell's last state says it lost: gone, whatever their tokens say here (this
    # monitor's links may outlive the cell's)
    cell_lost: frozenset[str] = frozenset()
    had_workers: bool = False  # a process of the cell (observers aside) was seen alive
    state: Any = None  # the last CellState
    # (state, reason) the cell gave when it entered its current failed, faulted or paused state: what
    # it says later in that state (a consequence of the first cause) does not replace it
    first_reason: tuple[str, str] | None = None
    states_seen: list[str] = field(default_factory=list)  # consecutive distinct states
    joints: Any = None  # the last JointState
    status: Any = None  # the last ControllerStatus
    observation: Any = None
    grippers: dict[str, Any] = field(default_factory=dict)  # arm -> the last GripperState
    garment_clock: GarmentClock | None = None
    folds_of: tuple[str, int | None] | None = None  # (garment, start stamp) the folds belong to
    folds: dict[int, FoldClock] = field(default_factory=dict)  # fold number -> its clock
    topics: dict[str, TopicStats] = field(default_factory=dict)
    # (source, where, text) -> the last of its kind with a count, oldest first
    errors: collections.OrderedDict = field(default_factory=collections.OrderedDict)
    errors_total: int = 0
    first_seen_s: float = 0.0


class MonitorModel:
    """Everything the monitor shows, for one cell or every cell (`cell='*'`)."""

    def __init__(
        self,
        config: MonitorConfig,
        limits: Mapping[str, JointLimit],
        *,
        cell: str = "*",
        ignore_processes: frozenset[tuple[str, str]] = frozenset(),
        clock: Any = time.monotonic,
        wall_clock: Any = time.time,
    ):
        self.config = config
        self.limits = dict(limits)
        self.cell = cell
        self.ignore = ignore_processes
        self.clock = clock
        self.wall_clock = wall_clock
        self.lock = threading.Lock()
        self.cells: dict[str, CellView] = {}
        self.samples = 0

    def _view(self, cell: str, now: float) -> CellView:
        view = self.cells.get(cell)
        if view is None:
            view = CellView(cell, first_seen_s=now)
            self.cells[cell] = view
        return view

    # inputs
    def on_sample(
        self, key: str, payload: bytes, encoding_type: str = "", receive_s: float | None = None
    ) -> None:
        """One sample as received. A malformed one is recorded as an error naming key and problem."""
        now = self.clock() if receive_s is None else receive_s
        try:
            cell, rel = split_key(key)
        except WireError as err:
            self._error("?", now, "wire", key, err.problem)
            return
        msg: Any = None  # the decoded message, left None only when `problem` says why
        problem: str | None = None
        type_name = encoding_type
        try:
            type_name = spec_for(rel).type_name
            if encoding_type and encoding_type != type_name:
                raise WireError(key, f"sample is a {encoding_type}, this key carries {type_name}")
            msg = messages.decode(type_name, payload, key)
        except WireError as err:
            problem = err.problem
        with self.lock:
            self.samples += 1
            view = self._view(cell, now)
            stats = view.topics.get(rel)
            if stats is None:
                stats = view.topics[rel] = TopicStats(type_name)
            stats.count += 1
            stats.last_s = now
            stats.times.append(now)
            horizon = now - self.config.rate_window_s
            while stats.times and stats.times[0] < horizon:
                stats.times.popleft()
            if problem is not None:
                stats.bad += 1
                self._add_error(view, now, "wire", key, problem)
                return
            if rel == JOINT_STATES:
                view.joints = msg
            elif rel == STATUS:
                view.status = msg
            elif rel == CELL_STATE:
                if view.state is None or view.state.state != msg.state or not view.first_reason:
                    view.first_reason = (msg.state, msg.reason) if msg.reason else None
                view.state = msg
                self._cell_says_lost(view, frozenset(msg.processes_lost), now)
                if not view.states_seen or view.states_seen[-1] != msg.state:
                    view.states_seen.append(msg.state)
                    del view.states_seen[: -self.config.max_states]
                view.garment_clock = _garment_clock(view.garment_clock, msg, now)
                _update_folds(view, msg, now)
            elif rel.startswith(GRIPPER_PREFIX):
                view.grippers[msg.arm] = msg
            elif rel == CELL_LOG:
                if msg.level >= self.config.error_log_level:
                    self._add_error(
                        view,
                        now,
                        "log",
                        msg.name,
                        msg.msg,
                        level=int(msg.level),
                        stamp_ns=messages.stamp_to_ns(msg.stamp),
                    )
            elif rel == OBSERVATION:
                view.observation = msg

    def on_error(self, key: str, problem: str, now: float | None = None) -> None:
        """A bad sample reported by someone else (e.g. a Wire's on_error)."""
        now = self.clock() if now is None else now
        try:
            cell = split_key(key)[0]
        except WireError:
            cell = "?"
        self._error(cell, now, "wire", key, problem)

    def _error(self, cell: str, now: float, source: str, where: str, text: str) -> None:
        with self.lock:
            self._add_error(self._view(cell, now), now, source, where, text)

    def _add_error(
        self, view: CellView, now: float, source: str, where: str, text: str, **extra: Any
    ) -> None:
        """An error seen before is counted and moved last with its new time, not added again."""
        kind = (source, where, text)
        previous = view.errors.pop(kind, None)
        view.errors[kind] = {
            "at_s": now,
            "first_at_s": previous["first_at_s"] if previous else now,
            "count": previous["count"] + 1 if previous else 1,
            "source": source,
            "where": where,
            "text": text,
            **extra,
        }
        while len(view.errors) > self.config.max_errors:
            view.errors.popitem(last=False)
        view.errors_total += 1

    def on_alive(self, full_key: str, alive: bool, now: float | None = None) -> None:
        """A liveliness token `foldcell/<cell>/alive/<process>` appeared (True) or went (False)."""
        now = self.clock() if now is None else now
        try:
            cell, rel = split_key(full_key)
        except WireError:
            return
        process = rel.removeprefix("alive/")
        if (cell, process) in self.ignore:
            return
        with self.lock:
            view = self._view(cell, now)
            if alive:
                view.processes[process] = True
                view.lost_at_s.pop(process, None)
                view.had_workers = view.had_workers or not self._is_observer(process)
            elif process.startswith(self.config.transient_prefixes):
                view.processes.pop(process, None)  # one command's process: its end is no news
                view.lost_at_s.pop(process, None)
            else:
                view.processes[process] = False
                view.lost_at_s[process] = now
            self._prune_gone(view, now)

    @staticmethod
    def _cell_says_lost(view: CellView, lost: frozenset[str], now: float) -> None:
        """The cell's own view of its processes: one it lost is gone from when it first said so."""
        for process in lost - view.cell_lost:
            view.lost_at_s.setdefault(process, now)
        for process in view.cell_lost - lost:
            if view.processes.get(process):
                view.lost_at_s.pop(process, None)   # back: its token is here again
        view.cell_lost = lost

    def _prune_gone(self, view: CellView, now: float) -> None:
        """Keep the gone processes of the last `gone_keep_s`, at most `max_gone` of them (those the cell
        still says it lost stay)."""
        by_age = sorted(view.lost_at_s.items(), key=lambda item: item[1], reverse=True)
        for rank, (process, lost_s) in enumerate(by_age):
            if process in view.cell_lost:
                continue
            if rank >= self.config.max_gone or now - lost_s > self.config.gone_keep_s:
                del view.lost_at_s[process]
                view.processes.pop(process, None)

    # output
    def _is_observer(self, process: str) -> bool:
        return process.startswith(self.config.observer_prefixes)

    def snapshot(self, now: float | None = None) -> dict[str, Any]:
        """A JSON-able picture of every cell seen; see the README section for its fields."""
        now = self.clock() if now is None else now
        with self.lock:
            for view in self.cells.values():
                self._prune_gone(view, now)
            cells = {name: self._cell_json(view, now) for name, view in sorted(self.cells.items())}
            return {"watching": self.cell, "samples": self.samples, "cells": cells}

    def _cell_json(self, v: CellView, now: float) -> dict[str, Any]:
        # the tokens this monitor sees, but a process the cell says it lost is gone
        processes = {p: a and p not in v.cell_lost for p, a in v.processes.items()} | dict.fromkeys(
            v.cell_lost, False)
        working = any(a and not self._is_observer(p) for p, a in processes.items())
        tool = self.config.transient_prefixes
        alive = sorted(p for p, a in processes.items() if a and not p.startswith(tool))
        tools = sorted(p for p, a in processes.items() if a and p.startswith(tool))
        gone_procs = sorted(p for p, a in processes.items() if not a)
        return {
            "cell": v.cell,
            "alive": working,
            # gone: the cell had processes and none of them (observers aside) is alive now
            "gone": v.had_workers and not working,
            "replay": any(a and p.startswith(self.config.replay_prefixes) for p, a in processes.items()),
            "processes": alive,
            "tools": tools,   # command-line tools (cli-*) watching or poking the cell: not the cell's own
            "processes_gone": [
                {"name": p, "ago_s": round(now - v.lost_at_s.get(p, now), 3), "cell_lost": p in v.cell_lost}
                for p in gone_procs
            ],
            "state": _state_json(v.state, v.first_reason),
            "garment_elapsed_s": _elapsed_json(v.garment_clock, now),
            "fold_elapsed_s": _fold_elapsed_json(v, now),
            "folds": [
                {"fold": n, "elapsed_s": round(f.elapsed_s(now), 1), "outcome": f.outcome}
                for n, f in sorted(v.folds.items())
            ],
            "grippers": {arm: _gripper_json(g) for arm, g in sorted(v.grippers.items())},
            "states_seen": list(v.states_seen),
            "controller": _status_json(v.status),
            "joints": self._joints_json(v.joints),
            "observation": _observation_json(v.observation),
            "topics": {rel: self._topic_json(s, now) for rel, s in sorted(v.topics.items())},
            "errors": [
                dict(e, ago_s=round(now - e["at_s"], 3), last_time=self._wall_iso(now, e["at_s"]))
                for e in v.errors.values()
            ],
            "errors_total": v.errors_total,
        }

    def _wall_iso(self, now: float, at_s: float) -> str:
        """The wall-clock time (local, to the second) of the monitor time `at_s`."""
        return time.strftime("%H:%M:%S", time.localtime(self.wall_clock() - (now - at_s)))

    def _topic_json(self, s: TopicStats, now: float) -> dict[str, Any]:
        window = self.config.rate_window_s
        recent = sum(1 for t in s.times if t >= now - window)
        age = now - s.last_s
        return {
            "type": s.type_name,
            "count": s.count,
            "bad": s.bad,
            "rate_hz": round(recent / window, 2),
            "age_s": round(age, 3),
            "stale": age > self.config.stale_after_s,
        }

    def _joints_json(self, js: Any) -> list[dict[str, Any]]:
        if js is None:
            return []
        out = []
        for i, name in enumerate(js.name):
            pos = float(js.position[i]) if i < len(js.position) else float("nan")
            lim = self.limits.get(name)
            row: dict[str, Any] = {"name": name, "position": round(pos, 5)}
            if lim is not None:
                span = lim.upper - lim.lower
                fraction = (pos - lim.lower) / span if span > 0 else 0.0
                # distance to the nearer limit as a share of half the range: 1 at a limit
                near = abs(2.0 * fraction - 1.0)
                row.update(
                    lower=lim.lower,
                    upper=lim.upper,
                    fraction=round(fraction, 4),
                    near_limit=near >= self.config.joint_warn_fraction,
                    outside=pos < lim.lower or pos > lim.upper,
                )
            out.append(row)
        return out


def _state_json(s: Any, first_reason: tuple[str, str] | None = None) -> dict[str, Any] | None:
    if s is None:
        return None
    first = first_reason[1] if first_reason and first_reason[0] == s.state else s.reason
    return {
        "state": s.state,
        "garment": s.garment,
        "fold_index": int(s.fold_index),
        "fold_count": int(s.fold_count),
        "attempt": int(s.attempt),
        "stage": s.stage,
        "reason": first,
        "later_reason": s.reason if s.reason != first else "",
        "triggers": list(s.triggers),
        "history": [
            {
                "stamp_ns": messages.stamp_to_ns(t.stamp),
                "trigger": t.trigger,
                "source": t.source,
                "dest": t.dest,
                "reason": t.reason,
            }
            for t in s.history
        ],
    }


def _garment_clock(previous: GarmentClock | None, state: Any, now: float) -> GarmentClock | None:
    """The current garment's clock from a CellState received at `now`: started at the transition that
    took the garment up, timed with the cell's own stamps (the history's against the header's), so
    neither clock offsets nor a replay's old stamps matter. Without that transition in the history
    (a long garment pushed it out) it keeps the clock it had, or starts one now."""
    if not state.garment or state.state == "idle":
        return None
    stamp_ns = messages.stamp_to_ns(state.header.stamp)
    starts = [t for t in state.history if t.trigger in GARMENT_STARTS]
    if starts:
        start_ns = messages.stamp_to_ns(starts[-1].stamp)
        clock = GarmentClock(state.garment, start_ns, now - (stamp_ns - start_ns) / 1e9)
    elif previous is not None and previous.garment == state.garment:
        clock = GarmentClock(previous.garment, previous.start_stamp_ns, previous.started_s)
    else:
        clock = GarmentClock(state.garment, 0, now)
    if previous is not None and previous.start_stamp_ns == clock.start_stamp_ns and previous.ended_s:
        return previous  # ended before: keep its end
    if state.state in GARMENT_ENDS:
        end_ns = messages.stamp_to_ns(state.history[-1].stamp) if state.history else stamp_ns
        return GarmentClock(clock.garment, clock.start_stamp_ns, clock.started_s,
                            max(clock.started_s, now - (stamp_ns - end_ns) / 1e9))
    return clock


def _update_folds(view: CellView, state: Any, now: float) -> None:
    """The current garment's folds from a CellState received at `now`, timed with the cell's stamps.
    Folds whose start left the history keep the clock they had."""
    garments = split_garments(transitions_of(state.history))
    if not state.garment or state.state == "idle" or not garments:
        view.folds_of, view.folds = None, {}
        return
    garment = garments[-1]
    if state.fold_index:
        garment = garment.renumbered(int(state.fold_index))
    owner = (state.garment, garment.start_ns)
    same = view.folds_of is not None and view.folds_of[0] == state.garment and (
        garment.start_ns is None or view.folds_of[1] == garment.start_ns)
    if not same:
        view.folds_of, view.folds = owner, {}
    stamp_ns = messages.stamp_to_ns(state.header.stamp)
    for f in garment.folds:
        if f.start_ns is not None:
            started_s = now - (stamp_ns - f.start_ns) / 1e9
            view.folds[f.fold] = FoldClock(f.start_ns, f.end_ns, f.outcome, started_s)


def _fold_elapsed_json(view: CellView, now: float) -> float | None:
    fold = view.folds.get(int(view.state.fold_index)) if view.state is not None else None
    return None if fold is None else round(fold.elapsed_s(now), 1)


def _elapsed_json(clock: GarmentClock | None, now: float) -> float | None:
    if clock is None:
        return None
    return round((now if clock.ended_s is None else clock.ended_s) - clock.started_s, 1)


def _gripper_json(g: Any) -> dict[str, Any]:
    return {"closed": bool(g.closed), "opening_m": round(float(g.opening), 4)}


def _status_json(s: Any) -> dict[str, Any] | None:
    if s is None:
        return None
    return {
        "servo": TRISTATE.get(int(s.drives_powered)),
        "e_stop": TRISTATE.get(int(s.e_stopped)),
        "alarm": TRISTATE.get(int(s.in_error)),
        "alarm_code": int(s.error_code),
        "alarm_text": s.alarm_text,
        "in_motion": TRISTATE.get(int(s.in_motion)),
        "mode": MODES.get(int(s.mode), str(int(s.mode))),
        "motion_possible": TRISTATE.get(int(s.motion_possible)),
        "held": TRISTATE.get(int(s.held)),
        "lease_holder": s.lease_holder,
        "lease_note": s.lease_note,
        "loop_stalls": int(s.loop_stalls),
        "queue_count": int(s.queue_count),
        "time_scale": float(s.time_scale),
        "faults": list(s.faults),
    }


def _observation_json(o: Any) -> dict[str, Any] | None:
    if o is None:
        return None
    return {
        "category": o.category,
        "fold_index": int(o.fold_index),
        "cost": float(o.cost),
        "landmarks": {lm.name: [round(float(lm.x_px), 1), round(float(lm.y_px), 1)] for lm in o.landmarks},
    }


def joint_limits_from_robot(robot: Any) -> dict[str, JointLimit]:
    """`drivers.robot.config.RobotConfig` -> name -> limits."""
    return {j.name: JointLimit(float(j.lower), float(j.upper)) for j in robot.joints}
