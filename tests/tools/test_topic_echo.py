"""`foldcell topic echo` and `topic hz` on the controller's joint states: echo piped into a reader that
goes away after one message (`| head -1`) ends quietly at once, as YAML and as JSON lines; hz prints
one readable line."""

from __future__ import annotations

import json
import re
import subprocess
from collections.abc import Iterator

import pytest
import yaml

from tests.conftest import REPO, Endpoint, Proc, accepts, foldcell_argv, wait_until

READER_GONE_TIMEOUT_S = 30   # generous: the echo ends on the next sample after the reader left


@pytest.fixture(scope="module")
def controller(tmp_path_factory) -> Iterator[Endpoint]:
    ep = Endpoint("echo")
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", *ep.args()),
                tmp_path_factory.mktemp("echo") / "serve.log")
    # every process listens on the endpoint: the controller must hold it before a short-lived echo
    # takes it and leaves with it
    assert wait_until(lambda: accepts(ep.port), 60), proc.stderr()
    yield ep
    proc.stop()


def first_message_then_close(ep: Endpoint, *flags: str) -> tuple[str, subprocess.Popen]:
    """Start an echo of the joint states, read its first message, close the pipe; the echo's process."""
    echo = subprocess.Popen(foldcell_argv("topic", "echo", "controller/joint_states", *flags, *ep.args()),
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert echo.stdout is not None
    lines = []
    for line in echo.stdout:
        lines.append(line)
        if line.startswith("---") or "--json" in flags:
            break
    echo.stdout.close()
    return "".join(lines), echo


@pytest.mark.parametrize("flags", [(), ("--json",)], ids=["yaml", "json"])
def test_an_echo_whose_reader_leaves_ends_quietly(controller, flags):
    first, echo = first_message_then_close(controller, *flags)
    try:
        returncode = echo.wait(READER_GONE_TIMEOUT_S)
    finally:
        echo.kill()
    stderr = echo.stderr.read() if echo.stderr else ""
    # what the reader got is one whole message of the controller's stream
    message = json.loads(first)["message"] if flags else yaml.safe_load(first.removesuffix("---\n"))
    assert len(message["position"]) == len(message["name"]) > 0, first
    assert returncode == 141, (flags, returncode, stderr[-2000:])
    assert "Traceback" not in stderr and "BrokenPipe" not in stderr, stderr[-2000:]


def test_hz_prints_one_line_with_the_rate_and_the_gaps(controller):
    result = subprocess.run(foldcell_argv("topic", "hz", "controller/joint_states", "--duration", "1",
                                          *controller.args()),
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result
    (line,) = result.stdout.strip().splitlines()
    number = r"[0-9]+(\.[0-9]+)?"
    assert re.fullmatch(rf"controller/joint_states: {number} Hz over [0-9]+ samples; gaps p50 {number} ms, "
                        rf"p99 {number} ms, max {number} ms", line), line


def test_an_echo_of_a_key_nobody_publishes_says_what_it_waits_for_and_its_timeout_ends_it(controller):
    """The controller runs; no cell does, so nothing comes on cell/state."""
    result = subprocess.run(foldcell_argv("topic", "echo", "cell/state", "-n", "1", "--timeout", "3",
                                          *controller.args()),
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1, result
    assert result.stdout == ""
    waiting, gave_up = result.stderr.strip().splitlines()
    assert waiting.startswith("foldcell: waiting for a message on foldcell/echo/cell/state"), waiting
    # the processes of the cell that are there, not the echo itself
    assert waiting.endswith("(processes of cell 'echo' seen: controller; Ctrl-C to stop)"), waiting
    assert gave_up == "foldcell: no message on foldcell/echo/cell/state within 3 s", gave_up
