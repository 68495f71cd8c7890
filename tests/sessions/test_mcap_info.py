"""read_info on files with a summary, without one, cut short; JSON form."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from mcap.reader import make_reader
from mcap.writer import IndexType, Writer

from drivers.sessions.mcap import LogFileError, read_info
from tests.sessions.test_mcap_fixtures import JOINT_STATE, JOINTS_TOPIC, LOG, LOG_TOPIC, T0, write_session
from tools.log_cli import format_info


@pytest.fixture(scope="module")
def complete(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("info") / "s.mcap"
    write_session(path, 1000, chunk_size=4096, cell="cell1")
    return path


def test_info_from_summary(complete: Path) -> None:
    info = read_info(complete, verify=False)
    assert info.has_summary and info.complete and info.unreadable_bytes == 0
    assert info.profile == "ros2" and info.library.startswith("foldcell/")
    assert info.message_count == 1100
    assert info.start_ns == T0 and info.end_ns == T0 + 999 * 10_000_000
    assert info.duration_s == pytest.approx(9.99)
    assert info.compression == ("zstd",)
    assert info.size_bytes == complete.stat().st_size
    channels = {c.topic: c for c in info.channels}
    joints, log = channels[JOINTS_TOPIC], channels[LOG_TOPIC]
    assert (joints.type_name, joints.schema_encoding, joints.message_encoding) == (
        JOINT_STATE, "ros2msg", "cdr")
    assert joints.message_count == 1000 and joints.rate_hz == pytest.approx(100.0)
    assert log.type_name == LOG and log.message_count == 100 and log.rate_hz == pytest.approx(10.0)
    assert (log.first_log_time_ns, log.last_log_time_ns) == (T0 + 1, T0 + 990 * 10_000_000 + 1)
    assert dict(info.metadata[0].entries)["cell"] == "cell1"


def test_scan_gives_the_same_answer_as_the_summary(complete: Path, tmp_path: Path) -> None:
    data = complete.read_bytes()
    summary_start = int.from_bytes(data[-(8 + 29) + 9:-(8 + 29) + 17], "little")
    cut = tmp_path / "cut_in_summary.mcap"
    cut.write_bytes(data[: summary_start + 5])  # all data, the summary cut: only a scan works
    scanned, full = read_info(cut), read_info(complete, verify=False)
    assert not scanned.has_summary and not scanned.complete and scanned.unreadable_bytes > 0
    assert scanned.channels == full.channels
    assert (scanned.message_count, scanned.chunk_count, scanned.start_ns, scanned.end_ns) == (
        full.message_count, full.chunk_count, full.start_ns, full.end_ns)
    assert scanned.metadata == full.metadata


def test_a_verified_read_agrees_with_the_summary(complete: Path) -> None:
    assert read_info(complete) == read_info(complete, verify=False)


def test_a_chunk_failing_its_crc_makes_the_file_damaged_not_complete(complete: Path, tmp_path: Path) -> None:
    data = bytearray(complete.read_bytes())
    with open(complete, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[3]
    data[chunk.chunk_start_offset + chunk.chunk_length - 20] ^= 0xFF   # inside its compressed records
    damaged = tmp_path / "damaged.mcap"
    damaged.write_bytes(bytes(data))
    assert read_info(damaged, verify=False).complete   # the summary alone cannot tell
    info = read_info(damaged)
    assert not info.complete and info.damaged_chunks == 1 and info.unreadable_bytes == 0
    assert info.message_count < 1100
    text = format_info(info)
    assert "DAMAGED" in text and "complete" not in text.split("state:")[1].split("\n")[0]


def test_cut_file_counts_only_complete_chunks(complete: Path, tmp_path: Path) -> None:
    data = complete.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    info = read_info(cut)
    assert not info.complete and not info.has_summary
    assert 0 < info.message_count < 1100
    assert info.unreadable_bytes > 0
    assert sum(c.message_count for c in info.channels) == info.message_count


def test_complete_file_without_summary_is_scanned(tmp_path: Path) -> None:
    path = tmp_path / "nosummary.mcap"
    with open(path, "wb") as f:
        w = Writer(f, chunk_size=512, index_types=IndexType.NONE, repeat_channels=False,
                   repeat_schemas=False, use_statistics=False, use_summary_offsets=False)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data\n")
        cid = w.register_channel("/chatter", "cdr", sid)
        for i in range(50):
            w.add_message(cid, log_time=T0 + i * 500_000_000, data=b"\x00\x01\x00\x00\x02\x00\x00\x00a\x00",
                          publish_time=T0)
        w.finish()
    info = read_info(path)
    assert info.complete and not info.has_summary
    (chatter,) = info.channels
    assert chatter.topic == "/chatter" and chatter.message_count == 50
    assert chatter.rate_hz == pytest.approx(2.0)
    assert info.duration_s == pytest.approx(24.5)


def test_info_is_json_able(complete: Path) -> None:
    doc = json.loads(json.dumps(read_info(complete).to_json_dict()))
    assert doc["message_count"] == 1100
    assert {c["topic"] for c in doc["channels"]} == {JOINTS_TOPIC, LOG_TOPIC}
    assert doc["metadata"]["foldcell_session"]["cell"] == "cell1"


def test_empty_session_has_no_span(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    write_session(path, 0)
    info = read_info(path)
    assert info.message_count == 0 and info.channels == () and info.start_ns is None
    assert info.duration_s == 0.0


def test_bad_files_raise_log_file_error(tmp_path: Path) -> None:
    with pytest.raises(LogFileError, match="cannot open"):
        read_info(tmp_path / "missing.mcap")
    (tmp_path / "text.mcap").write_text("not mcap")
    with pytest.raises(LogFileError, match="not an MCAP file"):
        read_info(tmp_path / "text.mcap")
    with pytest.raises(LogFileError):
        read_info(tmp_path)
