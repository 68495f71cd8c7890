"""Recorded files decode with readers that share no code with our registry: mcap_ros2 and rosbags."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.highlevel import AnyReader
from rosbags.rosbag2.storage_mcap import McapReader as RosbagsMcapReader

from drivers.sessions.mcap import recover
from tests.sessions.test_mcap_fixtures import JOINT_STATE, JOINTS_TOPIC, LOG, LOG_TOPIC, T0, write_session

N = 400


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[str, int, bytes]]]:
    path = tmp_path_factory.mktemp("decode") / "s.mcap"
    return path, write_session(path, N, chunk_size=8192)


def _check_joint_state(msg: object, i: int) -> None:
    assert list(msg.name) == [f"r1_joint_{c}" for c in "slurbt"]
    np.testing.assert_allclose(np.asarray(msg.position), np.arange(6) * 0.01 + i)
    np.testing.assert_allclose(np.asarray(msg.velocity), np.full(6, 0.5 * i))
    assert len(msg.effort) == 0
    assert msg.header.frame_id == "world"
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (i // 100, (i % 100) * 10_000_000)


def _check_log(msg: object, i: int) -> None:
    assert (msg.stamp.sec, msg.stamp.nanosec) == (i, 7)
    assert msg.level == 20 and msg.name == "foldcell.cell"
    assert msg.msg == f"step {i} " + "x" * (i % 13)
    assert (msg.file, msg.function, msg.line) == ("cell/run.py", "step", i)


def _index(topic: str, log_time: int) -> int:
    offset = 1 if topic == LOG_TOPIC else 0
    return (log_time - offset - T0) // 10_000_000


def _check(topic: str, log_time: int, msg: object) -> None:
    i = _index(topic, log_time)
    (_check_joint_state if topic == JOINTS_TOPIC else _check_log)(msg, i)


def test_mcap_ros2_decodes_every_message(session) -> None:
    path, written = session
    count = 0
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            assert schema.name == (JOINT_STATE if channel.topic == JOINTS_TOPIC else LOG)
            _check(channel.topic, message.log_time, decoded)
            count += 1
    assert count == len(written)


def test_rosbags_anyreader_decodes_every_message_from_embedded_definitions(session) -> None:
    path, written = session
    count = 0
    # No default typestore: the types come from the file's ros2msg schemas only.
    with AnyReader([path]) as reader:
        assert {c.msgtype for c in reader.connections} == {JOINT_STATE, LOG}
        for connection, timestamp, raw in reader.messages():
            _check(connection.topic, timestamp, reader.deserialize(raw, connection.msgtype))
            count += 1
    assert count == len(written)


def test_rosbags_reads_a_recovered_file(session, tmp_path: Path) -> None:
    path, _ = session
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    out = tmp_path / "rec.mcap"
    report = recover(cut, out)
    assert report.messages_kept > 0
    reader = RosbagsMcapReader(out)
    reader.open()
    try:
        rows = list(reader.messages(reader.connections))
    finally:
        reader.close()
    assert len(rows) == report.messages_kept
    with AnyReader([out]) as anyreader:
        for connection, timestamp, raw in anyreader.messages():
            _check(connection.topic, timestamp, anyreader.deserialize(raw, connection.msgtype))
