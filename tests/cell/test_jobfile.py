"""The job file: what a restarted cell takes up, and what it refuses (naming the file and the field)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from cell.config import load_cell_config
from cell.fold_check import FoldExpectation, FoldToCheck
from cell.jobfile import HeldCloth, JobFile, JobFileError, JobRecord
from cell.perception.config import load_perception_config
from cell.perception.folded import derive_folded_model
from cell.perception.pipeline import load_garment_models, load_table_model
from cell.planning.folds import FoldPlanner
from cell.planning.release import Carry
from cell.runner import CellRunner, Perception
from drivers.common.plane import FoldLine
from drivers.emulator.local import LocalController
from drivers.robot.table import default_table_config
from drivers.sim.camera import SimCamera
from tests.cell.sim_cell import RecordingEvents


@pytest.fixture(scope="module")
def perception() -> Perception:
    config = load_perception_config()
    return Perception(config, load_table_model(None, config), load_garment_models(config))


def towel_after_one_fold(perception: Perception) -> JobRecord:
    """A towel folded bottom onto top: its folded model and where the fold left its landmarks; gripper
    r2 closed on it for the second fold."""
    towel = perception.models["towel"]
    # the flat towel, 0.6 x 0.4 m, named as the model names its corners (clockwise from bottom-left)
    corners = {"bottom-left": (0.0, 0.0), "top-left": (0.0, 0.4), "top-right": (0.6, 0.4),
               "bottom-right": (0.6, 0.0)}
    polygon = np.array([corners[name] for name in towel.names])
    folded = derive_folded_model(towel, polygon, ((0.3, 0.0), (0.3, 0.4)), 1)
    expected = {"top-left": (0.0, 0.4), "top-right": (0.6, 0.4), "fold1-from": (0.6, 0.2),
                "fold1-to": (0.0, 0.2)}
    held = (HeldCloth("r2", 2, "grasping", Carry((0.9, 0.1, 0.95), (0.9, 0.3, 0.85))),)
    return JobRecord("towel", 2, 1, "grasping", 2, folded, expected, held)


def fold_to_check(record: JobRecord) -> FoldToCheck:
    """The check of the towel's second fold (left onto right), as the cell keeps it once it grasps."""
    assert record.expected_landmarks is not None
    before = dict(record.expected_landmarks)
    outline = np.array(list(before.values()))
    expected = {"top-right": np.array([0.6, 0.4]), "fold1-from": np.array([0.6, 0.2]),
                "fold2-from": np.array([0.3, 0.2]), "fold2-to": np.array([0.3, 0.4])}
    return FoldToCheck(FoldExpectation(record.model, expected), outline, before,
                       FoldLine(np.array([0.3, 0.3]), np.array([-1.0, 0.0])))


def test_a_record_is_written_whole_and_read_back(tmp_path, perception):
    record = towel_after_one_fold(perception)
    jobs = JobFile(tmp_path / "runs" / "cell1.job.json")
    assert jobs.load() is None  # no file: no job
    jobs.save(record)
    jobs.save(record)  # over the old one
    assert jobs.load() == record
    assert sorted(p.name for p in jobs.path.parent.iterdir()) == ["cell1.job.json"]  # no temporary left
    jobs.clear()
    assert jobs.load() is None and not jobs.path.exists()


def _written(tmp_path: Path, record: JobRecord, **changes) -> JobFile:
    data = record.to_dict()
    for dotted, value in changes.items():
        *parents, name = dotted.split("__")
        target = data
        for parent in parents:
            target = target[int(parent)] if isinstance(target, list) else target[parent]
        target[name] = value
    jobs = JobFile(tmp_path / "job.json")
    jobs.path.write_text(json.dumps(data))
    return jobs


@pytest.mark.parametrize(("changes", "field", "reason"), [
    ({"version": 1}, "version", "1 is not a job file version this cell reads (2)"),
    ({"folds_done": 2}, "folds_done", "must be <= 1"),
    ({"state": "dancing"}, "state", "'dancing' is not a state of the cell"),
    ({"attempt": "2"}, "attempt", "must be an integer"),
    ({"colour": "blue"}, "colour", "unknown field"),
    ({"model__vertices__0__angle_var": -1.0}, "model.vertices[0].angle_var", "must be > 0"),
    ({"model__category": "pants"}, "model.category", "is not the job's category 'towel'"),
    ({"expected_landmarks__fold1-to": [0.0]}, "expected_landmarks.fold1-to", "must have 2 numbers"),
    ({"held__0__phase": "waving"}, "held[0].phase", "must be one of grasping, folding, pulling"),
    ({"held__0__fold": 3}, "held[0].fold", "must be <= 2"),
    ({"held__0__carry__place": [0.9, 0.3]}, "held[0].carry.place", "must have 3 numbers"),
    ({"held": [{"arm": "r2", "fold": 2, "phase": "folding", "carry": None}] * 2}, "held",
     "an arm is named twice"),
])
def test_a_wrong_field_is_refused_by_name(tmp_path, perception, changes, field, reason):
    jobs = _written(tmp_path, towel_after_one_fold(perception), **changes)
    with pytest.raises(JobFileError) as refused:
        jobs.load()
    assert (refused.value.file, refused.value.field) == (str(jobs.path), field)
    assert reason in refused.value.reason


def test_a_file_that_is_not_a_record_is_refused(tmp_path):
    jobs = JobFile(tmp_path / "job.json")
    jobs.path.write_text('{"version": 1, "category": "tow')  # cut short
    with pytest.raises(JobFileError, match=r"job\.json: not valid JSON"):
        jobs.load()
    jobs.path.write_text("[1, 2]")
    with pytest.raises(JobFileError, match="top level must be an object"):
        jobs.load()


def runner_on(jobs: JobFile, perception: Perception) -> CellRunner:
    return CellRunner(SimCamera(seed=2, category="towel"), LocalController(), FoldPlanner(), perception,
                      load_cell_config(), RecordingEvents(), default_table_config(), lambda: 1.0, jobs=jobs)


def test_a_cell_takes_up_a_persisted_job_paused(tmp_path, perception):
    record = towel_after_one_fold(perception)
    jobs = JobFile(tmp_path / "job.json")
    jobs.save(record)
    runner = runner_on(jobs, perception)
    said = runner.restore_job()
    machine, garment = runner.machine, runner.garment
    assert machine.state == "paused" and "restored job: towel after fold 1/2" in machine.reason, said
    assert (machine.job.fold_index, machine.job.attempt) == (2, 2)
    # the next fold matches the folded model, expecting the landmarks where the fold left them
    assert garment is not None and garment.model == record.model
    assert record.expected_landmarks is not None and garment.expected_table is not None
    assert set(garment.expected_table) == set(record.expected_landmarks)
    assert jobs.load() == dataclasses.replace(record, state="paused")
    assert garment.held == {"r2": record.held[0]} and "gripper r2 held the cloth" in machine.reason
    assert machine.resume_state == "perceiving"    # no fold's grippers closed: nothing to check
    accepted, text = runner.command("abort")
    assert accepted and not jobs.path.exists(), text  # an aborted job clears the file


def test_a_fold_its_grippers_were_making_is_checked_on_resume(tmp_path, perception):
    record = towel_after_one_fold(perception)
    record = dataclasses.replace(record, to_check=fold_to_check(record))
    jobs = JobFile(tmp_path / "job.json")
    jobs.save(record)
    assert jobs.load().to_dict() == record.to_dict()
    runner = runner_on(jobs, perception)
    runner.restore_job()
    assert runner.machine.state == "paused" and "resume checks fold 2" in runner.machine.reason
    assert runner.machine.resume_state == "verifying"
    assert runner.garment is not None and runner.garment.to_check is not None
    data = record.to_dict()
    data["to_check"]["line"]["normal"] = [1.0, 1.0]
    jobs.path.write_text(json.dumps(data))
    with pytest.raises(JobFileError) as refused:
        jobs.load()
    assert (refused.value.field, refused.value.reason) == ("to_check.line.normal",
                                                           "must be a unit vector, got length 1.414214")


@pytest.mark.parametrize(("changes", "field"), [
    ({"version": 0}, "version"),
    ({"fold_count": 3, "folds_done": 1}, "fold_count"),  # the towel's recipe has two folds
])
def test_a_cell_refuses_a_job_it_cannot_use_and_starts_idle(tmp_path, perception, changes, field):
    jobs = _written(tmp_path, towel_after_one_fold(perception), **changes)
    runner = runner_on(jobs, perception)
    said = runner.restore_job()
    assert runner.machine.state == "idle" and runner.garment is None
    assert said.startswith("job file refused") and f"{jobs.path}: {field}: " in said, said
