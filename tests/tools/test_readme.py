"""The README as written: every `foldcell` command in its code blocks is one the CLI takes, and the
block that starts a cell by hand runs as it stands, to a cell folding a towel that `monitor --once
--json` reports; so do the blocks of the secured cell, MotoROS, replay, the monitor, Foxglove and the
rosbags reading of a session, their output compared with the shape the README gives."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
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
        stop(processes)


def logs(folder: Path) -> str:
    return "\n".join(f"{log.name}: {log.read_text(errors='replace')[-1500:]}"
                     for log in sorted(folder.glob("*.log")))


# --- the other blocks, run as written -----------------------------------------------------------------
# Every block below is read from README.md by its heading and run line by line as a user types it, in a
# folder of its own, on a private endpoint: the FOLDCELL_* variables (as the test above) stand in for the
# default tcp/127.0.0.1:7448, so a cell of another user on this machine is neither joined nor disturbed.
# Any further substitution is named in a comment where it is made.


def private_env(ep: Endpoint) -> dict[str, str]:
    env = dict(os.environ, FOLDCELL_CELL=ep.cell, FOLDCELL_LISTEN=f"{ep.url},tcp/127.0.0.1:0",
               FOLDCELL_CONNECT=ep.url, PYTHONUNBUFFERED="1",
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    env.pop("FOLDCELL_SECURITY", None)
    return env


def code_lines(heading: str) -> list[str]:
    """`block_after`, without the lines that were only a comment."""
    return [line for line in block_after(heading) if line and not line.startswith("#")]


class Shell:
    """README lines run as a shell runs them, in `folder` with `env`: `NAME=value` sets a variable that
    `$NAME` expands to, a part ending in `&` runs in the background (stopped by `stop_all`, SIGINT as
    Ctrl-C, the last started first), `> FILE` sends stdout to FILE; `substitutions` (text -> text) are
    applied to every line first."""

    def __init__(self, folder: Path, env: dict[str, str], substitutions: dict[str, str] | None = None):
        self.folder, self.env = folder, env
        self.substitutions = dict(substitutions or {})
        self.variables: dict[str, str] = {}
        self.background: list[tuple[subprocess.Popen, Path]] = []

    def expand(self, line: str) -> str:
        for text, value in self.substitutions.items():
            line = line.replace(text, value)
        for name, value in self.variables.items():
            line = line.replace(f"${name}", value)
        return line

    def line(self, line: str, timeout: float = 120) -> list[subprocess.CompletedProcess]:
        """Runs `line`; the foreground commands' results."""
        line = self.expand(line)
        assignment = re.fullmatch(r"(\w+)=(\S+)", line)
        if assignment:
            self.variables[assignment.group(1)] = assignment.group(2)
            return []
        done = []
        parts = [part.strip() for part in re.split(r"(?<=\s&)\s+", line) if part.strip()]
        for part in parts:
            if part.endswith("&"):
                self.start(part.removesuffix("&").strip())
            else:
                done.append(self.run(part, timeout))
        return done

    def start(self, command: str) -> tuple[subprocess.Popen, Path]:
        # a log of its own, beside those of another shell in the same folder
        log = next(self.folder / f"background{n}.log" for n in itertools.count()
                   if not (self.folder / f"background{n}.log").exists())
        with open(log, "wb") as err:
            process = subprocess.Popen(shlex.split(command), cwd=self.folder, env=self.env,
                                       stdout=subprocess.DEVNULL, stderr=err)
        self.background.append((process, log))
        return process, log

    def run(self, command: str, timeout: float = 120) -> subprocess.CompletedProcess:
        argv, out = shlex.split(command), None
        if ">" in argv:
            argv, out = argv[:argv.index(">")], self.folder / argv[argv.index(">") + 1]
        done = subprocess.run(argv, cwd=self.folder, env=self.env, capture_output=True, text=True,
                              timeout=timeout)
        if out is not None:
            out.write_text(done.stdout)
        return done

    def logs(self) -> str:
        return "\n".join(f"{log.name} ({process.args!r}): {log.read_text(errors='replace')[-1500:]}"
                         for process, log in self.background)

    def says(self, text: str, timeout: float = 60) -> bool:
        """Whether a background process's log says `text` within `timeout` (none of them ended first)."""
        wait_until(lambda: text in self.logs() or any(p.poll() is not None for p, _ in self.background),
                   timeout)
        return text in self.logs()

    def stop_all(self) -> None:
        stop([process for process, _ in self.background])
        self.background.clear()


def stop(processes: list[subprocess.Popen]) -> None:
    """SIGINT (Ctrl-C) to each, the last started first, then waits; killed if one hangs."""
    for process in reversed(processes):
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in reversed(processes):
        try:
            process.wait(20)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def snapshot(shell: Shell, *args: str, heard: bool = True) -> dict:
    """`foldcell monitor --once --json` on the shell's wire (the monitor's one-snapshot form); with
    `heard` False, no cells when it heard none (exit 1), for a caller that waits for one."""
    done = shell.run(shlex.join(["foldcell", "monitor", *args, "--once", "--json"]), 60)
    if not heard and done.returncode == 1 and "heard from" in done.stderr:
        return {"cells": {}}
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def alive_processes(shell: Shell, cell: str, *args: str) -> set[str]:
    cells = snapshot(shell, *args, heard=False)["cells"]
    return set(cells[cell]["processes"]) if cell in cells else set()


def free_ports(count: int) -> int:
    """The first of `count` consecutive free ports (MotoROS serves motion, state and IO on P, P+1, P+2)."""
    import random
    for _ in range(200):
        first = random.randint(20000, 60000 - count)
        try:
            with contextlib.ExitStack() as stack:
                for port in range(first, first + count):
                    s = stack.enter_context(socket.socket())
                    s.bind(("127.0.0.1", port))
            return first
        except OSError:
            continue
    raise RuntimeError("no free ports")


def shape_of(text: str) -> re.Pattern[str]:
    """A pattern for output of `text`'s shape: each number matches a number of its kind (an integer, a
    decimal with as many decimals), everything else itself."""
    out, last = [], 0
    for match in re.finditer(r"-?\d+(?:\.\d+)?", text):
        decimals = match.group(0).partition(".")[2]
        number = r"-?\d+" + (rf"\.\d{{{len(decimals)}}}" if decimals else "")
        out += [re.escape(text[last:match.start()]), number]
        last = match.end()
    return re.compile("".join([*out, re.escape(text[last:])]))


SHAPE_TOKEN = re.compile(r'"[^"]*"|\.\.\.|[A-Z]+|[{}\[\]:,]')


def json_shape(text: str) -> dict | list | None:
    """The JSON shape the README writes as `{"key", "key": {...}, "list": [{"key"}], ID: {...}}`: a dict
    of key -> shape (None: any value), `*` for a placeholder key (ID, KEY, ARM: every key, each value of
    that shape), `...` for keys left unnamed; a list as [shape of each item]."""
    tokens = SHAPE_TOKEN.findall(text)
    at = 0

    def take() -> str:
        nonlocal at
        at += 1
        return tokens[at - 1]

    def value() -> dict | list | None:
        token = take()
        if token == "[":
            item = None if tokens[at] == "..." and take() else value()
            assert take() == "]", text
            return [item]
        assert token == "{", text
        shape: dict = {}
        while tokens[at] != "}":
            key = take()
            name = key.strip('"') if key.startswith('"') else key if key == "..." else "*"
            shape[name] = value() if tokens[at] == ":" and take() else None
            if tokens[at] == ",":
                take()
        take()
        return shape

    return value()


def shape_mismatches(actual: object, shape: dict | list | None, path: str = "$") -> list[str]:
    """Where `actual` (parsed JSON) differs from `shape`: an object has exactly the keys named (at least
    them where the README leaves some unnamed with `...`); null stands for any object."""
    if shape is None or actual is None:
        return []
    if isinstance(shape, list):
        assert isinstance(actual, list), path
        return [m for i, item in enumerate(actual) for m in shape_mismatches(item, shape[0], f"{path}[{i}]")]
    assert isinstance(actual, dict), f"{path}: {actual!r} is no object"
    if "*" in shape:
        return [m for key, item in actual.items()
                for m in shape_mismatches(item, shape["*"], f"{path}.{key}")]
    named = set(shape) - {"..."}
    found = []
    if not named <= set(actual) or ("..." not in shape and set(actual) != named):
        found.append(f"{path}: the README names {sorted(named - set(actual))} not there, the output has "
                     f"{sorted(set(actual) - named) if '...' not in shape else []} the README does not name")
    return found + [m for key in sorted(named & set(actual))
                    for m in shape_mismatches(actual[key], shape[key], f"{path}.{key}")]


def readme_span_after(marker: str) -> str:
    """The text of the code span that starts right after `marker` in the README."""
    start = README.index(marker) + len(marker)
    assert README[start] == "`", marker
    return README[start + 1:README.index("`", start + 1)]


@pytest.mark.timeout(300)
def test_a_locked_down_cell_as_the_readme_says(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """README "A locked-down cell": the CA and the roles' directories made and checked, the CA's key moved
    away, a router and the secured cell's processes each in its role's directory, the observer's monitor
    in a terminal watching them; then the demo on the top directory, until it folds."""
    lines = code_lines("### A locked-down cell: `--security DIR`")
    ep = Endpoint("readme-secured")
    (tmp_path / "offline").mkdir()
    # /etc/foldcell/security and /media/offline (a medium kept off the cell) are folders of the test's own
    shell = Shell(tmp_path, private_env(ep), {"/etc/foldcell/security": str(tmp_path / "security"),
                                              "/media/offline/": f"{tmp_path / 'offline'}/"})
    demo = [line for line in lines if line.startswith("foldcell demo")]
    assert demo == ["foldcell demo --security $S"], lines   # run last, the hand-started cell stopped
    monitor = "foldcell monitor --security $S/observer"
    assert monitor in lines, lines
    wanted = {"camera", "cell", "controller-master", "controller-slave"}
    try:
        for line in lines:
            if line in demo:
                continue
            if line == monitor:   # in a terminal, once the cell's processes are up: it watches, keys off
                def all_up(observer: str = shell.expand("$S/observer")) -> bool:
                    return alive_processes(shell, ep.cell, "--security", observer) >= wanted
                assert wait_until(all_up, 120, 1.0), shell.logs()
                shown = on_a_terminal(shell, shell.expand(line), ep.cell, monkeypatch)
                assert "keys off" in shown, shown
                continue
            results = shell.line(line)
            assert all(done.returncode == 0 for done in results), f"{line}: {results}"
            out = "".join(done.stdout for done in results)
            if line.startswith("foldcell security init"):   # the hosts given, besides this machine's
                assert re.search(r"\(valid for localhost, 127\.0\.0\.1, .*cell-pc, 10\.0\.0\.5\)", out), out
            if line.startswith("foldcell security show"):    # one line per role: its rights
                from drivers.wire.security import load_security_config
                assert [row.split()[0] for row in out.splitlines()] == list(load_security_config().roles), out
                assert all(re.search(r" valid until \d{4}-\d\d-\d\d  publishes .*; serves .*; calls ", row)
                           for row in out.splitlines()), out
            if line.startswith("foldcell router"):   # the meeting point, started first: up before the rest
                assert shell.says("router serving"), shell.logs()
        top = tmp_path / "security"
        assert not (top / "ca-private").exists() and (tmp_path / "offline" / "ca-private").is_dir()
        assert all((top / role / f"{role}.key").is_file() for role in ("router", "cell", "observer"))
        assert alive_processes(shell, ep.cell, "--security", str(top / "observer")) >= wanted, shell.logs()
        assert all(process.poll() is None for process, _ in shell.background), shell.logs()
        shell.stop_all()
        # the demo, given the top directory (its CA key moved away), starts every role secured and folds:
        # every garment in the physics world takes minutes, so it is stopped (Ctrl-C) once its cell works
        # on the first garment (tests/cell/test_e2e.py runs a secured demo to its end)
        process, log = shell.start(shell.expand(demo[0]))
        assert shell.says("[towel] fold 1/2 perceiving", 240), shell.logs()
        stop([process])
        assert process.returncode == 130 and "[towel] interrupted" in log.read_text(), shell.logs()
        assert list(tmp_path.glob("runs/demo-*/summary.json")), "the demo writes runs/demo-<time>/"
    finally:
        shell.stop_all()


@pytest.mark.timeout(300)
def test_motoros_as_the_readme_says(tmp_path: Path) -> None:
    """README "MotoROS": the emulator serves MotoROS, and `status --json`, `servo on` and `watch` speak
    it; then, secured, a router, the emulator serving MotoROS over TLS and `status` in the operator's
    role."""
    lines = code_lines("### MotoROS: the real controller's protocol")
    plain_port, secured_port = free_ports(3), free_ports(3)
    # MotoROS' default ports 50240-50242 may be another user's on this machine: the test's own instead.
    # dx100.local (a real DX100) is the emulator here, as the README's first line serves it; cell-pc (the
    # cell's machine, named in the certificates) is this machine, whose name `security init` always adds
    shell = Shell(tmp_path, private_env(Endpoint("readme-motoros")), {
        "--motoros 127.0.0.1": f"--motoros 127.0.0.1:{plain_port}",
        "--motoros dx100.local:50240": f"--motoros 127.0.0.1:{plain_port}",
        "--motoros 0.0.0.0": f"--motoros 0.0.0.0:{secured_port}",
        "--motoros cell-pc": f"--motoros {socket.gethostname()}:{secured_port}",
        "DIR/": f"{tmp_path / 'security'}/"})
    secured_from = next(i for i, line in enumerate(lines) if "--security" in line)
    assert lines[0].startswith("foldcell controller serve --motoros") and lines[0].endswith("&"), lines
    try:
        for line in lines[:secured_from]:
            if line.startswith("foldcell controller watch"):   # a stream until Ctrl-C: its first lines
                watch = subprocess.Popen(shlex.split(shell.expand(line)), cwd=tmp_path, env=shell.env,
                                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                assert watch.stdout is not None
                seen = [watch.stdout.readline() for _ in range(3)]
                stop([watch])
                # the state port: the status, then a joint position line per state burst (13 joints)
                assert seen[0].startswith("t=") and "drives_powered" in seen[0], seen
                joints = re.compile(r"t=\d+\.\d{3}( [+-]\d+\.\d{4}){13}\n")
                assert all(joints.fullmatch(row) for row in seen[1:]), seen
                continue
            results = shell.line(line)
            if line.endswith("&"):   # the emulator is up once its MotoROS answers
                assert shell.says("MotoROS (upstream) on 127.0.0.1"), shell.logs()
            for done in results:
                assert done.returncode == 0, f"{line}: {done.stderr}"
            if "status" in line and "--json" in line:
                status = json.loads(results[0].stdout)
                assert status["ok"] and [g["name"] for g in status["status"]["groups"]] == ["R1", "R2", "B1"]
        shell.stop_all()
        # off this machine, secured: a CA first (README: A locked-down cell)
        init = shell.run(f"foldcell security init {tmp_path / 'security'}")
        assert init.returncode == 0, init.stderr
        for line in lines[secured_from:]:
            results = shell.line(line)
            if line.startswith("foldcell router"):
                assert shell.says("router serving"), shell.logs()
            elif line.endswith("&"):
                assert shell.says("over TLS for cell, operator"), shell.logs()
            for done in results:
                assert done.returncode == 0, f"{line}: {done.stderr}"
                assert re.match(r"t=\d+\.\d{3} \[", done.stdout), done.stdout
    finally:
        shell.stop_all()


class Cell:
    """The module's live cell: its wire, folder and shell; `session` the bag `foldcell log record` makes of
    it while it folds a towel."""

    def __init__(self, ep: Endpoint, folder: Path):
        self.ep, self.folder = ep, folder
        self.shell = Shell(folder, private_env(ep))
        self.session = folder / "session"
        self.recorder: subprocess.Popen | None = None
        self.recording_since = 0.0


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    """A cell as "Running the processes yourself" starts it (one controller process, the geometric world and
    10x robot time: a towel folded in seconds, little CPU), its session recorded, folding a towel."""
    live = Cell(Endpoint("readme-cell"), tmp_path_factory.mktemp("cell"))
    shell = live.shell
    try:
        for command in ("foldcell controller serve --role both --time-scale 10",
                        "foldcell camera serve --source sim --garment towel --seed 3 --folding geometric",
                        "foldcell run"):
            shell.start(command)
        wanted = {"controller", "camera", "cell"}
        assert wait_until(lambda: alive_processes(shell, live.ep.cell) >= wanted, 120, 1.0), shell.logs()
        live.recorder, _ = shell.start("foldcell log record -o session")
        assert wait_until(lambda: (live.session / "metadata.yaml").exists(), 60), shell.logs()
        live.recording_since = time.monotonic()
        fold = shell.run("foldcell topic call cell/command '{command: fold, argument: towel}'", 60)
        assert fold.returncode == 0 and "accepted: true" in fold.stdout, (fold.stdout, fold.stderr)
        yield live
    finally:
        shell.stop_all()


@pytest.fixture(scope="module")
def session(cell: Cell) -> Path:
    """The cell's recorded session once the towel is done: some 16 s of it (the README's replay block
    starts one at 12.5 s), every file complete."""
    def done() -> bool:
        state = snapshot(cell.shell, heard=False)["cells"].get(cell.ep.cell, {}).get("state")
        return state is not None and state["state"] == "done"

    assert wait_until(done, 180, 1.0), cell.shell.logs()
    time.sleep(max(0.0, 16 - (time.monotonic() - cell.recording_since)))
    assert cell.recorder is not None
    stop([cell.recorder])
    assert cell.recorder.returncode == 0, cell.shell.logs()
    return cell.session


def screen_until(master: int, process: subprocess.Popen, wanted: list[str], timeout: float = 60) -> str:
    """What a terminal showed until every text in `wanted` appeared (or `timeout`, or the process ended)."""
    import select
    shown = b""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and process.poll() is None:
        text = shown.decode(errors="replace")
        if all(w in text for w in wanted):
            break
        if select.select([master], [], [], 0.2)[0]:
            try:
                shown += os.read(master, 65536)
            except OSError:
                break
    return shown.decode(errors="replace")


def on_a_terminal(shell: Shell, line: str, cell: str, monkeypatch: pytest.MonkeyPatch) -> str:
    """`line` (a monitor) run in a terminal on the shell's wire, as a user runs it: what it showed once
    `cell`'s processes were on screen; then q quits it."""
    from tests.conftest import on_terminal
    for variable in ("FOLDCELL_CELL", "FOLDCELL_LISTEN", "FOLDCELL_CONNECT", "PATH"):
        monkeypatch.setenv(variable, shell.env[variable])
    with on_terminal(shlex.split(line)) as (process, master):
        shown = screen_until(master, process, [f"cell {cell}", "processes "])
        assert f"cell {cell}" in shown and "processes " in shown, shown
        os.write(master, b"q")
        assert process.wait(30) == 0, shown
    return shown


@pytest.mark.timeout(300)
def test_watch_cells_live_as_the_readme_says(cell: Cell, monkeypatch: pytest.MonkeyPatch) -> None:
    """README "Watch cells live": the dashboard in a terminal (q quits), every cell's, the one JSON
    snapshot with the keys the README lists, the JSON stream, and a monitor recording what it watches."""
    lines = code_lines("### Watch cells live: `foldcell monitor`")
    assert lines == ["foldcell monitor", "foldcell monitor --cell '*'", "foldcell monitor --once --json",
                     "foldcell monitor --json", "foldcell monitor --record watch"], lines
    shell, name = cell.shell, cell.ep.cell
    for line in lines[:2]:   # in a terminal, as a user runs them: the cell at work, then q
        shown = on_a_terminal(shell, line, name, monkeypatch)
        assert f"watching {name if '--cell' not in line else '*'}" in shown, shown
    once = shell.run(lines[2], 60)
    assert once.returncode == 0, once.stderr
    readme_shape = json_shape(readme_span_after("JSON snapshot: "))
    state = json.loads(once.stdout)
    assert not shape_mismatches(state, readme_shape), shape_mismatches(state, readme_shape)
    assert state["cells"][name]["alive"] and state["cells"][name]["state"]["garment"] == "towel", state
    stream = subprocess.Popen(shlex.split(lines[3]), cwd=cell.folder, env=shell.env, stdout=subprocess.PIPE,
                              stderr=subprocess.DEVNULL, text=True)
    try:   # one snapshot a line, each of the same shape
        assert stream.stdout is not None
        rows = [json.loads(stream.stdout.readline()) for _ in range(2)]
    finally:
        stop([stream])
    assert all(not shape_mismatches(row, readme_shape) and row["watching"] == name for row in rows), rows
    recording, _ = shell.start(lines[4])   # records until Ctrl-C: the bag watch/ in the folder it runs in
    assert wait_until(lambda: (cell.folder / "watch" / "watch_0.mcap").exists(), 60), shell.logs()
    time.sleep(2)
    stop([recording])
    assert recording.returncode in (0, 130), shell.logs()
    info = shell.run("foldcell log info watch", 60)
    assert info.returncode == 0 and f"/foldcell/{name}/controller/joint_states" in info.stdout, info


@pytest.mark.timeout(300)
def test_replay_a_logged_session_as_the_readme_says(cell: Cell, session: Path) -> None:
    """README "Replay a logged session": every line on the cell's recorded session, all at once (each
    paces itself by the session's clock), into the replay cells the README names, which the monitor
    shows as replays; then the --perceive block, its JSON of the shape its comment gives."""
    lines = code_lines("### Replay a logged session: `foldcell replay`")
    assert lines[0] == "foldcell replay runs/cell1-20260101T101010Z", lines
    assert all(line.startswith("foldcell replay SESSION") for line in lines[1:]), lines
    # runs/cell1-20260101T101010Z and SESSION: the session the cell recorded (`foldcell log record`)
    shell = Shell(cell.folder, cell.shell.env, {"runs/cell1-20260101T101010Z": session.name,
                                                 "SESSION": session.name})
    replays = [subprocess.Popen(shlex.split(shell.expand(line)), cwd=cell.folder, env=shell.env,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for line in lines]
    try:
        into = {f"{cell.ep.cell}-replay": replays[0], "test-replay": replays[1]}
        for replay_cell in into:   # `foldcell monitor` shows such a cell as a replay
            def replaying(replay_cell: str = replay_cell) -> bool:
                cells = snapshot(shell, "--cell", replay_cell, heard=False)["cells"]
                return replay_cell in cells and cells[replay_cell]["replay"]
            assert wait_until(replaying, 60, 0.5), replay_cell
        looping = replays[lines.index("foldcell replay SESSION --loop")]
        for line, replay in zip(lines, replays, strict=True):
            if replay is not looping:
                _, err = replay.communicate(timeout=120)
                assert replay.returncode == 0, f"{line}: {err}"
                assert re.search(r"^replayed [1-9]\d* samples \(\d+ skipped\) from session$", err, re.M), \
                    (line, err)
        assert looping.poll() is None, "--loop replays again and again, until Ctrl-C"
    finally:
        stop(replays)
    assert looping.returncode in (0, 130), looping.stderr.read() if looping.stderr else ""
    perceive = code_lines("#### Check a change to perception against real sessions: `--perceive`")
    assert perceive == ["foldcell replay SESSION --perceive", "foldcell replay SESSION --perceive --json"]
    text = shell.run(shell.expand(perceive[0]), 120)
    assert text.returncode == 0, text.stderr
    # per image: its time, topic, stamp and categories, then a line per landmark: logged, new, difference
    image = r"^ +\d+\.\d{3} s  /foldcell/\S+/camera/image  stamp \d+  logged towel  new towel"
    landmark = r"^    \S+ +logged +[\d.]+ +[\d.]+   new +[\d.]+ +[\d.]+   diff +[\d.]+ px$"
    assert re.search(image, text.stdout, re.M) and re.search(landmark, text.stdout, re.M), text.stdout
    done = shell.run(shell.expand(perceive[1]), 120)
    assert done.returncode == 0, done.stderr
    comment = next(line for line in README.splitlines() if line.startswith(perceive[1] + " "))
    shape = json_shape(comment[comment.index("{"):])
    result = json.loads(done.stdout)
    assert result["images"] and not shape_mismatches(result, shape), shape_mismatches(result, shape)


def foxglove_channels(port: int, subprotocol: str, wanted: set[str]) -> set[str]:
    """The topics a Foxglove client asking for `subprotocol` is advertised, once `wanted` are among them."""
    from tests.sessions.test_foxglove_bridge import WsClient
    client = WsClient(port, subprotocol)
    try:
        assert client.granted == subprotocol
        topics: set[str] = set()
        deadline = time.monotonic() + 30
        while not wanted <= topics and time.monotonic() < deadline:
            opcode, data = client.frame()
            if opcode == 1 and json.loads(data).get("op") == "advertise":
                topics |= {channel["topic"] for channel in json.loads(data)["channels"]}
        return topics
    finally:
        client.close()


@pytest.mark.timeout(300)
def test_foxglove_as_the_readme_says(cell: Cell, session: Path) -> None:
    """README "Foxglove": the bridge of the default cell and of another on all addresses, each serving a
    Foxglove client (either subprotocol) the cell's topics and the three it adds; the export of a session
    beside it with those three; the layout for a cell."""
    live = code_lines("### Foxglove")
    assert live[0] == "foldcell foxglove" and len(live) == 2, live
    export_lines = code_lines("**A recorded session.**")
    assert export_lines == ["foldcell foxglove --export runs/cell1-20260101T101010Z"], export_lines
    layout = "foldcell foxglove --layout --cell ID > layout.json"   # in the text of "The layout"
    assert f"`{layout}`" in README
    name = cell.ep.cell
    # the Foxglove ports (8765 by default, 8766) may be another user's on this machine: each line gets a
    # free one instead (the first line, on the default port, by --port); the layout's ID: the test's cell
    shell = Shell(cell.folder, cell.shell.env,
                  {" ID ": f" {name} ", "runs/cell1-20260101T101010Z": session.name})
    bridges, urls = [], []
    for line in live:
        port = free_ports(1)
        command = (re.sub(r"--port \d+", f"--port {port}", line) if "--port" in line
                   else f"{line} --port {port}")
        host = re.search(r"--host (\S+)", line)
        where = f"ws://{host.group(1) if host else '127.0.0.1'}:{port}"
        urls.append((port, f"to Foxglove at {where} (Ctrl-C to stop)", re.search(r"--cell (\S+)", line)))
        bridges.append(shell.start(command))
    try:
        for (_, log), (_, url, _) in zip(bridges, urls, strict=True):   # each says where it serves
            assert shell.says(url) and url in log.read_text(), shell.logs()
        added = {"/robot_description", "/tf"}
        ours = {f"/foldcell/{name}/controller/joint_states", f"/foldcell/{name}/cell/state"}
        for port, _, other_cell in urls:   # another cell (cell2) has nobody here: the bridge's own topics
            wanted = added if other_cell else ours | added
            for subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1"):
                assert wanted <= foxglove_channels(port, subprotocol, wanted), (port, subprotocol)
    finally:
        stop([process for process, _ in bridges])
    assert all(process.returncode in (0, 130) for process, _ in bridges), shell.logs()
    done = shell.line(export_lines[0])[0]
    assert done.returncode == 0, done.stderr
    exported = session.with_name(session.name + ".foxglove.mcap")   # beside the bag, as the README says
    from mcap.reader import make_reader
    with open(exported, "rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    topics = {channel.topic for channel in summary.channels.values()}
    assert {"/robot_description", "/tf", f"/foldcell/{name}/foxglove/observation_annotations",
            f"/foldcell/{name}/camera/image"} <= topics, topics
    done = shell.line(shell.expand(layout))[0]
    assert done.returncode == 0, done.stderr
    assert f"/foldcell/{name}/camera/image" in (cell.folder / "layout.json").read_text()
    json.loads((cell.folder / "layout.json").read_text())


@pytest.mark.timeout(120)
def test_the_rosbags_reading_of_a_session_as_the_readme_shows(session: Path) -> None:
    """README "Bags, time and Foxglove": the session read with rosbags' AnyReader by the venv's python
    prints connections, messages and seconds in the shape shown."""
    block = block_after("**Bags, time and Foxglove.**")
    at = next(i for i, line in enumerate(block) if line.startswith("$ "))
    command = block[at].removeprefix("$ ")
    while True:   # the command's lines, until its quotes close
        try:
            argv = shlex.split(command)
            break
        except ValueError:
            at += 1
            command += "\n" + block[at]
    shown = block[at + 1:]
    assert argv[0] == ".venv/bin/python", argv   # the repository's venv, as the README runs it
    # the README's demo session: the test cell's
    argv = [str(REPO / argv[0]), *[arg.replace("runs/demo-20261203T111253Z/session", str(session))
                                   for arg in argv[1:]]]
    assert str(session) in argv[-1], argv
    done = subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    assert len(shown) == 1 and shape_of(shown[0]).fullmatch(done.stdout.strip()), (shown, done.stdout)
