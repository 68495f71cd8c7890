"""The demo's view of a cell over loopback Zenoh: its progress lines count folds as the cell works on
them, a garment done shows no failure reason (a retried step is a note), and its summary counts the
folds the cell reported as they ended."""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import pytest

from cell.evaluation.demo_run import GarmentRun, Observer, summarise
from drivers.common.outcomes import GarmentOutcome
from drivers.sessions.report import write_report
from drivers.wire import messages
from drivers.wire.transport import Wire
from statemachine.machine import CellMachine
from tests.conftest import Endpoint, wait_until
from tests.sessions.test_mcap_fixtures import write_session
from tools.demo_cli import print_summary

STEPS = ("perceived", "matched", "planned", "grasped", "folded", "verified")
SLAVE_LATE = "the slave answered too late; retry"


def state_message(machine: CellMachine) -> Any:
    """The cell state as the cell daemon publishes it on every transition."""
    job = machine.job
    return messages.new(
        "foldcell_msgs/msg/CellState", header=messages.header(), cell_id="demo", state=machine.state,
        garment=job.category if job else "", fold_index=job.fold_index if job else 0,
        fold_count=job.fold_count if job else 0, attempt=job.attempt if job else 0, reason=machine.reason,
        history=[messages.new("foldcell_msgs/msg/CellTransition", stamp=messages.stamp_from_ns(r.stamp_ns),
                              trigger=r.trigger, source=r.source, dest=r.dest, reason=r.reason)
                 for r in machine.history])


class NoChildren:
    """The demo's processes, none of which has died."""

    def dead(self) -> list[str]:
        return []


def fold_report(fold_index: int, attempt: int, outcome: str, cause: str = "") -> Any:
    return messages.new("foldcell_msgs/msg/FoldReport", header=messages.header(), garment="towel",
                        fold_index=fold_index, attempt=attempt, outcome=outcome, verify_iou=0.9,
                        robot_time=2.0, cause=cause)


def test_progress_counts_folds_and_a_garment_done_has_no_failure_reason(
        capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    ep = Endpoint("demo")
    with Wire(ep.settings(), "cell") as cell, Wire(ep.settings(), "cli-demo-test") as demo:
        observer = Observer(demo, progress=True)
        publisher = cell.publisher("cell/state")
        machine = CellMachine(max_attempts=3)

        def heard() -> bool:
            publisher.put(state_message(machine))
            return observer.state == "idle"

        assert wait_until(heard, 20)  # until the subscription matches
        machine.listeners.append(lambda _record: publisher.put(state_message(machine)))

        towel = GarmentRun("towel", 1)
        observer.begin(towel)
        machine.start_job("towel", 2)
        machine.step_done("perceived")
        machine.step_failed(SLAVE_LATE)
        for _ in range(2):
            for trigger in STEPS:
                machine.step_done(trigger)
        # fold 1 imperfect, then fold 2 failed once and done on its second attempt
        reports = cell.publisher("cell/fold_report")
        sent = [fold_report(1, 1, "imperfect", "the outline differs"), fold_report(2, 1, "failed", "slipped"),
                fold_report(2, 2, "done")]
        for report in sent:
            reports.put(report)
        assert wait_until(lambda: len(towel.fold_reports) == len(sent), 20)
        assert wait_until(lambda: observer.state == "done", 20)
        assert observer.state_msg.reason == SLAVE_LATE  # the cell keeps its last reason
        towel.outcome, towel.reason = observer.wait_terminal(20, threading.Event(), NoChildren())
        assert towel.outcome is GarmentOutcome.DONE

        machine.reset_cell()
        shirt = GarmentRun("tshirt", 1)
        observer.begin(shirt)
        machine.start_job("tshirt", 3)
        machine.step_failed("garment out of reach", retryable=False)
        assert wait_until(lambda: observer.state == "failed", 20)
        shirt.outcome, shirt.reason = observer.wait_terminal(20, threading.Event(), NoChildren())
        assert shirt.outcome is GarmentOutcome.FAILED

    progress = [line.strip() for line in capsys.readouterr().err.splitlines()]
    work = ("perceiving", "matching", "planning", "grasping", "folding", "verifying")
    assert progress[:15] == [
        "[towel] fold 1/2 perceiving", "[towel] fold 1/2 matching",
        f"[towel] fold 1/2 perceiving ({SLAVE_LATE})",
        *[f"[towel] fold 1/2 {state}" for state in work[1:]],
        *[f"[towel] fold 2/2 {state}" for state in work], "[towel] fold 2/2 done"]

    done = summarise(towel)
    assert done["reason"] == "" and done["notes"] == [f"retry after matching: {SLAVE_LATE}"]
    # both folds ended done, one of them imperfect: what the last report of each fold said
    assert (done["folds_done"], done["folds_imperfect"]) == (2, 1), done
    assert [(f["fold_index"], f["attempt"], f["outcome"], f["cause"]) for f in done["folds"]] == [
        (1, 1, "imperfect", "the outline differs"), (2, 1, "failed", "slipped"), (2, 2, "done", "")]
    failed = summarise(shirt)
    assert failed["reason"] == "garment out of reach" and failed["notes"] == []  # none of the towel's
    summary = {"time_scale": 1.0, "seed": 1, "garments": [done, failed], "session_log": "s", "report": "r",
               "wall_time_s": 1.0}
    print_summary(summary)
    table = capsys.readouterr().out
    assert table.count("reason:") == 1 and "  reason: garment out of reach" in table
    assert f"  note: retry after matching: {SLAVE_LATE}" in table
    # a longer outcome keeps the columns in line: every row ends where the header does
    cut_short = {**failed, "outcome": "interrupted", "reason": "stopped before its folding began"}
    print_summary({**summary, "garments": [done, cut_short]})
    lines = capsys.readouterr().out.splitlines()
    header = next(i for i, text in enumerate(lines) if text.startswith("garment"))
    rows = [text for text in lines[header + 2:] if text and not text.startswith(" ")][:2]
    assert [r.split()[1] for r in rows] == ["done", "interrupted"], lines
    assert all(len(r) == len(lines[header]) for r in rows), "\n".join(lines)

    write_session(tmp_path / "session", 1, bag=True)  # a session without images
    write_report(tmp_path / "session", summary, tmp_path / "report.html")
    page = (tmp_path / "report.html").read_text()
    # the headline says what happened; a figure not measured is a dash, never Python's None
    assert '<p class="headline">1 of 2 garments folded (1 with imperfect folds)</p>' in page
    assert "<li><b>towel</b> done (2 folds, 1 of them imperfect)</li>" in page
    assert "<li><b>tshirt</b> failed (0 folds): garment out of reach</li>" in page
    assert "None" not in page
    rows = page.split("<tr>")
    assert rows[2].startswith("<td>towel</td><td>done</td>")
    assert rows[2].endswith(f"<td></td><td>retry after matching: {SLAVE_LATE}</td></tr>")  # reason, notes
    assert "<td>garment out of reach</td><td></td></tr>" in rows[3]
