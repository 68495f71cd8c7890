"""`foldcell demo` stopped by Ctrl-C (SIGINT) while its processes start and while a garment is being
folded: it exits 130 (a shell's 128 + SIGINT) without a traceback, prints its summary with the columns
in line and says what the garment's end was, and leaves none of its processes behind."""

from __future__ import annotations

import signal
import subprocess
import threading
from pathlib import Path

import pytest

from tests.cell.test_e2e import alive, children_of
from tests.conftest import DEMO_TIMEOUT_S, REPO, Endpoint, foldcell_argv, wait_until

pytestmark = pytest.mark.slow


def _descendants(pid: int) -> set[int]:
    found, todo = set(), [pid]
    while todo:
        for child in children_of(todo.pop()):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


@pytest.mark.parametrize("moment", ["[towel] folding", "watch it live"], ids=["mid-garment", "starting"])
@pytest.mark.timeout(DEMO_TIMEOUT_S + 60)
def test_a_demo_stopped_by_ctrl_c_ends_with_its_summary_and_no_process_left(tmp_path: Path, moment: str):
    summary = tmp_path / "stdout.txt"
    with open(summary, "w") as stdout_file:   # one reader per pipe: stderr is read line by line below
        demo = subprocess.Popen(foldcell_argv("demo", "--garment", "towel", "--folding", "geometric",
                                              "--output", str(tmp_path / "demo"), *Endpoint("cell1").args()),
                                cwd=REPO, stdout=stdout_file, stderr=subprocess.PIPE, text=True)
    said: list[str] = []
    assert demo.stderr is not None
    reader = threading.Thread(target=lambda: said.extend(demo.stderr), daemon=True)  # type: ignore[arg-type]
    reader.start()
    try:
        assert wait_until(lambda: any(moment in line for line in said), DEMO_TIMEOUT_S), said[-5:]
        children = _descendants(demo.pid)
        demo.send_signal(signal.SIGINT)
        demo.wait(timeout=DEMO_TIMEOUT_S)
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
    reader.join(10)
    stderr, stdout = "".join(said), summary.read_text()
    assert demo.returncode == 128 + signal.SIGINT, (demo.returncode, stderr[-2000:])
    assert "Traceback" not in stderr, stderr[-2000:]
    assert not [pid for pid in children if alive(pid)], "processes of the demo left running"
    lines = stdout.splitlines()
    header = next(i for i, text in enumerate(lines) if text.startswith("garment"))
    table = lines[header + 2:lines.index("", header)]   # the rows, up to the blank line after them
    rows = [text for text in table if not text.startswith(" ")]
    if moment == "watch it live" and not rows:
        assert "no garment was begun" in stderr, stderr[-2000:]
    else:
        (row,) = rows
        assert row.split()[:2] == ["towel", "interrupted"] and len(row) == len(lines[header]), lines
