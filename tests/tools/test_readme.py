"""The README as written: every `foldcell` command in its code blocks is one the CLI takes, and the
block that starts a cell by hand runs as it stands, to a cell folding a towel that `monitor --once
--json` reports."""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO, Endpoint, wait_until
from tools.cli import build_parser

README = (REPO / "README.md").read_text()
# stand-ins for the README's placeholders, so the line parses as a user's would
PLACEHOLDERS = {"$S": "/etc/foldcell/security"}


def readme_commands() -> list[tuple[int, str]]:
    """(README line, command) of every `foldcell` invocation in a code block: one per `&`-separated
    part of a line, its trailing comment cut."""
    found = []
    for block in re.finditer(r"```\w*\n(.*?)```", README, re.S):
        first_line = README.count("\n", 0, block.start(1)) + 1
        for offset, line in enumerate(block.group(1).splitlines()):
            code = line.split("  #", 1)[0].split(" # ", 1)[0].strip()
            for part in re.split(r"\s&\s*|\s&$", code):
                part = part.strip()
                if part.startswith("foldcell "):
                    for placeholder, value in PLACEHOLDERS.items():
                        part = part.replace(placeholder, value)
                    found.append((first_line + offset, part))
    return found


COMMANDS = readme_commands()


def test_the_readme_has_the_commands_it_documents() -> None:
    assert len(COMMANDS) >= 50, COMMANDS   # the extraction reads every block


@pytest.mark.parametrize(("line", "command"), COMMANDS, ids=[f"L{n}" for n, _ in COMMANDS])
def test_every_readme_command_is_one_the_cli_takes(line: int, command: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    argv = shlex.split(command)[1:]
    try:
        build_parser().parse_args(argv)
    except SystemExit as exc:
        pytest.fail(f"README line {line}: `{command}` is refused ({exc.code}): {capsys.readouterr().err}")


def block_after(heading: str) -> list[str]:
    """The lines of the first code block after `heading`, comments cut."""
    start = README.index(heading)
    block = re.search(r"```\w*\n(.*?)```", README[start:], re.S)
    assert block is not None, heading
    return [line.split("  #", 1)[0].strip() for line in block.group(1).splitlines() if line.strip()]


@pytest.mark.timeout(300)
def test_running_the_processes_yourself_as_the_readme_says(tmp_path: Path) -> None:
    """README "Running the processes yourself", line by line on a private endpoint (the environment's
    FOLDCELL_* variables, as a user on a shared machine would set them), in a folder of its own: the
    fold command is accepted and the monitor's one snapshot shows the cell at work on the towel."""
    lines = block_after("### Running the processes yourself")
    ep = Endpoint("readme")
    env = dict(os.environ, FOLDCELL_CELL=ep.cell, FOLDCELL_LISTEN=f"{ep.url},tcp/127.0.0.1:0",
               FOLDCELL_CONNECT=ep.url, PYTHONUNBUFFERED="1",
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    env.pop("FOLDCELL_SECURITY", None)
    background = [line.removesuffix("&").strip() for line in lines if line.endswith("&")]
    assert [shlex.split(b)[1] for b in background] == ["controller", "controller", "camera", "run"]
    call = next(line for line in lines if line.startswith("foldcell topic call"))
    assert next(line for line in lines if line.startswith("foldcell monitor")) == "foldcell monitor"
    processes = []
    try:
        for index, command in enumerate(background):
            with open(tmp_path / f"process{index}.log", "wb") as log:
                processes.append(subprocess.Popen(shlex.split(command), cwd=tmp_path, env=env,
                                                  stdout=subprocess.DEVNULL, stderr=log))

        def accepted() -> bool:
            done = subprocess.run(shlex.split(call), cwd=tmp_path, env=env, capture_output=True, text=True,
                                  timeout=60)
            return done.returncode == 0

        assert wait_until(accepted, 120), logs(tmp_path)
        # the interactive monitor's one-snapshot form
        snapshot = subprocess.run(["foldcell", "monitor", "--once", "--json"], cwd=tmp_path, env=env,
                                  capture_output=True, text=True, timeout=60)
        assert snapshot.returncode == 0, snapshot.stderr
        state = json.loads(snapshot.stdout)["cells"][ep.cell]["state"]
        assert state["garment"] == "towel" and state["state"] not in ("idle", "fault"), state
        assert list((tmp_path / "runs").glob(f"{ep.cell}-*")), "run records its bag to runs/<cell>-<time>/"
    finally:
        for process in reversed(processes):
            process.send_signal(signal.SIGINT)
        for process in reversed(processes):
            try:
                process.wait(15)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


def logs(folder: Path) -> str:
    return "\n".join(f"{log.name}: {log.read_text(errors='replace')[-1500:]}"
                     for log in sorted(folder.glob("*.log")))
