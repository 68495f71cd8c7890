"""No single meeting point: when the process holding the shared endpoint dies, a surviving process
takes the endpoint over and a newcomer that knows only that endpoint still finds the cell."""

from __future__ import annotations

import json
import signal
import subprocess

from tests.conftest import REPO, Endpoint, Proc, foldcell_argv, wait_until


def seen_cells(ep: Endpoint) -> set[str]:
    """The cells a newcomer sees alive, knowing only the shared endpoint (it listens on its own port)."""
    result = subprocess.run(foldcell_argv("monitor", "--once", "--json", "--duration", "1.5", "--cell", "*",
                                          "--listen", "tcp/127.0.0.1:0", "--connect", ep.url),
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    return {name for name, cell in json.loads(result.stdout)["cells"].items() if cell["alive"]}


def test_a_survivor_takes_the_shared_endpoint_over_when_its_holder_dies(tmp_path) -> None:
    ep = Endpoint()
    serve = ("controller", "serve", "--role", "both")
    first = Proc(foldcell_argv(*serve, *ep.args("first")), tmp_path / "first.log")
    second = None
    try:
        assert wait_until(lambda: seen_cells(ep) == {"first"}, 60), first.stderr()
        second = Proc(foldcell_argv(*serve, *ep.args("second")), tmp_path / "second.log")
        assert wait_until(lambda: seen_cells(ep) == {"first", "second"}, 60), second.stderr()
        first.stop(signal.SIGKILL)   # the holder of the shared endpoint
        assert wait_until(lambda: seen_cells(ep) == {"second"}, 60), second.stderr()
    finally:
        first.stop()
        if second is not None:
            second.stop()
