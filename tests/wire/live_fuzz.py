"""Property-based fuzzing of the running processes' queryables (hypothesis): random bytes, valid
requests cut short, bit-flipped or extended, and other types' messages go to every queryable of a split
cell (master, slave, camera, cell daemon) from a stranger's session. Each must be answered (a reply or
a refusal) and every process must live on. Shared by tests/wire/test_fuzz_live.py (a derandomized few
per endpoint) and tests/bench/bench_fuzz.py (many, random, per-endpoint figures)."""

from __future__ import annotations

import contextlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from hypothesis import HealthCheck, given, settings

from drivers.wire.messages import ErrorReply, NobodyServes, NoReply
from drivers.wire.registry import spec_for
from drivers.wire.transport import Wire
from tests.conftest import Endpoint, Proc, foldcell_argv, wait_until
from tests.wire.fuzz_payloads import payloads

ENDPOINTS = ("controller/command", "controller/trajectory", "controller/slave/command",
             "controller/slave/trajectory", "camera/capture", "cell/command")
PROCESSES = ("controller-master", "controller-slave", "camera", "cell")
REPLY_TIMEOUT_S = 10.0   # generous: a refusal comes in milliseconds, a capture in a fraction of a second


@dataclass
class Tally:
    """Per endpoint: how each case was answered."""

    outcomes: dict[str, Counter] = field(default_factory=dict)
    unanswered: list[tuple[str, bytes]] = field(default_factory=list)

    def add(self, key: str, outcome: str) -> None:
        self.outcomes.setdefault(key, Counter())[outcome] += 1


@dataclass
class LiveCell:
    endpoint: Endpoint
    wire: Wire
    procs: dict[str, Proc]

    def dead(self) -> list[str]:
        return [name for name, proc in self.procs.items() if proc.popen.poll() is not None]

    def joint_states_flow(self, timeout: float = 20.0) -> bool:
        seen: list[int] = []
        self.wire.subscribe("controller/joint_states", lambda *_: seen.append(1))
        return wait_until(lambda: len(seen) > 50, timeout)


@contextlib.contextmanager
def live_cell(logs: Path) -> Iterator[LiveCell]:
    ep = Endpoint("fuzz")
    argvs = {
        "controller-master": ("controller", "serve", "--role", "master"),
        "controller-slave": ("controller", "serve", "--role", "slave"),
        "camera": ("camera", "serve", "--source", "sim", "--garment", "towel", "--folding", "geometric"),
        "cell": ("run", "--no-record"),
    }
    procs: dict[str, Proc] = {}
    wire = None
    try:
        for name, argv in argvs.items():
            procs[name] = Proc(foldcell_argv(*argv, *ep.args()), logs / f"{name}.log")
        wire = Wire(ep.settings(), "cli-fuzz")
        alive = lambda: {key.rsplit("/", 1)[1] for key in wire.alive()}  # noqa: E731
        assert wait_until(lambda: set(PROCESSES) <= alive(), 120), \
            {name: proc.stderr()[-800:] for name, proc in procs.items()}
        yield LiveCell(ep, wire, procs)
    finally:
        if wire is not None:
            wire.close()
        for proc in reversed(list(procs.values())):
            proc.stop()


def fuzz_endpoint(cell: LiveCell, key: str, examples: int, derandomize: bool, tally: Tally) -> None:
    """`examples` cases at `key`; each one's outcome in `tally` (refused, answered, unanswered)."""
    spec = spec_for(key)
    full_key = cell.wire.key(key)

    @settings(max_examples=examples, deadline=None, derandomize=derandomize, database=None,
              suppress_health_check=list(HealthCheck))
    @given(payload=payloads(spec.type_name))
    def one(payload: bytes) -> None:
        try:
            cell.wire.request_raw(full_key, payload, spec.type_name, spec.reply_type, timeout=REPLY_TIMEOUT_S)
            tally.add(key, "answered")
        except ErrorReply:
            tally.add(key, "refused")
        except (NoReply, NobodyServes):
            tally.add(key, "unanswered")
            tally.unanswered.append((key, payload))

    one()
