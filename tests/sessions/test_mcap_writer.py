"""SessionWriter: round trip, rosbag2 conventions, metadata, sequences, rotation, threads, errors."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader

from drivers.sessions.mcap import (
    LogWriteError,
    SessionWriter,
    WriterClosedError,
    iter_messages,
    read_info,
)
from drivers.sessions.mcap.bag import qos_text, type_hash
from tests.sessions.test_mcap_fixtures import (
    JOINT_STATE,
    JOINTS_TOPIC,
    LOG,
    LOG_TOPIC,
    T0,
    joint_state,
    msgdef,
    write_session,
)


def test_round_trip_keeps_every_message_and_both_times(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    written = write_session(path, 500, chunk_size=4096)
    got = list(iter_messages(path))
    assert [(m.topic, m.log_time_ns, m.data) for m in got] == sorted(written, key=lambda w: w[1])
    by_time = {m.log_time_ns: m for m in got}
    assert by_time[T0].publish_time_ns == T0 - 1000
    assert by_time[T0 + 1].publish_time_ns == T0 - 2000
    assert by_time[T0].type_name == JOINT_STATE and by_time[T0].msgdef == msgdef(JOINT_STATE)
    assert by_time[T0 + 1].type_name == LOG and by_time[T0 + 1].msgdef == msgdef(LOG)


def test_file_follows_rosbag2_conventions(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    write_session(path, 50, cell="cell7", metadata={"operator": "test"})
    with open(path, "rb") as f:
        reader = make_reader(f)
        header = reader.get_header()
        summary = reader.get_summary()
        assert summary is not None  # a clean stop leaves a summary section
        metadata = list(reader.iter_metadata())
    assert header.profile == "ros2"
    assert header.library.startswith("foldcell/")
    assert {s.name for s in summary.schemas.values()} == {JOINT_STATE, LOG}
    assert all(s.encoding == "ros2msg" for s in summary.schemas.values())
    assert {s.name: s.data.decode() for s in summary.schemas.values()} == {
        JOINT_STATE: msgdef(JOINT_STATE), LOG: msgdef(LOG)}
    assert {c.topic for c in summary.channels.values()} == {JOINTS_TOPIC, LOG_TOPIC}
    assert all(c.message_encoding == "cdr" for c in summary.channels.values())
    # what rosbag2's MCAP storage writes, and what rosbags matches to the bag's metadata.yaml by
    assert {c.topic: c.metadata for c in summary.channels.values()} == {
        JOINTS_TOPIC: {"offered_qos_profiles": qos_text(JOINTS_TOPIC),
                       "topic_type_hash": type_hash(JOINT_STATE)},
        LOG_TOPIC: {"offered_qos_profiles": qos_text(LOG_TOPIC), "topic_type_hash": type_hash(LOG)}}
    assert summary.statistics.message_count == 55
    assert summary.chunk_indexes and all(ci.compression == "zstd" for ci in summary.chunk_indexes)
    (meta,) = metadata
    assert meta.name == "foldcell_session"
    assert meta.metadata["cell"] == "cell7"
    assert meta.metadata["operator"] == "test"
    assert meta.metadata["foldcell_version"] not in ("", "unknown")
    assert int(meta.metadata["start_time_ns"]) > T0
    assert meta.metadata["part"] == "0"


@pytest.mark.parametrize("compression", ["zstd", "lz4", "none"])
def test_compressions_are_recorded_and_readable(tmp_path: Path, compression: str) -> None:
    path = tmp_path / "s.mcap"
    written = write_session(path, 200, chunk_size=2048, compression=compression)
    assert read_info(path).compression == ((compression,) if compression != "none" else ("none",))
    assert len(list(iter_messages(path))) == len(written)


def test_sequence_numbers_count_per_channel(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    write_session(path, 300, chunk_size=1024)
    seqs: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            seqs.setdefault(channel.topic, []).append(message.sequence)
    assert seqs[JOINTS_TOPIC] == list(range(1, 301))
    assert seqs[LOG_TOPIC] == list(range(1, 31))


def test_rotation_makes_several_valid_files_holding_every_message(tmp_path: Path) -> None:
    path = tmp_path / "session.mcap"
    written = write_session(path, 2000, chunk_size=2048, rotate_bytes=16_000, bag=True)
    parts = sorted((tmp_path / "session").glob("session_*.mcap"), key=lambda p: int(p.stem.split("_")[1]))
    assert len(parts) >= 4
    assert parts[:2] == [tmp_path / "session" / "session_0.mcap", tmp_path / "session" / "session_1.mcap"]
    total = 0
    for index, part in enumerate(parts):
        with open(part, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            assert summary is not None
            # Each part re-registers what its messages need.
            assert {c.topic for c in summary.channels.values()} <= {JOINTS_TOPIC, LOG_TOPIC}
            assert all(summary.schemas[c.schema_id].encoding == "ros2msg" for c in summary.channels.values())
            (meta,) = list(reader.iter_metadata())
            assert meta.metadata["part"] == str(index)
            total += summary.statistics.message_count
        # A finished part is not much bigger than the limit: one chunk plus the summary.
        assert part.stat().st_size < 16_000 + 2 * 2048 + 4096
    assert total == len(written)
    merged = list(iter_messages(parts))
    assert [(m.topic, m.log_time_ns, m.data) for m in merged] == sorted(written, key=lambda w: w[1])


def test_writer_reports_its_paths_and_count(tmp_path: Path) -> None:
    path = tmp_path / "session.mcap"
    w = SessionWriter(path, chunk_size=512, rotate_bytes=4000, bag=True)
    for i in range(300):
        w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(i), T0 + i, T0 + i)
    w.close()
    assert w.bag == tmp_path / "session"
    assert len(w.paths) > 2
    assert w.paths == [tmp_path / "session" / f"session_{i}.mcap" for i in range(len(w.paths))]
    assert set(w.paths) == set((tmp_path / "session").glob("*.mcap"))
    assert w.message_count == 300 and w.closed


def test_threads_writing_concurrently_lose_nothing(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    n_threads, n_each = 4, 300
    data = joint_state(1)
    with SessionWriter(path, chunk_size=2048) as w:
        def run(k: int) -> None:
            for i in range(n_each):
                w.write(f"/t{k}", JOINT_STATE, msgdef(JOINT_STATE), data, T0 + i, T0 + i)
        threads = [threading.Thread(target=run, args=(k,)) for k in range(n_threads)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    seqs: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            seqs.setdefault(channel.topic, []).append(message.sequence)
    assert sorted(seqs) == [f"/t{k}" for k in range(n_threads)]
    assert all(sorted(s) == list(range(1, n_each + 1)) for s in seqs.values())


def test_close_is_idempotent_and_write_after_close_fails(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    w = SessionWriter(path)
    w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(0), T0, T0)
    w.close()
    size = path.stat().st_size
    w.close()
    assert path.stat().st_size == size
    with pytest.raises(WriterClosedError):
        w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(1), T0, T0)
    assert len(list(iter_messages(path))) == 1


def test_flush_writes_the_open_chunk(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    w = SessionWriter(path)  # 1 MiB chunks: nothing reaches the file by size alone
    for i in range(10):
        w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(i), T0 + i, T0 + i)
    before = path.stat().st_size
    w.flush()
    assert path.stat().st_size > before + 500
    w.close()


def test_flush_interval_closes_old_chunks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import drivers.sessions.mcap.writer as writer_mod

    now = [100.0]
    monkeypatch.setattr(writer_mod.time, "monotonic", lambda: now[0])
    path = tmp_path / "s.mcap"
    w = SessionWriter(path, flush_interval_s=0.5)
    w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(0), T0, T0)
    size = path.stat().st_size
    now[0] += 0.4
    w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(1), T0 + 1, T0 + 1)
    assert path.stat().st_size == size
    now[0] += 0.2
    w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(2), T0 + 2, T0 + 2)
    assert path.stat().st_size > size
    w.close()


def test_flush_if_due_writes_the_open_chunk_once_its_oldest_message_is_old_enough(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The recorder's timer: no write while the open chunk is younger than the interval (it is told how
    long to sleep), the chunk on disk once it is due, even with no message after it."""
    import drivers.sessions.mcap.writer as writer_mod

    now = [100.0]
    monkeypatch.setattr(writer_mod.time, "monotonic", lambda: now[0])
    path = tmp_path / "s.mcap"
    w = SessionWriter(path, flush_interval_s=0.05)
    assert w.flush_if_due() == pytest.approx(0.05)  # nothing open: a whole interval
    w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(0), T0, T0)
    size = path.stat().st_size
    now[0] = 100.03
    assert w.flush_if_due() == pytest.approx(0.02)
    assert path.stat().st_size == size
    now[0] = 100.051
    assert w.flush_if_due() == pytest.approx(0.05)
    assert path.stat().st_size > size
    w.close()
    assert SessionWriter(tmp_path / "t.mcap").flush_if_due() is None  # no interval: no timer


@pytest.mark.parametrize(
    ("args", "field"),
    [
        (("", JOINT_STATE, "x", b"", 0, 0), "topic"),
        (("/a", "JointState", "x", b"", 0, 0), "type_name"),
        (("/a", "sensor_msgs/JointState", "x", b"", 0, 0), "type_name"),
        (("/a", JOINT_STATE, b"x", b"", 0, 0), "msgdef"),
        (("/a", JOINT_STATE, "x", "text", 0, 0), "data"),
        (("/a", JOINT_STATE, "x", b"", -1, 0), "log_time_ns"),
        (("/a", JOINT_STATE, "x", b"", 0, 1.5), "publish_time_ns"),
    ],
)
def test_bad_write_arguments_name_the_field(tmp_path: Path, args: tuple, field: str) -> None:
    with SessionWriter(tmp_path / "s.mcap") as w, pytest.raises(LogWriteError, match=field):
        w.write(*args)


def test_a_topic_keeps_one_type(tmp_path: Path) -> None:
    with SessionWriter(tmp_path / "s.mcap") as w:
        w.write("/a", JOINT_STATE, msgdef(JOINT_STATE), joint_state(0), T0, T0)
        with pytest.raises(LogWriteError, match="'/a': type changed"):
            w.write("/a", LOG, msgdef(LOG), b"", T0, T0)
        with pytest.raises(LogWriteError, match="definition differs"):
            w.write("/b", JOINT_STATE, "float64 x\n", b"", T0, T0)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [({"chunk_size": 0}, "chunk_size"), ({"compression": "gzip"}, "compression"),
     ({"rotate_bytes": 0}, "rotate_bytes"), ({"flush_interval_s": -1.0}, "flush_interval_s"),
     ({"metadata": {"a": 1}}, "metadata")],
)
def test_bad_writer_settings_name_the_field(tmp_path: Path, kwargs: dict, field: str) -> None:
    with pytest.raises(LogWriteError, match=field):
        SessionWriter(tmp_path / "s.mcap", **kwargs)


def test_fsync_mode_writes_a_valid_file(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    written = write_session(path, 100, chunk_size=1024, fsync=True)
    assert len(list(iter_messages(path))) == len(written)


def test_config_from_yaml_fields(tmp_path: Path) -> None:
    from drivers.common.configfile import ConfigError, load_yaml
    from drivers.sessions.mcap import SessionLogConfig, session_log_config_from_fields

    cfg = tmp_path / "cell.yaml"
    cfg.write_text("log:\n  chunk_size: 2048\n  compression: lz4\n  rotate_bytes: 20000\n"
                   "  flush_interval_s: 1.0\n  fsync: false\n  max_backlog_bytes: 1000000\n")
    config = session_log_config_from_fields(load_yaml(cfg).sub("log"))
    assert config == SessionLogConfig(2048, "lz4", 20000, 1.0, False, 1000000)
    path = tmp_path / "s.mcap"
    with SessionWriter.from_config(path, config, cell="cell2") as w:
        w.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), joint_state(0), T0, T0)
    assert w.paths == [tmp_path / "s" / "s_0.mcap"]  # a session is a bag
    assert read_info(w.paths[0]).compression == ("lz4",)
    cfg.write_text("log:\n  chunk_size: 2048\n  compression: gzip\n  rotate_bytes: null\n"
                   "  flush_interval_s: null\n  fsync: false\n  max_backlog_bytes: 1000000\n")
    with pytest.raises(ConfigError, match=r"log\.compression"):
        session_log_config_from_fields(load_yaml(cfg).sub("log"))
    cfg.write_text("log:\n  chunk_size: 2048\n  compresion: lz4\n")
    with pytest.raises(ConfigError, match=r"log\.compresion: unknown field"):
        session_log_config_from_fields(load_yaml(cfg).sub("log"))


def test_uncreatable_path_names_the_path(tmp_path: Path) -> None:
    from drivers.sessions.mcap import LogFileError

    with pytest.raises(LogFileError, match=r"missing_dir/s\.mcap: cannot create"):
        SessionWriter(tmp_path / "missing_dir" / "s.mcap")


def test_without_cell_the_metadata_has_no_cell_key(tmp_path: Path) -> None:
    path = tmp_path / "s.mcap"
    SessionWriter(path).close()
    with open(path, "rb") as f:
        (meta,) = list(make_reader(f).iter_metadata())
    assert "cell" not in meta.metadata and meta.metadata["part"] == "0"
