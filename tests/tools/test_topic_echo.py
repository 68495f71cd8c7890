"""`foldcell topic echo` as a Unix filter: piped into a reader that goes away after one message
(`| head -1`), it ends quietly at once, as YAML and as JSON lines."""

from __future__ import annotations

import json
import subprocess

import yaml

from tests.conftest import REPO, Endpoint, Proc, foldcell_argv

READER_GONE_TIMEOUT_S = 30   # generous: the echo ends on the next sample after the reader left


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


def test_an_echo_whose_reader_leaves_ends_quietly(tmp_path):
    ep = Endpoint("echo")
    controller = Proc(foldcell_argv("controller", "serve", "--role", "both", *ep.args()),
                      tmp_path / "serve.log")
    try:
        for flags in ((), ("--json",)):
            first, echo = first_message_then_close(ep, *flags)
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
    finally:
        controller.stop()
