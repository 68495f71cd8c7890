"""The `foldcell` command itself: its version, `-v` on either side of a subcommand, and a reader that goes
away (`| head`) ending it quietly."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader

from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.conftest import REPO, Endpoint, foldcell_argv, wait_until
from tests.sessions.test_mcap_fixtures import write_session
from tools.cli import build_parser, main


@pytest.mark.parametrize("argv", [[], ["controller", "serve"], ["topic", "echo"], ["security", "init"]])
def test_version_is_the_package_version_before_or_after_any_subcommand(
        capsys: pytest.CaptureFixture[str], argv: list[str]) -> None:
    declared = re.search(r'^version = "([^"]+)"', (REPO / "pyproject.toml").read_text(), re.M)
    assert declared is not None
    with pytest.raises(SystemExit) as done:
        main([*argv, "--version"])
    assert done.value.code == 0
    assert capsys.readouterr().out.strip() == f"foldcell {declared.group(1)}"


@pytest.mark.parametrize("argv, count", [
    (["-v", "log", "info", "x.mcap"], 1),
    (["log", "info", "-v", "x.mcap"], 1),
    (["log", "info", "x.mcap", "-vv"], 2),
    (["controller", "status", "-v"], 1),
    (["log", "info", "x.mcap"], 0),
])
def test_verbose_goes_before_or_after_the_subcommand(argv: list[str], count: int) -> None:
    assert build_parser().parse_args(argv).verbose == count


@pytest.mark.parametrize("argv", [["topic", "list", "--registry"], ["topic", "list", "--registry", "--json"]])
def test_a_reader_that_goes_away_ends_the_command_quietly(argv: list[str]) -> None:
    proc = subprocess.Popen(foldcell_argv(*argv), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout is not None
    proc.stdout.close()   # like `| head`, gone before the output comes
    _, err = proc.communicate(timeout=60)
    assert b"Traceback" not in err and b"BrokenPipe" not in err, err.decode()
    assert proc.returncode == 141, (proc.returncode, err.decode())   # 128 + SIGPIPE, as a shell reports it


def test_a_monitor_snapshot_of_no_cell_fails_and_says_so() -> None:
    ep = Endpoint()
    argv = foldcell_argv("monitor", "--once", "--cell", "nobody", "--duration", "0.5", "--json",
                         "--listen", ep.url, "--connect", ep.url)
    done = subprocess.run(argv,
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert done.returncode == 1, done
    assert json.loads(done.stdout)["cells"] == {}
    assert "no cell 'nobody'" in done.stderr


def test_eval_of_a_folder_without_images_is_an_error(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", str(tmp_path)]) == 2
    assert f"{tmp_path}: no annotated images" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [["security", "show"], ["dataset", "sheet", "-o", "sheet.png"]],
                         ids=["security show", "dataset sheet"])
def test_a_missing_directory_is_named_as_missing(tmp_path, capsys: pytest.CaptureFixture[str],
                                                 argv: list[str]) -> None:
    missing = tmp_path / "nope"
    assert main([*argv[:2], str(missing), *argv[2:]]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"foldcell: error: DIR: {missing} is not a directory"), line


def test_exporting_a_log_without_a_message_fails(tmp_path, capsys: pytest.CaptureFixture[str]) -> None:
    whole = tmp_path / "whole.mcap"
    write_session(whole, 200, chunk_size=1 << 20)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole.read_bytes()[:600])   # the header and the start of the only chunk
    assert main(["foxglove", "--export", str(cut), "-o", str(tmp_path / "out.mcap")]) == 1
    assert "holds no readable message" in capsys.readouterr().err


def test_pub_and_record_report_what_they_did_as_json(tmp_path) -> None:
    ep = Endpoint()
    path = tmp_path / "s.mcap"
    recorder = subprocess.Popen(foldcell_argv("log", "record", "-o", str(path), "--duration", "20", "--json",
                                              *ep.args()), cwd=REPO, stdout=subprocess.PIPE, text=True)
    line = "{level: 20, name: t, msg: hi}"
    pub = subprocess.run(foldcell_argv("topic", "pub", "cell/log", line, "-r", "50", "-n", "20",
                                       "--wait", "15", "--json", *ep.args()),
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert pub.returncode == 0, pub.stderr
    published = json.loads(pub.stdout)
    assert published == {"key": f"foldcell/{ep.cell}/cell/log", "published": 20, "subscribed": True}
    recorder.send_signal(signal.SIGINT)
    out, _ = recorder.communicate(timeout=60)
    recorded = json.loads(out)
    assert recorded["bag"] == str(tmp_path / "s") and recorded["rejected"] == 0
    assert recorded["files"] == [str(tmp_path / "s" / "s_0.mcap")]
    with open(recorded["files"][0], "rb") as f:
        topics = [channel.topic for _, channel, _ in make_reader(f).iter_messages()]
    logged = sum(1 for topic in topics if topic.endswith("cell/log"))
    assert logged == 20 and recorded["recorded"] == len(topics)


def test_a_capture_with_no_camera_says_so_in_one_line_and_writes_nothing(tmp_path) -> None:
    ep = Endpoint("nocamera")
    out = tmp_path / "x.png"
    result = subprocess.run(foldcell_argv("camera", "capture", "-o", str(out), "--timeout", "2", *ep.args()),
                            cwd=REPO, capture_output=True, text=True, timeout=60)
    assert result.returncode == 1, result
    assert result.stderr.startswith("foldcell: error: no image:") and "camera/capture" in result.stderr, \
        result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not out.exists()


def test_monitor_once_prints_one_snapshot_with_no_key_hints() -> None:
    ep = Endpoint("nomonitor")
    result = subprocess.run(foldcell_argv("monitor", "--once", "--duration", "0.2", *ep.args()), cwd=REPO,
                            capture_output=True, text=True, timeout=60)
    assert result.stdout.startswith(f"foldcell monitor - watching {ep.cell}"), result
    assert "quits" not in result.stdout, result.stdout
    assert result.returncode == 1 and "no cell" in result.stderr, result   # nothing heard: says so


def test_monitor_once_waits_for_the_cell_s_state() -> None:
    """A cell telling its state at 2 Hz, as the daemon does, first heard only after 1.5 s (a loaded
    machine, a slow link): `monitor --once` waits for it rather than print an empty snapshot."""
    ep = Endpoint("oncestate")
    stop = threading.Event()
    with Wire(ep.settings(), "cell") as wire:
        state = wire.publisher("cell/state")

        def tell() -> None:
            stop.wait(1.0)
            while not stop.wait(0.5):
                state.put(messages.new("foldcell_msgs/msg/CellState", header=messages.header(),
                                       state="folding", garment="towel"))
        teller = threading.Thread(target=tell, daemon=True)
        teller.start()
        try:
            result = subprocess.run(foldcell_argv("monitor", "--once", "--json", *ep.args()), cwd=REPO,
                                    capture_output=True, text=True, timeout=60)
        finally:
            stop.set()
            teller.join()
    assert result.returncode == 0, result
    snap = json.loads(result.stdout)
    assert snap["cells"][ep.cell]["state"]["state"] == "folding", snap["cells"]


# (command, flag): every duration, timeout and offset on the command line
SECONDS_FLAGS = [
    (["camera", "capture"], "--timeout"),
    (["controller", "home"], "--timeout"),
    (["log", "record"], "--duration"),
    (["monitor", "--once"], "--duration"),
    (["topic", "list"], "--duration"),
    (["topic", "echo", "controller/status"], "--timeout"),
    (["topic", "hz", "controller/status"], "--duration"),
    (["topic", "pub", "controller/joint_states"], "--wait"),
    (["topic", "call", "controller/command"], "--timeout"),
    (["replay", "session.mcap"], "--start"),
    (["replay", "session.mcap"], "--end"),
    (["demo"], "--time-scale"),
]


@pytest.mark.parametrize("value", ["nan", "inf", "-5"])
@pytest.mark.parametrize("command, flag", SECONDS_FLAGS, ids=[" ".join([*c, f]) for c, f in SECONDS_FLAGS])
def test_a_duration_that_is_not_a_finite_positive_number_is_refused_by_its_flag(
        capsys: pytest.CaptureFixture[str], command: list[str], flag: str, value: str) -> None:
    """Refused before anything starts, in one line naming the flag: NaN passes every `<= 0` check and
    once reached a sleep ("Invalid value NaN") or a monitor that never ended."""
    assert main([*command, flag, value, "--connect", "tcp/127.0.0.1:9"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"foldcell: error: {flag}: must be "), line
    assert value in line, line


def test_a_negative_seed_is_refused_by_its_flag(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["plan", "check", "--seed", "-5"]) == 2
    assert capsys.readouterr().err.strip() == "foldcell: error: --seed must be >= 0, got -5"


EMPTY_ARGUMENTS = [
    (["monitor", "--record", ""], "argument -o/--output/--record: an empty path names no file"),
    (["run", "--job", ""], "argument --job: an empty path names no file"),
    (["log", "record", "-o", ""], "argument -o/--output: an empty path names no file"),
    (["security", "init", ""], "argument DIR: an empty path names no file"),
    (["camera", "capture", "-o", ""], "argument -o/--output: an empty path names no file"),
    (["topic", "list", "--cell", ""], "argument --cell: an empty cell id names no cell"),
    (["dataset", "sheet", "DIR", "-o", ""], "argument -o/--output: an empty path names no file"),
    (["log", "recover", "x.mcap", "-o", ""], "argument -o/--output: an empty path names no file"),
    (["perceive", "photo.png", "--table-model", ""], "argument --table-model: an empty path names no file"),
]


@pytest.mark.parametrize("argv, message", EMPTY_ARGUMENTS, ids=[" ".join(a) for a, _ in EMPTY_ARGUMENTS])
def test_an_empty_path_or_cell_is_refused_by_its_flag(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                                       monkeypatch: pytest.MonkeyPatch, argv: list[str],
                                                       message: str) -> None:
    """An empty path was taken as `.` (`monitor --record ""` replaced a session recorded in the current
    directory), an empty cell as none given: refused before anything starts, nothing written."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exited:
        main(argv)
    assert exited.value.code == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_service_given_json_logs_json_lines_and_says_ready_as_one(spawn, endpoint: Endpoint) -> None:
    """`router --json`: every line on stderr is one JSON object: the ready line naming what it listens
    on, and its log lines (here the warning an open process listening beyond this machine gives)."""
    wide = f"tcp/0.0.0.0:{endpoint.port}"
    router = spawn(foldcell_argv("router", "--listen", wide, "--connect", endpoint.url, "--json", "-v"))

    def ready() -> dict | None:
        for line in router.stderr().splitlines():
            entry = json.loads(line)
            if entry.get("event") == "ready":
                return entry
        return None

    assert wait_until(lambda: ready() is not None, 60), router.stderr()
    entry = ready()
    assert entry is not None and entry["listen"][0] == wide and entry["level"] == "INFO"
    assert router.stop() == 0
    entries = [json.loads(line) for line in router.stderr().splitlines()]
    assert all({"time", "level", "logger", "message"} <= entry.keys() for entry in entries), entries
    assert any(entry["level"] == "WARNING" and wide in entry["message"] for entry in entries), entries


@pytest.mark.parametrize(("argv", "dest"), [
    (["dataset", "generate", "--count", "1", "-o", "OUT"], "out_dir"),
    (["perceive", "photo.png", "-o", "OUT"], "overlay"),
    (["run", "-o", "OUT"], "record"),
    (["monitor", "-o", "OUT"], "record"),
    (["log", "record", "-o", "OUT"], "output"),
    (["demo", "-o", "OUT"], "output"),
    (["camera", "capture", "-o", "OUT"], "output"),
])
def test_o_is_what_every_command_writes(argv: list[str], dest: str) -> None:
    """-o/--output names the thing written, whatever the command (README: The command line)."""
    assert getattr(build_parser().parse_args(argv), dest) == Path("OUT")
    long = [("--output" if a == "-o" else a) for a in argv]
    assert getattr(build_parser().parse_args(long), dest) == Path("OUT")


def test_a_dataset_folder_given_twice_or_not_at_all_is_refused(tmp_path: Path, capsys) -> None:
    assert main(["dataset", "generate", "--count", "1", "-o", str(tmp_path / "a"), str(tmp_path / "b")]) == 2
    assert "given twice" in capsys.readouterr().err
    assert main(["dataset", "generate", "--count", "1"]) == 2
    assert "-o/--output: the folder to write into is missing" in capsys.readouterr().err
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
