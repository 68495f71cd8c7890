"""A partition between the cell and its controller, run for a test (tests/cell/test_partition.py) and
for `make bench` (tests/bench/bench_faults.py): the controller in a network namespace of its own, the
camera and the cell on this side, the link cut (packets silently lost) as the arms set off for the
cloth, then healed; the operator's reset and a new fold afterwards."""

from __future__ import annotations

import datetime as dt
import re
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.wire import messages
from drivers.wire.settings import load_wire_settings
from drivers.wire.transport import Wire
from tests.cell.cell_states import CellStates
from tests.conftest import Proc, foldcell_argv, free_port, wait_until
from tests.netns import NetNamespace

CELL = "part"
# the controller's line when it drops the lease (its commander's token went, or its watchdog fired)
LEASE_DROPPED = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) WARNING .*lease dropped, stopping: ")
# the cell's line when it faults (its own clock: what reaches an observer may come later)
CELL_FAULTED = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) INFO .*-> fault \(")


@dataclass(frozen=True)
class PartitionResult:
    cell_fault_s: float        # from the cut to the cell's fault (its log)
    fault_reason: str
    controller_stop_s: float   # from the cut to the controller dropping the lease and stopping (its log)
    after_heal: str            # the state a new fold ends in after the heal and the operator's reset
    after_heal_reason: str


def _listening(host: str, port: int) -> bool:
    try:
        with socket.create_connection((host, port), timeout=1.0):
            return True
    except OSError:
        return False


def run_partition(namespace: NetNamespace, logs: Path, recover: bool = True) -> PartitionResult:
    port = free_port()
    shared = f"tcp/{namespace.far}:{port}"
    near = ["--cell", CELL, "--listen", f"tcp/{namespace.near}:0", "--connect", shared]
    procs = {"controller": Proc([*namespace.prefix(), *foldcell_argv(
        "controller", "serve", "--role", "both", "--time-scale", "5", "--cell", CELL, "--listen", shared,
        "--connect", shared)], logs / "controller.log")}
    watcher = None
    try:
        assert wait_until(lambda: _listening(namespace.far, port), 60), procs["controller"].stderr()
        procs["camera"] = Proc(foldcell_argv("camera", "serve", "--garment", "towel", "--seed", "2",
                                             "--folding", "geometric", *near), logs / "camera.log")
        procs["cell"] = Proc(foldcell_argv("run", "--no-record", "--job", str(logs / "cell.job.json"), *near),
                             logs / "cell.log")
        watcher = Wire(load_wire_settings().overridden(
            cell_id=CELL, listen=[f"tcp/{namespace.near}:0"], connect=[shared]), "cli-partition")
        states = CellStates(watcher)

        def first(names: set[str], since: float, timeout: float) -> tuple[float, Any]:
            seen = states.first(names, since, timeout)
            assert seen is not None, f"no cell state in {names} within {timeout} s; last {states.last()!r}"
            return seen

        def command(what: str, argument: str = "") -> Any:
            request = messages.new("foldcell_msgs/msg/CellCommand", command=what, argument=argument,
                                   client="partition")
            return watcher.request("cell/command", request, timeout=10)

        alive = lambda: {key.rsplit("/", 1)[1] for key in watcher.alive()}  # noqa: E731
        assert wait_until(lambda: {"controller", "camera", "cell"} <= alive(), 90), \
            {name: proc.stderr()[-1500:] for name, proc in procs.items()}
        assert command("fold", "towel").accepted
        first({"grasping"}, 0.0, 120)   # the arms on their way to the cloth, nothing held yet
        cut_wall, cut = dt.datetime.now(), time.monotonic()
        namespace.cut()
        _, msg = first({"fault"}, cut, 30)

        def logged_after_cut(proc: Proc, line: re.Pattern) -> float:
            lines = lambda: proc.stderr().splitlines()  # noqa: E731
            assert wait_until(lambda: any(line.match(text) for text in lines()), 30), lines()[-20:]
            stamp = next(m for m in map(line.match, lines()) if m)
            return (dt.datetime.strptime(stamp.group(1), "%Y-%m-%d %H:%M:%S,%f") - cut_wall).total_seconds()

        faulted = logged_after_cut(procs["cell"], CELL_FAULTED)
        stopped = logged_after_cut(procs["controller"], LEASE_DROPPED)
        after, why = "", ""
        if recover:
            namespace.heal()
            assert wait_until(lambda: "controller" in alive(), 60), "the controller did not come back"
            assert command("reset").accepted
            assert command("fold", "towel").accepted
            _, end = first({"done", "failed", "fault"}, time.monotonic(), 180)
            after, why = end.state, end.reason
        return PartitionResult(faulted, msg.reason, stopped, after, why)
    finally:
        if watcher is not None:
            watcher.close()
        for proc in reversed(list(procs.values())):
            proc.stop()
