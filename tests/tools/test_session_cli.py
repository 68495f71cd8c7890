"""`foldcell log info|recover`, `replay` and `foxglove --export` take a bag split by size as one
session, named by its folder or any of its files; a crashed bag is recovered in place or into a new one."""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from drivers.sessions.mcap import SessionWriter, iter_messages
from tests.conftest import Endpoint
from tests.sessions.test_mcap_fixtures import (
    JOINT_STATE,
    JOINTS_TOPIC,
    T0,
    joint_state,
    msgdef,
    write_session,
)
from tools.cli import main


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, int]:
    """A session in several files, and how many messages it holds."""
    path = tmp_path_factory.mktemp("cli") / "rot"
    written = write_session(path, 1500, chunk_size=2048, rotate_bytes=16_000, bag=True)
    assert len(list(path.glob("rot_*.mcap"))) >= 3
    return path, len(written)


def test_log_info_describes_every_file_as_one_session(bag, capsys: pytest.CaptureFixture[str]) -> None:
    folder, total = bag
    for named in (folder, folder / "rot_1.mcap"):
        assert main(["log", "info", str(named), "--json"]) == 0
        info = json.loads(capsys.readouterr().out)
        assert info["message_count"] == total and info["complete"]
        assert info["bag"] == str(folder) and len(info["files"]) == len(list(folder.glob("*.mcap")))
    assert main(["log", "info", str(folder)]) == 0
    text = capsys.readouterr().out
    assert f"bag:       {folder}" in text and "rot_0.mcap, rot_1.mcap" in text


def test_replay_publishes_every_sample_of_every_file(bag, capsys: pytest.CaptureFixture[str]) -> None:
    folder, total = bag
    argv = ["replay", str(folder / "rot_0.mcap"), "--rate", "max", "--json", *Endpoint().args("rot")]
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["published"] == total and summary["file"] == str(folder)


def test_foxglove_export_of_a_bag_writes_one_file_beside_it(bag, capsys: pytest.CaptureFixture[str]) -> None:
    folder, total = bag
    assert main(["foxglove", "--export", str(folder)]) == 0
    out = folder.with_name("rot.foxglove.mcap")
    assert f"wrote {out}: {total} messages" in capsys.readouterr().err
    assert Counter(m.topic for m in iter_messages(out))[JOINTS_TOPIC] == 1500


def _crashed_bag(path: Path) -> tuple[SessionWriter, int]:
    """A bag whose writer stopped without closing (a killed recorder): its last file is cut short."""
    writer = SessionWriter(path, chunk_size=1024, rotate_bytes=12_000, bag=True)
    for i in range(800):
        writer.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(i), T0 + i, T0 + i)
    return writer, 800


def test_log_recover_makes_a_crashed_bag_whole_in_place(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    writer, sent = _crashed_bag(tmp_path / "crash")
    assert main(["log", "info", str(tmp_path / "crash")]) == 3   # described; data was lost
    assert "CUT SHORT OR DAMAGED: " + writer.paths[-1].name in capsys.readouterr().out
    assert main(["log", "recover", str(tmp_path / "crash")]) == 3  # the open chunk was lost
    assert f"metadata:  {tmp_path / 'crash' / 'metadata.yaml'}" in capsys.readouterr().out
    with AnyReader([tmp_path / "crash"]) as reader:
        kept = sum(1 for _ in reader.messages())
        assert kept == reader.message_count and 0 < sent - kept < 10
    assert main(["log", "info", str(tmp_path / "crash"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["complete"] and info["message_count"] == kept


def test_log_recover_with_output_writes_a_new_bag(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    writer, sent = _crashed_bag(tmp_path / "crash")
    files = list(writer.paths)
    before = [p.read_bytes() for p in files]
    assert main(["log", "recover", str(files[0]), "-o", str(tmp_path / "fixed"), "--json"]) == 3
    report = json.loads(capsys.readouterr().out)
    assert report["output"] == str(tmp_path / "fixed") and report["data_lost"]
    assert [p.read_bytes() for p in files] == before  # the crashed bag is left as it was
    with AnyReader([tmp_path / "fixed"]) as reader:
        assert 0 < sum(1 for _ in reader.messages()) == reader.message_count < sent
    assert sorted(p.name for p in (tmp_path / "fixed").glob("*.mcap")) == sorted(
        f"fixed_{i}.mcap" for i in range(len(files)))
    assert main(["log", "recover", str(files[0]), "-o", str(tmp_path / "fixed")]) == 2
    assert "already exists" in capsys.readouterr().err
