"""A session is a rosbag2 bag: rosbags' readers open the folder, its metadata.yaml matches the files,
and a session split by size is one session for info, replay, recover and the Foxglove export."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import pytest
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import QosReliability
from rosbags.rosbag2 import Reader

from drivers.robot.config import default_robot_config
from drivers.sessions.foxglove import export_for_foxglove, load_foxglove_config
from drivers.sessions.mcap import SessionWriter, find_session, iter_messages, read_session_info, recover_bag
from drivers.sessions.replay import Replayer, Selection, load_replay_config, open_session, select
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

ROTATE_BYTES = 16_000


@pytest.fixture(scope="module")
def rotated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[tuple[str, int, bytes]]]:
    """A session split by size into several files, and what was written to it."""
    path = tmp_path_factory.mktemp("bag") / "rot.mcap"
    written = write_session(path, 2000, chunk_size=2048, rotate_bytes=ROTATE_BYTES, cell="cell1", bag=True)
    return path.with_suffix(""), written


def _files(folder: Path) -> list[Path]:
    return sorted(folder.glob("*.mcap"), key=lambda p: int(p.stem.rsplit("_", 1)[1]))


def _count_in_file(path: Path) -> int:
    with open(path, "rb") as f:
        return sum(1 for _ in make_reader(f).iter_messages())


def test_the_folder_is_laid_out_as_rosbag2_lays_a_bag_out(rotated) -> None:
    folder, _ = rotated
    files = _files(folder)
    assert len(files) >= 4
    assert [p.name for p in files] == [f"rot_{i}.mcap" for i in range(len(files))]
    assert {p.name for p in folder.iterdir()} == {"metadata.yaml", *(p.name for p in files)}


def test_any_reader_reads_every_message_of_every_file_with_its_type(rotated) -> None:
    folder, written = rotated
    with AnyReader([folder]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        read = [(c.topic, t, reader.deserialize(data, c.msgtype)) for c, t, data in reader.messages()]
    assert types == {JOINTS_TOPIC: JOINT_STATE, LOG_TOPIC: LOG}
    assert Counter(topic for topic, _, _ in read) == Counter(topic for topic, _, _ in written)
    assert sorted(t for _, t, _ in read) == sorted(t for _, t, _ in written)
    # decoded, not only counted: the n-th joint state carries position n (the fixture's content)
    positions = [float(msg.position[0]) for topic, _, msg in sorted(read, key=lambda r: r[1])
                 if topic == JOINTS_TOPIC]
    assert positions == [float(i) for i in range(2000)]


def test_rosbags_metadata_reader_accepts_the_metadata_and_it_matches_the_files(rotated) -> None:
    folder, written = rotated
    times = [t for _, t, _ in written]
    files = _files(folder)
    with Reader(folder) as reader:
        assert reader.message_count == len(written)
        assert reader.start_time == min(times)
        assert reader.duration == max(times) - min(times) + 1  # rosbags counts the last nanosecond in
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts == dict(Counter(topic for topic, _, _ in written))
        reliability = {c.topic: c.ext.offered_qos_profiles[0].reliability for c in reader.connections}
        assert reliability == {JOINTS_TOPIC: QosReliability.BEST_EFFORT, LOG_TOPIC: QosReliability.RELIABLE}
        assert all(c.digest.startswith("RIHS01_") for c in reader.connections)
        listed = list(reader.storage.files)  # type: ignore[attr-defined]  (cleared on close)
        assert [f["path"] for f in listed] == [p.name for p in files]
        assert [f["message_count"] for f in listed] == [_count_in_file(p) for p in files]
        assert sum(f["message_count"] for f in listed) == len(written)
    info = yaml.safe_load((folder / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9 and info["storage_identifier"] == "mcap"
    assert info["relative_file_paths"] == [p.name for p in files]
    assert info["compression_format"] == "" and info["compression_mode"] == ""
    assert info["custom_data"]["cell"] == "cell1" and info["ros_distro"] == "jazzy"
    with open(files[1], "rb") as f:
        first_in_file_1 = min(m.log_time for _, _, m in make_reader(f).iter_messages())
    assert listed[1]["starting_time"]["nanoseconds_since_epoch"] == first_in_file_1


def test_the_bag_s_folder_and_each_of_its_files_name_the_whole_session(rotated) -> None:
    folder, written = rotated
    for named in (folder, folder.with_suffix(".mcap"), _files(folder)[2]):
        assert find_session(named).files == tuple(_files(folder))
        info = read_session_info(named)
        assert info.message_count == len(written) and info.complete
        assert {c.topic: c.message_count for c in info.channels} == dict(Counter(t for t, _, _ in written))
        assert info.start_ns == T0 and len(info.files) == len(_files(folder))


def test_a_rotated_session_replays_whole(rotated) -> None:
    folder, written = rotated
    session = open_session(_files(folder)[1])
    published: list[int] = []
    try:
        assert session.source == folder and not session.recovered
        assert list(select(session, Selection())) == list(iter_messages(folder))

        def sink(message) -> bool:
            published.append(message.log_time_ns)
            return True

        stats = Replayer(lambda: select(session, Selection()), sink, rate=None, loop=False,
                         config=load_replay_config()).run()
    finally:
        session.close()
    assert stats.published == len(written)
    assert published == sorted(t for _, t, _ in written)


def test_the_foxglove_export_of_a_rotated_session_holds_every_file(rotated, tmp_path: Path) -> None:
    folder, written = rotated
    out = tmp_path / "rot.foxglove.mcap"
    counts = export_for_foxglove(folder, out, load_foxglove_config(), default_robot_config().urdf_path)
    assert counts["messages"] == len(written)
    exported = Counter(m.topic for m in iter_messages(out))
    assert exported[JOINTS_TOPIC] + exported[LOG_TOPIC] == len(written)


def test_a_crashed_session_is_made_a_readable_bag_by_recover(tmp_path: Path) -> None:
    """A writer that stops without closing (as a killed process): the finished files are whole, the
    last has no summary and metadata.yaml does not know its count; recover makes the bag whole."""
    writer = SessionWriter(tmp_path / "crash", chunk_size=1024, rotate_bytes=20_000, bag=True)
    data = joint_state(5)
    for i in range(1500):
        writer.write(JOINTS_TOPIC, JOINT_STATE, msgdef(JOINT_STATE), data, T0 + i * 1000, T0 + i * 1000)
    files = list(writer.paths)
    assert len(files) >= 3
    with pytest.raises(AnyReaderError, match="end magic"), AnyReader([tmp_path / "crash"]):
        pass  # the last file, cut short, has no footer
    report = recover_bag(files[-1])
    assert [Path(r.output) for r in report.recovered] == [files[-1]]
    assert [Path(p) for p in report.untouched] == files[:-1]
    with AnyReader([tmp_path / "crash"]) as reader:
        times = [t for _, t, _ in reader.messages()]
        assert len(times) == reader.message_count
    # what survives is a prefix: every finished file and chunk, only the open chunk is lost
    assert times == [T0 + i * 1000 for i in range(len(times))]
    assert 1500 - 1024 // len(data) - 1 <= len(times) < 1500
    assert read_session_info(tmp_path / "crash").complete
    del writer

