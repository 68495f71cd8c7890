"""`foldcell replay` as a real process on loopback Zenoh, against a session recorded here.

The session: `tests.nodes.fake_cell` (a fake cell: state changes, 250 Hz joints, status, log, one
image with its observation) recorded by `foldcell log record`.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader

from drivers.sessions.mcap.bag import find_session
from drivers.sessions.mcap.reader import iter_messages
from drivers.sessions.mcap.recover import recover
from drivers.sessions.monitor.live import MonitorSession
from drivers.sessions.replay import open_session
from drivers.wire.transport import RawSample, Wire
from tests.conftest import DEMO_TIMEOUT_S, REPO, Endpoint, foldcell_argv, wait_until
from tests.nodes.fake_cell import STATES

CELL = "rec"


def run(argv: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=REPO, capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def session_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One fake session, recorded once for the module."""
    tmp = tmp_path_factory.mktemp("session")
    path = tmp / "session.mcap"
    ep = Endpoint(CELL)
    rec = subprocess.Popen(
        foldcell_argv("log", "record", "-o", str(path), *ep.args()),
        cwd=REPO,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        node = run(
            [
                sys.executable,
                "-m",
                "tests.nodes.fake_cell",
                *ep.args(),
                "--state-period",
                "0.15",
                "--image",
                "--wait",
                "5",
            ]
        )
        assert node.returncode == 0, node.stderr
        assert "done" in node.stdout
    finally:
        rec.send_signal(2)
        rec.wait(20)
    assert len(find_session(path).files) == 1  # the bag session/, named by session.mcap
    return path


def logged(path: Path, **kw) -> list[tuple[str, bytes]]:
    return [(m.topic.lstrip("/"), m.data) for m in iter_messages(path, **kw)]


class Collector:
    """Every sample of a cell, in arrival order (one subscription, so one ordered lane)."""

    def __init__(self, ep: Endpoint, cell: str):
        self.wire = Wire(ep.settings("observer"), "collector")
        self.samples: list[RawSample] = []
        self.lock = threading.Lock()
        self.wire.subscribe_raw(f"foldcell/{cell}/**", self._on)

    def _on(self, raw: RawSample) -> None:
        with self.lock:
            self.samples.append(raw)

    def pairs(self, cell_from: str, cell_to: str) -> list[tuple[str, bytes]]:
        with self.lock:
            return [
                (s.key.replace(f"foldcell/{cell_from}/", f"foldcell/{cell_to}/"), s.payload)
                for s in self.samples
            ]

    def close(self) -> None:
        self.wire.close()


def wait_for_monitor(ep: Endpoint, cell: str) -> None:
    """Until a monitor's subscriptions on `cell` are in place (a probe publisher matches one)."""
    with Wire(ep.settings(cell), "probe") as probe:
        assert probe.publisher("cell/state").wait_for_subscribers(20), "the monitor did not subscribe"


def replay(path: Path, ep: Endpoint, cell: str, *extra: str) -> subprocess.CompletedProcess:
    result = run(foldcell_argv("replay", str(path), *ep.args(cell), "--json", *extra))
    assert result.returncode == 0, result.stderr
    return result


def test_replay_at_5x_shows_the_same_cell_states_in_the_monitor(session_file: Path) -> None:
    ep = Endpoint()
    with MonitorSession(ep.settings("watcher"), "five", "monitor-test") as monitor:
        wait_for_monitor(ep, "five")
        replay(session_file, ep, "five", "--rate", "5")
        states = lambda: monitor.snapshot()["cells"].get("five", {}).get("states_seen")  # noqa: E731
        assert wait_until(lambda: states() == list(STATES), 30), states()
        cell = monitor.snapshot()["cells"]["five"]
    assert [t["dest"] for t in cell["state"]["history"]] == list(STATES[1:])
    assert cell["topics"]["controller/joint_states"]["count"] > 0
    assert cell["controller"]["lease_holder"] == "cell"


def test_replay_keeps_the_order_of_samples_across_topics(session_file: Path) -> None:
    ep = Endpoint()
    collector = Collector(ep, "order")
    try:
        replay(session_file, ep, "order", "--rate", "2")
        expected = logged(session_file)
        assert wait_until(lambda: len(collector.samples) >= len(expected), 10)
        got = collector.pairs("order", CELL)
    finally:
        collector.close()
    assert got == [(k, d) for k, d in expected]
    assert len({k for k, _ in got}) >= 5  # several topics interleaved


def test_replay_carries_the_original_sender_stamp(session_file: Path) -> None:
    ep = Endpoint()
    collector = Collector(ep, "stamp")
    try:
        replay(session_file, ep, "stamp", "--rate", "max", "--topics", "cell/state")
        expected = [
            m.publish_time_ns for m in iter_messages(session_file, topics=[f"/foldcell/{CELL}/cell/state"])
        ]
        assert wait_until(lambda: len(collector.samples) >= len(expected), 10)
    finally:
        collector.close()
    assert [s.stamp_ns for s in collector.samples] == expected


def test_topics_and_window_select_exactly_what_they_say(session_file: Path) -> None:
    session = open_session(session_file)
    start_s, end_s = 0.3, 0.9
    lo, hi = session.start_ns + int(start_s * 1e9), session.start_ns + int(end_s * 1e9)
    wanted = [f"/foldcell/{CELL}/cell/state", f"/foldcell/{CELL}/cell/log"]
    expected = logged(session_file, topics=wanted, start_ns=lo, end_ns=hi)
    assert 2 <= len(expected) < len(logged(session_file, topics=wanted))
    ep = Endpoint()
    collector = Collector(ep, "sel")
    try:
        result = replay(
            session_file,
            ep,
            "sel",
            "--rate",
            "max",
            "--topics",
            "cell/*",
            "--start",
            str(start_s),
            "--end",
            str(end_s),
        )
        assert json.loads(result.stdout)["published"] == len(expected)
        assert wait_until(lambda: len(collector.samples) >= len(expected), 10)
        collector.wire.close()
        got = collector.pairs("sel", CELL)
    finally:
        collector.close()
    assert got == expected


def test_exclusion_glob_leaves_out_a_topic(session_file: Path) -> None:
    ep = Endpoint()
    collector = Collector(ep, "excl")
    try:
        result = replay(session_file, ep, "excl", "--rate", "max", "--topics", "!controller/*")
        expected = [p for p in logged(session_file) if "/controller/" not in p[0]]
        assert json.loads(result.stdout)["published"] == len(expected)
        assert wait_until(lambda: len(collector.samples) >= len(expected), 10)
        got = collector.pairs("excl", CELL)
    finally:
        collector.close()
    assert got == expected


def test_a_file_cut_by_a_crash_replays_up_to_its_last_complete_chunk(
    session_file: Path, tmp_path: Path
) -> None:
    cut = tmp_path / "cut.mcap"
    (recorded,) = find_session(session_file).files
    data = recorded.read_bytes()
    with open(recorded, "rb") as f:
        chunks = make_reader(f).get_summary().chunk_indexes
    assert len(chunks) >= 2
    # a crash while writing the last chunk: everything before it is complete
    last = chunks[-1]
    cut.write_bytes(data[: last.chunk_start_offset + last.chunk_length // 2])
    reference = tmp_path / "reference.mcap"
    report = recover(cut, reference)
    expected = logged(reference)
    assert 0 < len(expected) < len(logged(session_file))
    ep = Endpoint()
    collector = Collector(ep, "cut")
    try:
        result = replay(cut, ep, "cut", "--rate", "max")
        summary = json.loads(result.stdout)
        assert summary["recovered"] is True and summary["published"] == report.messages_kept
        assert wait_until(lambda: len(collector.samples) >= len(expected), 10)
        got = collector.pairs("cut", CELL)
    finally:
        collector.close()
    assert got == expected
    assert "cut short" in result.stderr


def test_bad_arguments_exit_2_with_a_message(session_file: Path, tmp_path: Path) -> None:
    for args, words in (
        (["--rate", "fast"], "--rate"),
        (["--start", "2", "--end", "1"], "--end"),
        (["--topics", "!"], "--topics"),
    ):
        r = run(foldcell_argv("replay", str(session_file), *args))
        assert r.returncode == 2 and r.stderr.startswith("foldcell: error:") and words in r.stderr, r.stderr
    r = run(foldcell_argv("replay", str(tmp_path / "missing.mcap")))
    assert r.returncode == 2 and "no such file" in r.stderr
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    r = run(foldcell_argv("replay", str(junk)))
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr


def test_perceive_compares_logged_and_new_landmarks(session_file: Path) -> None:
    r = run(foldcell_argv("replay", str(session_file), "--perceive", "--json"), timeout=120)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert len(doc["images"]) == 1
    image = doc["images"][0]
    assert image["error"] is None
    assert image["logged_category"] == "towel" and image["new_category"] == "towel"
    assert (
        set(image["logged"]) == set(image["new"]) == {"bottom-left", "bottom-right", "top-right", "top-left"}
    )
    # the node logged the true corners shifted by 3 px in x: perception finds the true ones again
    for name, diff in image["difference_px"].items():
        assert 1.0 <= diff <= 12.0, (name, diff)
    text = run(foldcell_argv("replay", str(session_file), "--perceive"), timeout=120)
    assert text.returncode == 0 and "top-left" in text.stdout and "diff" in text.stdout


@pytest.mark.timeout(DEMO_TIMEOUT_S + 60)
def test_demo_session_replayed_at_5x_shows_the_same_states(tmp_path: Path) -> None:
    ep = Endpoint("demo")
    out_dir = tmp_path / "demo"
    lines = tmp_path / "live.jsonl"
    with open(lines, "w") as out:  # JSON lines at the refresh rate: a file, not a pipe that fills up
        live = subprocess.Popen(
            foldcell_argv("monitor", "--json", *ep.args()), cwd=REPO, stdout=out, stderr=subprocess.DEVNULL
        )
        try:
            demo = run(
                foldcell_argv("demo", "--garment", "towel", "-o", str(out_dir), "--folding", "geometric",
                              *ep.args()),
                timeout=DEMO_TIMEOUT_S,
            )
        finally:
            live.send_signal(2)
            live.wait(20)
    # the demo's own session log; a fold that fails still makes a session to compare
    logs = sorted(out_dir.rglob("*.mcap"))
    assert logs, f"the demo wrote no session log: {demo.stderr}"
    live_states = _states_from_json_lines(lines.read_text(), "demo")
    assert len(live_states) >= 2, demo.stderr
    with MonitorSession(ep.settings("watcher"), "demo5", "monitor-test") as monitor:
        wait_for_monitor(ep, "demo5")
        replay(logs[0], ep, "demo5", "--rate", "5", "--topics", "cell/*")
        states = lambda: monitor.snapshot()["cells"].get("demo5", {}).get("states_seen")  # noqa: E731
        assert wait_until(lambda: states() == live_states, 30), (states(), live_states)


def _states_from_json_lines(text: str, cell: str) -> list[str]:
    last: list[str] = []
    for line in text.splitlines():
        if line.strip():
            last = json.loads(line)["cells"].get(cell, {}).get("states_seen", last)
    return last


def test_a_selection_that_keeps_nothing_exits_1_and_says_why(session_file: Path) -> None:
    ep = Endpoint()
    result = run(foldcell_argv("replay", str(session_file), *ep.args("none"), "--json", "--rate", "max",
                               "--topics", "nothing/at/all"))
    assert result.returncode == 1, result
    assert json.loads(result.stdout)["published"] == 0
    assert "nothing was replayed" in result.stderr


def test_replay_refuses_a_live_cell_and_by_default_goes_to_a_cell_of_its_own(session_file: Path) -> None:
    ep = Endpoint()
    with Wire(ep.settings("busy"), "cell"):   # a running cell daemon's token, alive/cell
        refused = run(foldcell_argv("replay", str(session_file), *ep.args("busy"), "--rate", "max"))
        assert refused.returncode == 2, refused
        assert "--cell: busy is a live cell (cell alive there)" in refused.stderr
        recorded, replayed = Collector(ep, CELL), Collector(ep, f"{CELL}-replay")
        try:
            without_cell = [a for a in ep.args() if a not in ("--cell", ep.cell)]
            result = run(foldcell_argv("replay", str(session_file), *without_cell, "--json", "--rate", "max",
                                       "--topics", "cell/*"))
            assert result.returncode == 0, result.stderr
            published = json.loads(result.stdout)["published"]
            assert published > 0
            assert wait_until(lambda: len(replayed.samples) == published, 20), len(replayed.samples)
            assert recorded.samples == []
        finally:
            recorded.close()
            replayed.close()
