"""Every `foldcell` subcommand given bad input, as an operator would type it (README "The command line"):
exit status 2, no traceback, the last line on stderr naming the flag, file or field and the reason,
nothing on stdout, nothing written. The subcommands are read from the real parser, so one added without
a case here fails `test_every_subcommand_has_a_bad_input_case`."""

from __future__ import annotations

import argparse
import os
import subprocess
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import REPO, Endpoint, foldcell_argv
from tools.cli import build_parser

WORKERS = 3        # 2 cores: the processes mostly import, a third keeps both busy
PROCESS_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class Case:
    argv: tuple[str, ...]
    names: tuple[str, ...]   # each must be in stderr's last line: the culprit and a word of the reason

    @property
    def id(self) -> str:
        return " ".join(repr(a) if not a or " " in a else a for a in self.argv)


def case(*argv: str, names: tuple[str, ...]) -> Case:
    return Case(argv, names)


ENDPOINT_OUT_OF_RANGE = ("--connect", "99999", "port")
NOT_RESOLVED = ("--connect", "nohost.invalid", "does not resolve")
EMPTY_OUTPUT = ("-o/--output", "empty path")
NOT_AN_MCAP = ("junk.mcap", "not an MCAP")
BAD_YAML = ("bad.yaml", "not valid YAML", "line 2")   # one line: where, not PyYAML's quoted source

# Files in the folder each case runs in (its cwd): made by `inputs` below.
CASES = [
    case("demo", "--seed", "-1", names=("--seed", ">= 0")),
    case("demo", "--time-scale", "inf", names=("--time-scale", "finite")),
    case("demo", "-o", "", names=EMPTY_OUTPUT),
    case("demo", "--garment", "sock", names=("--garment", "invalid choice", "sock")),
    case("demo", "--security", "missing", names=("--security", "missing")),
    case("run", "--connect", "tcp/127.0.0.1:99999", names=ENDPOINT_OUT_OF_RANGE),
    case("run", "--controller", "bogus://x", names=("--controller", "bogus://x")),
    case("run", "--config", "missing.yaml", names=("missing.yaml", "cannot read")),
    case("run", "--table-model", "bad.yaml", names=BAD_YAML),
    case("controller", "serve", "--time-scale", "inf", names=("--time-scale", "finite")),
    case("controller", "serve", "--role", "slave", "--motoros", ":50240", names=("--motoros", "role both")),
    case("controller", "serve", "--controller-config", "bad.yaml", names=BAD_YAML),
    case("controller", "status", "--connect", "tcp/127.0.0.1:99999", names=ENDPOINT_OUT_OF_RANGE),
    case("controller", "status", "--motoros", "host:abc", names=("--motoros", "PORT", "abc")),
    case("controller", "servo", "maybe", names=("state", "invalid choice", "maybe")),
    case("controller", "estop", "--cell", "a b", names=("--cell", "'a b'", "letters")),
    case("controller", "reset", "--connect", "tcp/nohost.invalid:7448", names=NOT_RESOLVED),
    case("controller", "hold", "--security", "notsec", names=("--security", "notsec")),
    case("controller", "resume", "--motoros", "127.0.0.1:50240", names=("--motoros", "no hold")),
    case("controller", "stop", "--connect", "", names=("--connect", "not a Zenoh endpoint")),
    case("controller", "home", "--timeout", "-1", names=("--timeout", "> 0")),
    case("controller", "jog", "nosuch", "0.1", names=("joint", "nosuch")),
    case("controller", "jog", "r1_joint_s", "abc", names=("delta", "invalid float", "abc")),
    case("controller", "jog", "r1_joint_s", "nan", names=("delta", "finite")),
    case("controller", "grip", "r3", "open", names=("arm", "r3")),
    case("controller", "send", "missing.yaml", names=("missing.yaml", "cannot read")),
    case("controller", "send", "bad.yaml", names=BAD_YAML),
    case("controller", "send", "", names=("trajectory", "empty path")),
    case("controller", "watch", "--rate", "0", names=("--rate", "> 0")),
    case("controller", "fault", "alarm", "on", "1", names=("fault alarm on", "0 value")),
    case("controller", "fault", "reply-latency", "on", "nan", "1", names=("values", "finite")),
    case("camera", "serve", "--seed", "-1", names=("--seed", ">= 0")),
    case("camera", "serve", "--source", "bogus:x", names=("--source", "bogus:x")),
    case("camera", "serve", "--source", "dir:missing", names=("--source", "dir:missing", "not a directory")),
    case("camera", "capture", "--timeout", "nan", names=("--timeout", "finite")),
    case("camera", "capture", "-o", "", names=EMPTY_OUTPUT),
    case("perceive", "missing.png", names=("missing.png", "no such image")),
    case("perceive", "junk.png", names=("junk.png", "cannot decode")),
    case("perceive", "", names=("image", "empty path")),
    case("perceive", "junk.png", "--category", "sock", names=("--category", "invalid choice", "sock")),
    case("perceive", "junk.png", "--table-model", "bad.yaml", names=BAD_YAML),
    case("table", "fit", "junk.png", "-o", "out.yaml", names=("junk.png", "cannot decode")),
    case("table", "fit", "--annotations", "missing", "-o", "out.yaml", names=("missing", "not a directory")),
    case("table", "fit", "--annotations", "", "-o", "out.yaml", names=("--annotations", "empty path")),
    case("table", "fit", "-o", "out.yaml", names=("IMAGES", "--annotations")),
    case("models", "learn", "missing", "-o", "out", names=("missing", "not a directory")),
    case("models", "learn", "empty", "-o", "out", names=("empty", "no usable")),
    case("models", "learn-recognition", "missing", "-o", "out.yaml", names=("missing", "not a directory")),
    case("models", "learn-recognition", "", "-o", "out.yaml", names=("DATASET", "empty path")),
    case("eval", "missing", names=("missing", "not a directory")),
    case("eval", "empty", "--cm-per-px", "-1", names=("--cm-per-px", "> 0")),
    case("eval", "", names=("dataset", "empty path")),
    case("dataset", "generate", "--count", "0", "-o", "out", names=("--count", "positive")),
    case("dataset", "generate", "--count", "1", names=("-o/--output", "missing")),
    case("dataset", "generate", "--count", "1", "--categories", "sock", "-o", "out",
         names=("--categories", "invalid choice", "sock")),
    case("dataset", "sheet", "missing", "-o", "s.png", names=("missing", "not a directory")),
    case("dataset", "sheet", "badset", "-o", "s.png", names=("garbage.yaml", "not valid YAML")),
    case("dataset", "sheet", "", "-o", "s.png", names=("DIR", "empty path")),
    case("plan", "check", "--placements", "0", names=("--placements", ">= 1")),
    case("plan", "check", "--category", "sock", names=("--category", "invalid choice", "sock")),
    case("plan", "reach", "abc", "0.1", names=("x", "invalid float", "abc")),
    case("plan", "reach", "nan", "0.1", names=("x, y", "finite")),
    case("plan", "reach", "0.1", "0.1", "--arm", "r3", names=("--arm", "invalid choice", "r3")),
    case("sim", "fold", "--seed", "-1", names=("--seed", ">= 0")),
    case("sim", "fold", "--speed", "0", names=("--speed", "positive")),
    case("sim", "fold", "--lift-fraction", "5", names=("--lift-fraction", "0..2")),
    case("sim", "fold", "--oracle", names=("--oracle", "--recipe")),
    case("log", "info", "missing.mcap", names=("missing.mcap", "no such file")),
    case("log", "info", "junk.mcap", names=NOT_AN_MCAP),
    case("log", "info", "empty", names=("empty", "not a session")),
    case("log", "info", "", names=("BAG|FILE", "empty path")),
    case("log", "recover", "junk.mcap", names=NOT_AN_MCAP),
    case("log", "recover", "", names=("BAG|FILE", "empty path")),
    case("log", "recover", "junk.mcap", "-o", "", names=EMPTY_OUTPUT),
    case("log", "record", "--duration", "-1", names=("--duration", "> 0")),
    case("log", "record", "-o", "", names=EMPTY_OUTPUT),
    case("log", "record", "--cell", "a b", names=("--cell", "'a b'", "letters")),
    case("topic", "list", "--duration", "0", names=("--duration", "> 0")),
    case("topic", "list", "--connect", "bad", names=("--connect", "'bad'", "not a Zenoh endpoint")),
    case("topic", "echo", "no/such/key", names=("no/such/key", "not a key")),
    case("topic", "echo", "cell/command", names=("cell/command", "queryable")),
    case("topic", "echo", "cell/state", "--count", "0", names=("--count", "at least 1")),
    case("topic", "echo", "cell/state", "--connect", "tcp/nohost.invalid:7448", names=NOT_RESOLVED),
    case("topic", "hz", "no/such/key", names=("no/such/key", "not a key")),
    case("topic", "hz", "cell/state", "--duration", "nan", names=("--duration", "finite")),
    case("topic", "pub", "no/such/key", names=("no/such/key", "not a key")),
    case("topic", "pub", "cell/command", names=("cell/command", "queryable")),
    case("topic", "pub", "cell/state", "{a: [b", names=("message", "not valid YAML", "line 1")),
    case("topic", "pub", "cell/state", "{nosuchfield: 1}", names=("nosuchfield",)),
    case("topic", "pub", "cell/state", "{state: idle}", "--rate", "0", names=("--rate", "> 0")),
    case("topic", "call", "cell/state", names=("cell/state", "not a queryable")),
    case("topic", "call", "cell/command", "{command: [}", names=("message", "not valid YAML")),
    case("topic", "call", "cell/command", "--timeout", "-1", names=("--timeout", "> 0")),
    case("replay", "missing.mcap", names=("missing.mcap", "no such file")),
    case("replay", "junk.mcap", names=NOT_AN_MCAP),
    case("replay", "junk.mcap", "--rate", "fast", names=("--rate", "fast")),
    case("replay", "junk.mcap", "--start", "-1", names=("--start", ">= 0")),
    case("replay", "", names=("BAG|FILE", "empty path")),
    case("monitor", "--duration", "-1", names=("--duration", ">= 0")),
    case("monitor", "-o", "", names=("-o/--output", "empty path")),
    case("monitor", "--cell", "a b", names=("--cell", "'a b'", "letters")),
    case("foxglove", "--port", "70000", names=("--port", "0..65535")),
    case("foxglove", "--export", "missing.mcap", names=("missing.mcap", "no such file")),
    case("foxglove", "--export", "junk.mcap", names=NOT_AN_MCAP),
    case("foxglove", "--export", "", names=("--export", "empty path")),
    case("ros2", "--domain-id", "999", names=("--domain-id", "999")),
    case("ros2", "--domain-id", "abc", names=("--domain-id", "abc")),
    case("ros2", "--ros-connect", "bad", "--print", names=("--ros-connect", "'bad'", "not a Zenoh endpoint")),
    case("ros2", "--cell", "*", names=("--cell", "one cell")),
    case("router", "--listen", "tcp/127.0.0.1:99999", names=("--listen", "99999", "port")),
    case("router", "--config", "bad.yaml", names=BAD_YAML),
    case("router", "--security", "notsec", names=("--security", "notsec")),
    case("router", "--mode", "bogus", names=("--mode", "invalid choice", "bogus")),
    case("security", "init", "", names=("DIR", "empty path")),
    case("security", "init", "junk.png", names=("junk.png", "not a directory")),
    case("security", "show", "missing", names=("DIR", "missing", "not a directory")),
    case("security", "show", "notsec", names=("DIR", "notsec", "not a directory")),
]

# A subcommand with no input that can be bad, and why: none so far (every one takes at least the
# connection flags or a file).
NO_BAD_INPUT: dict[str, str] = {}


def subcommands(parser: argparse.ArgumentParser, prefix: tuple[str, ...] = ()
                ) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    """Every leaf subcommand (its words) and its parser; an alias is not a subcommand of its own."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            seen: set[int] = set()
            for name, sub in action.choices.items():   # a name comes before its aliases
                if id(sub) not in seen:
                    seen.add(id(sub))
                    yield from subcommands(sub, (*prefix, name))
            return
    yield prefix, parser


PARSERS = dict(subcommands(build_parser()))


def command_of(argv: tuple[str, ...]) -> tuple[str, ...]:
    """The subcommand a command line runs: its longest prefix that names one."""
    return max((words for words in PARSERS if argv[:len(words)] == words), key=len, default=())


def test_every_subcommand_has_a_bad_input_case() -> None:
    covered = {command_of(c.argv) for c in CASES}
    missing = [" ".join(words) for words in PARSERS
               if words not in covered and " ".join(words) not in NO_BAD_INPUT]
    assert not missing, f"no bad-input case for: {', '.join(missing)}"
    stale = [c.id for c in CASES if not command_of(c.argv)] + \
        [name for name in NO_BAD_INPUT if tuple(name.split()) not in PARSERS]
    assert not stale, f"not a subcommand: {stale}"


@dataclass(frozen=True)
class Outcome:
    returncode: int
    stdout: str
    stderr: str


def _argv(c: Case) -> list[str]:
    """The case's command line; a command that joins Zenoh gets a free loopback endpoint of its own
    first (the case's own flags come after and win), so a case that wrongly gets as far as connecting
    meets nobody, on this machine only."""
    words = command_of(c.argv)
    wire = Endpoint(cell="badinput").args() if "--connect" in PARSERS[words]._option_string_actions else []
    return foldcell_argv(*words, *wire, *c.argv[len(words):])


def _run(c: Case, folder: Path, env: dict[str, str]) -> Outcome:
    try:
        done = subprocess.run(_argv(c), cwd=folder, env=env, capture_output=True, text=True,
                              timeout=PROCESS_TIMEOUT_S, stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired as exc:
        still = f"{exc.stderr or ''}\n(still running after {exc.timeout} s)"
        return Outcome(-1, str(exc.stdout or ""), still)
    return Outcome(done.returncode, done.stdout, done.stderr)


def _inputs(folder: Path) -> None:
    """What the cases name: garbage where an MCAP, a PNG or YAML is expected, empty folders."""
    (folder / "junk.mcap").write_bytes(b"garbage, not an MCAP file\x00\x01")
    (folder / "junk.png").write_bytes(b"garbage, not a PNG")
    (folder / "bad.yaml").write_text("a: [b\n")
    (folder / "empty").mkdir()
    (folder / "notsec").mkdir()     # not a `security init` directory
    (folder / "badset").mkdir()
    (folder / "badset" / "garbage.yaml").write_text("path_c: [\n")


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory: pytest.TempPathFactory
             ) -> Iterator[tuple[dict[str, Outcome], Path, set[Path]]]:
    folder = tmp_path_factory.mktemp("bad-input")
    _inputs(folder)
    before = set(folder.rglob("*"))
    env = {k: v for k, v in os.environ.items() if not k.startswith("FOLDCELL_")}   # no cell of the caller's
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [env.get("PYTHONPATH")])])
    with ThreadPoolExecutor(WORKERS) as pool:
        results = dict(zip([c.id for c in CASES], pool.map(lambda c: _run(c, folder, env), CASES),
                           strict=True))
    yield results, folder, before


@pytest.mark.parametrize("c", CASES, ids=[c.id for c in CASES])
def test_bad_input_is_refused_naming_the_culprit(c: Case, outcomes: tuple[dict[str, Outcome], Path, set[Path]]
                                                 ) -> None:
    out = outcomes[0][c.id]
    assert "Traceback" not in out.stderr, out.stderr
    assert out.returncode == 2, (out.returncode, out.stderr)
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert lines, "nothing on stderr"
    last = lines[-1]
    assert last.startswith("foldcell") and "error: " in last, last
    # one line says what is wrong: argparse's usage may come before it, nothing else that is an error
    assert [line for line in lines if "error" in line.lower()] == [last], out.stderr
    for name in c.names:
        assert name in last, (name, last)
    assert out.stdout == "", out.stdout


def test_bad_input_writes_nothing(outcomes: tuple[dict[str, Outcome], Path, set[Path]]) -> None:
    _, folder, before = outcomes
    assert sorted(map(str, set(folder.rglob("*")) - before)) == []
