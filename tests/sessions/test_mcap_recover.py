"""recover: cut files (many random offsets), damaged chunks, and a writer killed with SIGKILL."""

from __future__ import annotations

import os
import random
import select
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import breakup_chunk

from drivers.sessions.mcap import LogFileError, iter_messages, read_info, recover
from tests.conftest import REPO
from tests.sessions.test_mcap_fixtures import JOINTS_TOPIC, write_session


def _chunks(path: Path) -> list[tuple[int, int, list[tuple[int, bytes]]]]:
    """(start, end, [(log_time, data)...]) of every chunk, read with the mcap library's index."""
    out = []
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
        for ci in summary.chunk_indexes:
            f.seek(ci.chunk_start_offset + 9)
            chunk = Chunk.read(ReadDataStream(f))
            msgs = [(r.log_time, r.data) for r in breakup_chunk(chunk) if isinstance(r, Message)]
            out.append((ci.chunk_start_offset, ci.chunk_start_offset + ci.chunk_length, msgs))
    return out


def _read_all(path: Path) -> list[tuple[int, bytes]]:
    """Every message, read to the end with the seeking reader (needs summary and footer)."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        assert reader.get_summary() is not None
        return [(m.log_time, m.data) for _, _, m in reader.iter_messages(log_time_order=False)]


@pytest.fixture(scope="module")
def original(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("orig") / "s.mcap"
    write_session(path, 400, chunk_size=1500)
    return path


def _header_end(data: bytes) -> int:
    length = int.from_bytes(data[9:17], "little")
    return 8 + 9 + length


def test_truncated_at_many_offsets_recovers_exactly_the_complete_chunks(original: Path,
                                                                        tmp_path: Path) -> None:
    data = original.read_bytes()
    chunks = _chunks(original)
    assert len(chunks) >= 20
    summary_start = _footer_summary_start(data)
    rng = random.Random(1234)
    cuts = {rng.randrange(_header_end(data), len(data) + 1) for _ in range(120)}
    for start, end, _ in chunks:  # the edges: right before, at and after each chunk's end
        cuts |= {start, start + 1, end - 1, end, end + 1}
    cuts |= {_header_end(data), summary_start - 1, summary_start, len(data) - 1, len(data)}
    cut_path, out = tmp_path / "cut.mcap", tmp_path / "out.mcap"
    for cut in sorted(cuts):
        cut_path.write_bytes(data[:cut])
        report = recover(cut_path, out)
        expected = [m for _, end, msgs in chunks if end <= cut for m in msgs]
        got = _read_all(out)
        assert got == expected, f"cut at {cut}"
        assert report.messages_kept == len(expected)
        assert report.chunks_kept == sum(1 for _, end, _ in chunks if end <= cut)
        assert report.data_lost == (cut < summary_start), f"cut at {cut}"
        assert report.source_complete == (cut == len(data))
        assert report.bytes_read + report.bytes_dropped == cut
        info = read_info(out)
        assert info.complete and info.has_summary and info.message_count == len(expected)


def _footer_summary_start(data: bytes) -> int:
    # Footer: opcode(1) length(8) summary_start(8) summary_offset_start(8) crc(4), then magic(8).
    footer = data[-(8 + 29):-8]
    return int.from_bytes(footer[9:17], "little")


def test_cut_inside_magic_or_header_is_bad_input(original: Path, tmp_path: Path) -> None:
    data = original.read_bytes()
    cut_path = tmp_path / "cut.mcap"
    for cut in (0, 3, 7):
        cut_path.write_bytes(data[:cut])
        with pytest.raises(LogFileError, match="not an MCAP file"):
            recover(cut_path, tmp_path / "o.mcap")
    for cut in (8, 12, _header_end(data) - 1):
        cut_path.write_bytes(data[:cut])
        with pytest.raises(LogFileError, match="no header"):
            recover(cut_path, tmp_path / "o.mcap")
    assert not (tmp_path / "o.mcap").exists()
    assert not list(tmp_path.glob("*.partial"))


def test_damaged_chunk_is_skipped_and_the_rest_kept(original: Path, tmp_path: Path) -> None:
    data = bytearray(original.read_bytes())
    chunks = _chunks(original)
    k = len(chunks) // 2
    start, end, _ = chunks[k]
    data[(start + end) // 2] ^= 0xFF  # inside the compressed data: CRC or zstd fails
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    report = recover(bad, tmp_path / "out.mcap")
    assert report.chunks_damaged == 1 and report.data_lost
    expected = [m for i, (_, _, msgs) in enumerate(chunks) if i != k for m in msgs]
    assert _read_all(tmp_path / "out.mcap") == expected
    # info trusts a summary (no chunk is decompressed); a file without one is scanned and checked.
    bad.write_bytes(bytes(data[: chunks[-1][1]]))
    info = read_info(bad)
    assert info.damaged_chunks == 1 and not info.complete
    assert info.message_count == len(expected)


def test_complete_file_recovers_with_nothing_lost(original: Path, tmp_path: Path) -> None:
    report = recover(original, tmp_path / "out.mcap")
    assert report.source_complete and not report.data_lost and report.bytes_dropped == 0
    assert _read_all(tmp_path / "out.mcap") == [m for _, _, msgs in _chunks(original) for m in msgs]
    with open(tmp_path / "out.mcap", "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        assert "recovered by foldcell" in reader.get_header().library
        assert [m.name for m in reader.iter_metadata()] == ["foldcell_session"]


def test_recover_refuses_to_overwrite_its_source(original: Path, tmp_path: Path) -> None:
    copy = tmp_path / "s.mcap"
    copy.write_bytes(original.read_bytes())
    with pytest.raises(LogFileError, match="must not be the file"):
        recover(copy, copy)
    assert copy.read_bytes() == original.read_bytes()


def test_not_mcap_and_missing_are_bad_input(tmp_path: Path) -> None:
    text = tmp_path / "x.mcap"
    text.write_text("hello, this is not MCAP at all")
    with pytest.raises(LogFileError, match="not an MCAP file"):
        recover(text, tmp_path / "o.mcap")
    with pytest.raises(LogFileError, match="cannot open"):
        recover(tmp_path / "missing.mcap", tmp_path / "o.mcap")


_CHILD = textwrap.dedent("""
    import sys
    sys.path.insert(0, {repo!r})
    from pathlib import Path
    from drivers.sessions.mcap import SessionWriter
    from tests.sessions.test_mcap_fixtures import JOINT_STATE, JOINTS_TOPIC, T0, joint_state, msgdef

    payloads = [joint_state(i) for i in range(50)]
    definition = msgdef(JOINT_STATE)
    w = SessionWriter(Path(sys.argv[1]), chunk_size=4096, cell="cell1")
    i = 0
    while True:
        w.write(JOINTS_TOPIC, JOINT_STATE, definition, payloads[i % 50], T0 + i, T0 + i)
        i += 1
        if i == 2000:
            print("ready", flush=True)
""")


def test_writer_killed_with_sigkill_is_recovered_and_reads_to_the_end(tmp_path: Path) -> None:
    path = tmp_path / "killed.mcap"
    child = subprocess.Popen([sys.executable, "-c", _CHILD.format(repo=str(REPO)), str(path)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
    try:
        ready, _, _ = select.select([child.stdout], [], [], 60)
        assert ready, "writer child did not start"
        assert child.stdout.readline().strip() == b"ready", child.stderr.read().decode()
        time.sleep(0.2)  # keep writing for a while, so the kill lands mid-stream
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait(timeout=30)
        child.stdout.close()
        child.stderr.close()
    assert child.returncode == -signal.SIGKILL
    with open(path, "rb") as f, pytest.raises(McapError):
        list(make_reader(f).iter_messages())  # the seeking reader cannot use the cut file
    with pytest.raises(LogFileError, match="recover"):
        list(iter_messages(path))
    assert not read_info(path).complete

    out = tmp_path / "recovered.mcap"
    report = recover(path, out)
    assert report.data_lost and not report.source_complete
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        rows = [(c.topic, m.sequence, m.log_time) for _, c, m in reader.iter_messages()]
        assert [m.metadata["cell"] for m in reader.iter_metadata()] == ["cell1"]
    assert len(rows) == report.messages_kept
    # At least everything written before "ready", less the chunk open at that moment, survived,
    # and what survived is a gap-free prefix of the stream.
    assert len(rows) >= 2000 - 4096 // 150
    assert [seq for _, seq, _ in rows] == list(range(1, len(rows) + 1))
    assert all(topic == JOINTS_TOPIC for topic, _, _ in rows)


def _record_ends(data: bytes) -> list[tuple[int, int]]:
    """(opcode, end offset) of every record, from the MCAP framing alone."""
    out, offset = [], 8
    while offset + 9 <= len(data):
        opcode = data[offset]
        offset += 9 + int.from_bytes(data[offset + 1:offset + 9], "little")
        out.append((opcode, offset))
        if opcode == 0x02:  # footer
            break
    return out


def test_unchunked_messages_are_kept_record_by_record(tmp_path: Path) -> None:
    from mcap.writer import Writer

    path = tmp_path / "plain.mcap"
    with open(path, "wb") as f:
        w = Writer(f, use_chunking=False)
        w.start(profile="ros2", library="test")
        sid = w.register_schema("std_msgs/msg/String", "ros2msg", b"string data\n")
        cid = w.register_channel("/chatter", "cdr", sid)
        for i in range(60):
            w.add_message(cid, log_time=i, data=bytes([i]) * (i + 1), publish_time=i)
        w.finish()
    data = path.read_bytes()
    message_ends = [end for opcode, end in _record_ends(data) if opcode == 0x05]
    assert len(message_ends) == 60
    rng = random.Random(7)
    cuts = sorted({rng.randrange(message_ends[0] - 40, len(data)) for _ in range(60)} | set(message_ends))
    cut_path = tmp_path / "cut.mcap"
    for cut in cuts:
        cut_path.write_bytes(data[:cut])
        report = recover(cut_path, tmp_path / "out.mcap")
        kept = sum(1 for end in message_ends if end <= cut)
        assert report.messages_kept == kept, f"cut at {cut}"
        assert _read_all(tmp_path / "out.mcap") == [(i, bytes([i]) * (i + 1)) for i in range(kept)]


_CHILD_SIGNAL = textwrap.dedent("""
    import signal, sys
    sys.path.insert(0, {repo!r})
    from pathlib import Path
    from drivers.sessions.mcap import SessionWriter, WriterClosedError
    from tests.sessions.test_mcap_fixtures import JOINT_STATE, JOINTS_TOPIC, T0, joint_state, msgdef

    payload, definition = joint_state(1), msgdef(JOINT_STATE)
    w = SessionWriter(Path(sys.argv[1]), chunk_size=4096)
    # The handler closes directly: if it interrupts write(), the close waits for that write to end.
    signal.signal(signal.SIGTERM, lambda *_: w.close())
    signal.signal(signal.SIGINT, lambda *_: w.close())
    i = 0
    try:
        while True:
            w.write(JOINTS_TOPIC, JOINT_STATE, definition, payload, T0 + i, T0 + i)
            i += 1
            if i == 3000:
                print("ready", flush=True)
    except WriterClosedError:
        print(i, flush=True)
""")


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_closing_the_writer_leaves_a_file_with_summary(tmp_path: Path, signum: int) -> None:
    path = tmp_path / "stopped.mcap"
    child = subprocess.Popen([sys.executable, "-c", _CHILD_SIGNAL.format(repo=str(REPO)), str(path)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=REPO)
    try:
        ready, _, _ = select.select([child.stdout], [], [], 60)
        assert ready and child.stdout.readline().strip() == b"ready", child.stderr.read().decode()
        time.sleep(0.1)
        os.kill(child.pid, signum)
        out, err = child.communicate(timeout=30)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0, err.decode()
    written = int(out.split()[-1])
    info = read_info(path)
    assert info.has_summary and info.complete
    assert info.message_count == written >= 3000
    assert len(_read_all(path)) == written
