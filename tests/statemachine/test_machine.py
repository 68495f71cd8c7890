"""The cell's state machine, without Zenoh or robot."""

from __future__ import annotations

from pathlib import Path

import pytest

from statemachine.diagram import markdown
from statemachine.machine import STATES, TRANSITIONS, CellMachine, InvalidCommand

STEPS = ("perceived", "matched", "planned", "grasped", "folded")


def run_fold(m: CellMachine) -> None:
    for trigger in STEPS:
        m.step_done(trigger)
    m.step_done("verified")


def test_a_recipe_runs_every_fold_then_done():
    m = CellMachine(max_attempts=3)
    m.start_job("towel", 2)
    assert m.state == "perceiving" and m.job.fold_index == 1
    run_fold(m)
    assert m.state == "perceiving" and m.job.fold_index == 2 and m.job.folds_done == 1
    run_fold(m)
    assert m.state == "done" and m.job.folds_done == 2
    path = [r.dest for r in m.history]
    assert path == ["perceiving", "matching", "planning", "grasping", "folding", "verifying"] * 2 + ["done"]
    m.reset_cell()
    assert m.state == "idle" and m.job is None


def test_a_fold_out_of_reach_pulls_then_perceives_again_in_the_same_fold():
    m = CellMachine(max_attempts=3)
    m.start_job("long-sleeve", 3)
    for trigger in ("perceived", "matched", "out_of_reach"):
        m.step_done(trigger)
    assert m.state == "pulling"
    m.step_done("pulled")
    assert m.state == "perceiving" and m.job.fold_index == 1 and m.job.attempt == 1
    run_fold(m)
    assert m.job.fold_index == 2 and m.job.folds_done == 1
    assert [r.dest for r in m.history][:5] == ["perceiving", "matching", "planning", "pulling", "perceiving"]
    with pytest.raises(InvalidCommand):
        m.step_done("out_of_reach")          # only planning finds a fold out of reach


def test_a_pause_asked_while_pulling_waits_and_resumes_to_perceive():
    m = CellMachine(max_attempts=3)
    m.start_job("towel", 2)
    for trigger in ("perceived", "matched", "out_of_reach"):
        m.step_done(trigger)
    m.request_pause()
    m.step_done("pulled")
    assert m.state == "paused"
    m.resume_job()
    assert m.state == "perceiving"


def test_failed_step_retries_until_attempts_run_out():
    m = CellMachine(max_attempts=2)
    m.start_job("pants", 2)
    m.step_done("perceived")
    m.step_failed("IK failed at (0.1, 0.2)")
    assert m.state == "perceiving" and m.job.attempt == 2 and m.reason.startswith("IK")
    m.step_failed("again")
    assert m.state == "failed" and m.reason == "again"
    with pytest.raises(InvalidCommand, match="fold is not allowed in state failed"):
        m.start_job("pants", 2)


def test_retry_counts_per_fold():
    m = CellMachine(max_attempts=2)
    m.start_job("towel", 2)
    m.step_failed("verify: IoU 0.5")
    assert m.job.attempt == 2
    run_fold(m)
    assert m.job.fold_index == 2 and m.job.attempt == 1


def test_listeners_see_the_fold_and_attempt_the_new_state_works_on():
    """What the cell publishes on each transition (and the demo's progress line prints)."""
    m = CellMachine(max_attempts=3)
    seen: list[tuple[str, int, int]] = []
    m.listeners.append(lambda record: seen.append((record.dest, m.job.fold_index, m.job.attempt)))
    m.start_job("towel", 2)
    run_fold(m)
    m.step_done("perceived")
    m.step_failed("the slave answered too late; retry")
    run_fold(m)
    fold_1 = [(state, 1, 1) for state in ("perceiving", "matching", "planning", "grasping", "folding",
                                          "verifying")]
    assert seen == [*fold_1, ("perceiving", 2, 1), ("matching", 2, 1), ("perceiving", 2, 2),
                    *[(state, 2, 2) for state in ("matching", "planning", "grasping", "folding",
                                                  "verifying", "done")]]


def test_unretryable_failure_ends_in_failed():
    m = CellMachine()
    m.start_job("towel", 2)
    m.step_failed("garment out of reach at (1.3, 0.1) m", retryable=False)
    assert m.state == "failed" and "out of reach" in m.reason


def test_pause_takes_effect_at_the_next_step_boundary_and_resume_goes_on():
    m = CellMachine()
    m.start_job("towel", 1)
    m.step_done("perceived")
    m.request_pause()
    assert m.state == "matching"  # not yet
    m.step_done("matched")
    assert m.state == "paused"
    m.resume_job()
    assert m.state == "planning"


def test_interrupt_redoes_the_step_on_resume():
    m = CellMachine()
    m.start_job("towel", 1)
    for t in ("perceived", "matched", "planned", "grasped"):
        m.step_done(t)
    m.interrupt_step("e-stop pressed")
    assert m.state == "paused" and m.reason == "e-stop pressed"
    m.resume_job()
    assert m.state == "folding"


def test_abort_and_fault_from_any_active_state():
    for trigger_state in ("perceiving", "grasping", "paused"):
        m = CellMachine()
        m.start_job("towel", 1)
        if trigger_state == "grasping":
            for t in ("perceived", "matched", "planned"):
                m.step_done(t)
        if trigger_state == "paused":
            m.interrupt_step("hold")
        m.abort_job()
        assert m.state == "failed" and "aborted" in m.reason
    m = CellMachine()
    m.start_job("towel", 1)
    m.raise_fault("controller gone")
    assert m.state == "fault" and m.reason == "controller gone"
    m.reset_cell()
    assert m.state == "idle" and m.reason == "" and m.job is None


def test_resume_after_a_fault_redoes_the_step_it_stopped():
    m = CellMachine()
    m.start_job("towel", 2)
    run_fold(m)
    for trigger in ("perceived", "matched", "planned"):
        m.step_done(trigger)
    m.raise_fault("process camera is gone")
    m.resume_job()
    assert m.state == "grasping" and (m.job.fold_index, m.job.folds_done) == (2, 1) and m.reason == ""
    m.interrupt_step("e-stop")
    m.raise_fault("process controller-slave is gone")  # a fault while paused resumes as the pause would
    m.resume_job()
    assert m.state == "grasping"


def test_a_fault_with_no_garment_in_work_is_not_resumed():
    m = CellMachine()
    m.raise_fault("controller alarm")
    with pytest.raises(InvalidCommand, match="no garment to go on with in state fault"):
        m.resume_job()
    m.reset_cell()
    m.start_job("towel", 1)
    run_fold(m)
    assert m.state == "done"
    m.raise_fault("controller alarm")  # after the garment is done
    with pytest.raises(InvalidCommand, match=r"allowed: reset"):
        m.resume_job()


def test_invalid_triggers_name_what_is_allowed():
    m = CellMachine()
    with pytest.raises(InvalidCommand, match=r"perceived is not allowed in state idle \(allowed: .*start"):
        m.step_done("perceived")
    with pytest.raises(InvalidCommand, match="pause is not allowed in state idle"):
        m.request_pause()
    with pytest.raises(InvalidCommand, match="unknown trigger"):
        m.fire("dance")


def test_every_state_is_reachable_and_every_transition_names_known_states():
    for spec in TRANSITIONS:
        assert spec.dest in STATES and set(spec.source) <= set(STATES)
    assert {s.dest for s in TRANSITIONS} | {"idle"} == set(STATES)


def test_history_is_bounded_and_listeners_see_every_transition():
    m = CellMachine()
    seen = []
    m.listeners.append(seen.append)
    for _ in range(10):
        m.start_job("towel", 1)
        run_fold(m)
        m.reset_cell()
    assert len(seen) == 80
    assert len(m.history) == 50 and m.history[-1] == seen[-1]


def test_generated_docs_are_up_to_date():
    doc = Path(__file__).resolve().parents[2] / "docs" / "statemachine.md"
    assert doc.read_text() == markdown(), "run: python -m statemachine.diagram > docs/statemachine.md"


def test_a_restored_job_waits_paused_and_resume_goes_on_with_the_next_fold():
    m = CellMachine(max_attempts=3)
    m.restore_job("towel", 2, folds_done=1, attempt=2, reason="restored job: towel after fold 1/2")
    assert m.state == "paused" and m.reason == "restored job: towel after fold 1/2"
    assert (m.job.fold_index, m.job.folds_done, m.job.attempt) == (2, 1, 2)
    assert m.allowed_triggers() == ["abort", "fault", "resume"]
    m.resume_job()
    assert m.state == "perceiving" and m.reason == ""
    run_fold(m)
    assert m.state == "done" and m.job.folds_done == 2


def test_a_restore_is_refused_unless_idle_and_with_folds_left():
    m = CellMachine(max_attempts=3)
    with pytest.raises(InvalidCommand, match="nothing to resume"):
        m.restore_job("towel", 2, folds_done=2, attempt=1, reason="")
    assert m.state == "idle" and m.job is None
    m.start_job("towel", 2)
    with pytest.raises(InvalidCommand, match="restore is not allowed in state perceiving"):
        m.restore_job("towel", 2, folds_done=1, attempt=1, reason="")
    assert m.job.folds_done == 0
