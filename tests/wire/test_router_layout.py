"""The multi-machine layout: controller, camera and cell each in a network namespace of its own (as on
three machines that cannot reach each other directly), meeting through a `foldcell router`; the cell
folds a towel through it."""

from __future__ import annotations

import contextlib

import pytest

from drivers.wire import messages
from drivers.wire.settings import load_wire_settings
from drivers.wire.transport import Wire
from tests.conftest import Proc, foldcell_argv, free_port, wait_until
from tests.netns import NetNamespace

CELL = "routed"


@pytest.mark.timeout(300)
def test_three_namespaces_meet_through_a_router_and_fold(tmp_path) -> None:
    why = NetNamespace.unavailable()
    if why:
        pytest.skip(f"no network namespaces for the router layout: {why}")
    port = free_port()
    with contextlib.ExitStack() as stack:
        spaces = {name: stack.enter_context(NetNamespace()) for name in ("controller", "camera", "cell")}
        router = Proc(foldcell_argv("router", "--cell", CELL, "--listen", f"tcp/0.0.0.0:{port}"),
                      tmp_path / "router.log")
        stack.callback(router.stop)
        assert wait_until(lambda: "router serving" in router.stderr(), 60), router.stderr()
        commands = {"controller": ("controller", "serve", "--role", "both", "--time-scale", "5"),
                    "camera": ("camera", "serve", "--garment", "towel", "--seed", "2",
                               "--folding", "geometric"),
                    "cell": ("run", "--no-record")}
        for name, words in commands.items():
            ns = spaces[name]
            proc = Proc([*ns.prefix(), *foldcell_argv(*words, "--cell", CELL, "--mode", "client",
                                                      "--connect", f"tcp/{ns.near}:{port}")],
                        tmp_path / f"{name}.log")
            stack.callback(proc.stop)
        wire = Wire(load_wire_settings().overridden(cell_id=CELL, listen=["tcp/127.0.0.1:0"],
                                                    connect=[f"tcp/127.0.0.1:{port}"]), "cli-router-test")
        stack.callback(wire.close)
        states: list[str] = []
        wire.subscribe("cell/state", lambda _k, msg, _r: states.append(msg.state))
        alive = lambda: {key.rsplit("/", 1)[1] for key in wire.alive()}  # noqa: E731
        assert wait_until(lambda: {"controller", "camera", "cell"} <= alive(), 90), \
            (tmp_path / "cell.log").read_text()[-2000:]
        heard: list[str] = []
        wire.subscribe("controller/status", lambda k, _m, _r: heard.append(k))
        assert wait_until(lambda: len(heard) > 5, 30), "no controller status through the router"
        replies = []
        fold = messages.new("foldcell_msgs/msg/CellCommand", command="fold", argument="towel", client="test")
        assert wait_until(lambda: replies.append(wire.request("cell/command", fold, timeout=10)) or
                          replies[-1].accepted, 60, 1.0), replies[-1].text
        ended = ("done", "failed", "fault")
        assert wait_until(lambda: bool(states) and states[-1] in ended, 180), states[-5:]
        assert states[-1] == "done", (tmp_path / "cell.log").read_text()[-2000:]
