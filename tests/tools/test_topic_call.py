"""`foldcell topic call` against the emulator as a real process: a call made as the server starts waits for
it; a request the controller refuses exits 1 and says why, one it carries out exits 0; both print the
reply."""

from __future__ import annotations

import subprocess

from tests.conftest import REPO, Endpoint, Proc, foldcell_argv

# MOVE_TO without the lease, then CHECK_QUEUE_CNT
REFUSED = "{command: 300020, client: alive/nobody, values: [0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]}"
CARRIED_OUT = "{command: 200102}"


def call(ep: Endpoint, message: str) -> subprocess.CompletedProcess:
    # a generous --timeout: the call waits that long for a server it has not heard of yet
    return subprocess.run(foldcell_argv("topic", "call", "controller/command", message, "--json",
                                        "--timeout", "60", *ep.args()),
                          cwd=REPO, capture_output=True, text=True, timeout=120)


def test_a_refused_request_exits_1_and_one_carried_out_exits_0(tmp_path):
    ep = Endpoint("call")
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", *ep.args()), tmp_path / "serve.log")
    try:
        carried_out = call(ep, CARRIED_OUT)   # sent as the server starts: it waits for it
        assert carried_out.returncode == 0, (carried_out, proc.stderr()[-2000:])
        assert '"text": "queue count 0"' in carried_out.stdout
        refused = call(ep, REFUSED)
        assert refused.returncode == 1, refused
        assert '"result": 2' in refused.stdout   # FAILURE, no lease: the reply still printed
        assert "refused the request" in refused.stderr and "lease" in refused.stderr, refused.stderr
    finally:
        proc.stop()
