"""`foldcell log info|recover` through a throwaway argparse, as the lead's cli.py will call them."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from tests.sessions.test_mcap_fixtures import JOINT_STATE, JOINTS_TOPIC, LOG_TOPIC, write_session
from tools import log_cli


def _run(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="foldcell")
    sub = parser.add_subparsers(dest="command", required=True)
    log_cli.register(sub)
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def files(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("cli")
    full = d / "s.mcap"
    write_session(full, 300, chunk_size=2048, cell="cell1")
    data = full.read_bytes()
    cut = d / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    return full, cut


def test_info_table(files, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["log", "info", str(files[0])]) == 0
    out = capsys.readouterr().out
    assert "complete, with summary" in out
    assert "duration:  2.990 s" in out
    line = next(ln for ln in out.splitlines() if ln.startswith(JOINTS_TOPIC))
    assert line.split() == [JOINTS_TOPIC, JOINT_STATE, "300", "100.00"]
    assert any(ln.startswith(LOG_TOPIC) for ln in out.splitlines())


def test_info_json_is_one_document(files, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["log", "info", str(files[1]), "--json"]) == 3   # described, and data was lost
    doc = json.loads(capsys.readouterr().out)
    assert doc["complete"] is False and doc["unreadable_bytes"] > 0
    assert 0 < doc["message_count"] < 330


def test_info_on_cut_file_says_so(files, capsys: pytest.CaptureFixture[str]) -> None:
    assert _run(["log", "info", str(files[1])]) == 3   # as `log recover` when data was lost
    assert "CUT SHORT" in capsys.readouterr().out


def test_recover_default_name_and_exit_codes(files, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(files[1].read_bytes())
    assert _run(["log", "recover", str(cut)]) == 3  # data was lost
    out_path = tmp_path / "cut.mcap.recovered.mcap"
    assert out_path.exists()
    assert "DATA WAS LOST" in capsys.readouterr().out
    # The output exists now: refused without --force, replaced with it.
    assert _run(["log", "recover", str(cut)]) == 2
    assert "already exists" in capsys.readouterr().err
    assert _run(["log", "recover", str(cut), "--force", "--json"]) == 3
    doc = json.loads(capsys.readouterr().out)
    assert doc["data_lost"] is True and doc["messages_kept"] > 0
    # A complete file loses nothing.
    assert _run(["log", "recover", str(files[0]), "-o", str(tmp_path / "full.mcap")]) == 0
    assert "nothing lost" in capsys.readouterr().out


@pytest.mark.parametrize("command", ["info", "recover"])
def test_bad_input_exits_2_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                         command: str) -> None:
    text = tmp_path / "x.mcap"
    text.write_text("plain text")
    assert _run(["log", command, str(text)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("foldcell: error: ") and "not an MCAP file" in err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert _run(["log", command, str(tmp_path / "missing.mcap")]) == 2
    assert capsys.readouterr().err.startswith("foldcell: error: ")


def test_log_group_is_extensible_and_has_help(capsys: pytest.CaptureFixture[str]) -> None:
    def add_record(group) -> None:
        p = group.add_parser("record", help="record a cell")
        p.set_defaults(func=lambda args: 42)

    parser = argparse.ArgumentParser(prog="foldcell")
    sub = parser.add_subparsers(dest="command", required=True)
    log_cli.register(sub, extra=[add_record])
    args = parser.parse_args(["log", "record"])
    assert args.func(args) == 42
    with pytest.raises(SystemExit):
        parser.parse_args(["log", "--help"])
    out = capsys.readouterr().out
    assert "info" in out and "recover" in out and "record" in out
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(["log"])
    assert exc.value.code == 2
