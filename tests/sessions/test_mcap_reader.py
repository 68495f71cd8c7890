"""iter_messages: order, topic and time-window filters, several files, cut files."""

from __future__ import annotations

from pathlib import Path

import pytest

from drivers.sessions.mcap import LogFileError, SessionWriter, iter_messages, recover
from tests.sessions.test_mcap_fixtures import (
    JOINT_STATE,
    JOINTS_TOPIC,
    LOG_TOPIC,
    T0,
    joint_state,
    msgdef,
    write_session,
)


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[str, int, bytes]]]:
    path = tmp_path_factory.mktemp("reader") / "s.mcap"
    return path, write_session(path, 600, chunk_size=2048)


def test_messages_unpack_as_six_tuples_in_log_time_order(session) -> None:
    path, written = session
    rows = list(iter_messages(path))
    topic, type_name, definition, data, log_time, publish_time = rows[0]
    assert (topic, type_name, definition, log_time, publish_time) == (
        JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), T0, T0 - 1000)
    assert data == written[0][2]
    times = [r.log_time_ns for r in rows]
    assert times == sorted(times) and len(rows) == len(written)


def test_out_of_order_log_times_come_back_sorted(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    order = list(range(200))
    order[50:150] = reversed(order[50:150])  # a late burst, as when a sender's queue drains
    with SessionWriter(path, chunk_size=600) as w:
        for i in order:
            w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(i), T0 + i, T0 + i)
    assert [m.log_time_ns for m in iter_messages(path)] == [T0 + i for i in range(200)]


@pytest.mark.parametrize("window", [(0, 100), (37, 38), (120, 600), (599, 601), (300, 300)])
def test_time_window_is_half_open(session, window: tuple[int, int]) -> None:
    path, written = session
    start, end = (T0 + k * 10_000_000 for k in window)
    got = [(m.topic, m.log_time_ns, m.data) for m in iter_messages(path, start_ns=start, end_ns=end)]
    assert got == [w for w in sorted(written, key=lambda w: w[1]) if start <= w[1] < end]


def test_topic_filter(session) -> None:
    path, written = session
    got = list(iter_messages(path, topics=[LOG_TOPIC]))
    assert [m.log_time_ns for m in got] == [w[1] for w in written if w[0] == LOG_TOPIC]
    assert list(iter_messages(path, topics=["/nothing"])) == []


def test_bad_window_is_refused(session) -> None:
    path, _ = session
    with pytest.raises(ValueError, match="start_ns"):
        list(iter_messages(path, start_ns=T0 + 2, end_ns=T0 + 1))


def test_several_files_merge_by_log_time(tmp_path: Path) -> None:
    a, b = tmp_path / "a.mcap", tmp_path / "b.mcap"
    with SessionWriter(a) as wa, SessionWriter(b) as wb:
        for i in range(100):
            (wa if i % 3 else wb).write(f"/t{i % 3}", JOINT_STATE, msgdef(JOINT_STATE), joint_state(i),
                                        T0 + i, T0 + i)
    rows = list(iter_messages([a, b]))
    assert [r.log_time_ns for r in rows] == [T0 + i for i in range(100)]
    assert [r.topic for r in rows] == [f"/t{i % 3}" for i in range(100)]


def test_cut_file_asks_for_recover_and_recovered_file_reads(session, tmp_path: Path) -> None:
    path, written = session
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    with pytest.raises(LogFileError, match="log recover"):
        list(iter_messages(cut))
    report = recover(cut, tmp_path / "rec.mcap")
    rows = list(iter_messages(tmp_path / "rec.mcap"))
    assert len(rows) == report.messages_kept > 0
    expected = sorted(written, key=lambda w: w[1])[: len(rows)]
    assert [(r.topic, r.log_time_ns, r.data) for r in rows] == expected


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(LogFileError, match=r"missing\.mcap: no such file or bag folder"):
        list(iter_messages(tmp_path / "missing.mcap"))
    with pytest.raises(LogFileError, match="cannot open"):
        list(iter_messages([tmp_path / "missing.mcap"]))
