"""Every simple message against byte strings written here from the facts' offsets and sizes
(`shared/facts/motoros-simple-message.md` sections 2-4, 10), in both dialects: decode the reference,
encode the decoded value back to the same bytes, at the table's exact frame size."""

from __future__ import annotations

import struct

import pytest

from drivers.motoros import messages as sm

# frame sizes from the facts' table (section 3) and the fork's (section 10)
UPSTREAM_FRAMES = {1: 16, 10: 60, 11: 68, 13: 44, 14: 152, 15: 148, 2001: 68, 2002: 76, 2017: 548, 2018: 28}
CLOPEMA_FRAMES = {13: 44, 14: 188, 15: 184, 2001: 80, 2002: 88}


def frame(msg_type: int, body: bytes, comm: int = 2, reply: int = 0) -> bytes:
    """Section 2: int32 length (header + body), msg_type, comm_type, reply_code; little-endian."""
    return struct.pack("<iiii", 12 + len(body), msg_type, comm, reply) + body


def floats(*values: float) -> bytes:
    return struct.pack(f"<{len(values)}f", *values)


def ints(*values: int) -> bytes:
    return struct.pack(f"<{len(values)}i", *values)


# ROBOT_STATUS (section 4, 13): seven int32 whose bytes are all distinct, and their little-endian bytes
ROBOT_STATUS_VALUES = (0x01020304, 0x05060708, 0x090A0B0C, 0x0D0E0F10, 0x11121314, 0x15161718, 0x191A1B1C)
ROBOT_STATUS_BODY = bytes.fromhex("04030201" "08070605" "0c0b0a09" "100f0e0d"
                                  "14131211" "18171615" "1c1b1a19")

POS = (0.5, -1.25, 2.0, 0.0, 0.25, -0.75)
VEL = (0.125, 0.0, -0.5, 1.0, 0.0, 0.0)


def slots(values: tuple[float, ...], count: int) -> tuple[float, ...]:
    return values + (0.0,) * (count - len(values))


def cases(slot_count: int) -> list[tuple[str, bytes, sm.Body, int]]:
    """(name, reference frame, decoded body, comm) for the types both dialects share."""
    n = slot_count
    pos, vel, zero = slots(POS, n), slots(VEL, n), (0.0,) * n
    return [
        # 13: drives_powered, e_stopped, error_code, in_error, in_motion, mode, motion_possible. The codec
        # carries seven int32 as they are (the server's values are checked in test_server): here every
        # byte of the body differs from every other, so a field moved, in the wrong byte order (or words
        # swapped) or narrower than 4 bytes shows. The body is written out byte by byte, little-endian
        # (section 1: the DX100's native order), not packed by the code under test.
        ("ROBOT_STATUS", frame(13, ROBOT_STATUS_BODY, comm=1), sm.RobotStatus(*ROBOT_STATUS_VALUES), 1),
        # 14: robot_id, sequence, valid_fields, time, pos[n], vel[n], acc[n]
        ("JOINT_TRAJ_PT_FULL", frame(14, ints(1, 7, 7) + floats(1.5, *pos, *vel, *zero)),
         sm.JointTrajPtFull(1, 7, 7, 1.5, pos, vel, zero), 2),
        # 15: robot_id, valid_fields, time, pos[n], vel[n], acc[n]
        ("JOINT_FEEDBACK", frame(15, ints(0, 6) + floats(0.0, *pos, *vel, *zero), comm=1),
         sm.JointFeedback(0, 6, 0.0, pos, vel, zero), 1),
        # 2001: group, sequence, command, data[n]
        ("MOTO_MOTION_CTRL", frame(2001, ints(0, 3, 200121) + floats(*zero)),
         sm.MotionCtrl(0, 3, 200121, zero), 2),
        # 2002: group, sequence, command, result, subcode, data[n]; comm 3, reply 1
        ("MOTO_MOTION_REPLY", frame(2002, ints(2, 9, 14, 3, 3011) + floats(*zero), comm=3, reply=1),
         sm.MotionReply(2, 9, 14, 3, 3011, zero), 3),
    ]


def upstream_only() -> list[tuple[str, bytes, sm.Body, int]]:
    pos, vel, zero = slots(POS, 10), slots(VEL, 10), (0.0,) * 10
    block = ints(1, 7) + floats(0.25, *pos, *vel, *zero)  # 132 B: the layout of 15
    unused = bytes(132)
    dh = tuple(float(k) / 4.0 for k in range(128))
    return [
        ("PING", bytes.fromhex("0c000000" "01000000" "02000000" "00000000"), sm.Ping(), 2),
        ("JOINT_POSITION", frame(10, ints(4) + floats(*pos)), sm.JointPosition(4, pos), 2),
        ("JOINT_TRAJ_PT", frame(11, ints(4) + floats(*pos, 0.5, 2.0)), sm.JointTrajPt(4, pos, 0.5, 2.0), 2),
        # 2016: numberOfValidGroups, sequence, then n blocks
        ("MOTO_JOINT_TRAJ_PT_FULL_EX n=1", frame(2016, ints(1, 5) + block),
         sm.JointTrajPtFullEx(5, (sm.JointFeedback(1, 7, 0.25, pos, vel, zero),)), 2),
        ("MOTO_JOINT_TRAJ_PT_FULL_EX n=3", frame(2016, ints(3, 5) + block * 3),
         sm.JointTrajPtFullEx(5, (sm.JointFeedback(1, 7, 0.25, pos, vel, zero),) * 3), 2),
        # 2017: n, then always 4 blocks, unused ones zero
        ("MOTO_JOINT_FEEDBACK_EX", frame(2017, ints(2) + block + block + unused + unused, comm=1),
         sm.JointFeedbackEx((sm.JointFeedback(1, 7, 0.25, pos, vel, zero),) * 2), 1),
        # 2018: group, tool, sequence
        ("MOTO_SELECT_TOOL", frame(2018, ints(0, 63, 11)), sm.SelectTool(0, 63, 11), 2),
        ("MOTO_GET_DH_PARAMETERS request", frame(2020, b""), sm.DhParameters(), 2),
        ("MOTO_GET_DH_PARAMETERS reply", frame(2020, floats(*dh), comm=3, reply=1), sm.DhParameters(dh), 3),
        ("MOTO_READ_IO_BIT", frame(2003, struct.pack("<I", 10010)), sm.IoAddress(2003, 10010), 2),
        ("MOTO_READ_IO_BIT_REPLY", frame(2004, struct.pack("<Ii", 1, 0), comm=3, reply=1),
         sm.IoReadReply(2004, 1, 0), 3),
        ("MOTO_WRITE_IO_BIT", frame(2005, struct.pack("<II", 10010, 1)), sm.IoWrite(2005, 10010, 1), 2),
        ("MOTO_WRITE_IO_BIT_REPLY", frame(2006, ints(1002), comm=3, reply=1), sm.IoWriteReply(2006, 1002), 3),
        ("MOTO_READ_IO_GROUP", frame(2007, struct.pack("<I", 1001)), sm.IoAddress(2007, 1001), 2),
        ("MOTO_READ_IO_GROUP_REPLY", frame(2008, struct.pack("<Ii", 255, 0), comm=3, reply=1),
         sm.IoReadReply(2008, 255, 0), 3),
        ("MOTO_WRITE_IO_GROUP", frame(2009, struct.pack("<II", 1001, 3)), sm.IoWrite(2009, 1001, 3), 2),
        ("MOTO_WRITE_IO_GROUP_REPLY", frame(2010, ints(0), comm=3, reply=1), sm.IoWriteReply(2010, 0), 3),
        ("MOTO_IOCTRL_REPLY", frame(2011, ints(3, 3010), comm=3, reply=1), sm.IoCtrlReply(3, 3010), 3),
        ("MOTO_READ_MREGISTER", frame(2012, struct.pack("<I", 123)), sm.IoAddress(2012, 123), 2),
        ("MOTO_READ_MREGISTER_REPLY", frame(2013, struct.pack("<Ii", 7, 0), comm=3, reply=1),
         sm.IoReadReply(2013, 7, 0), 3),
        ("MOTO_WRITE_MREGISTER", frame(2014, struct.pack("<II", 123, 7)), sm.IoWrite(2014, 123, 7), 2),
        ("MOTO_WRITE_MREGISTER_REPLY", frame(2015, ints(0), comm=3, reply=1), sm.IoWriteReply(2015, 0), 3),
    ]


ALL = [("upstream", *c) for c in cases(10) + upstream_only()] + [("clopema", *c) for c in cases(13)]


@pytest.mark.parametrize(("dialect", "name", "reference", "body", "comm"), ALL,
                         ids=[f"{d}-{name}" for d, name, *_ in ALL])
def test_round_trip_against_the_facts(dialect: str, name: str, reference: bytes, body: sm.Body,
                                      comm: int) -> None:
    d = sm.DIALECTS[dialect]
    message = sm.decode(reference, d)
    assert message.body == body
    assert message.comm_type == comm
    reply = 1 if comm == sm.CommType.SERVICE_REPLY else 0
    encoded = sm.encode(body, d, comm, reply)
    assert encoded == reference
    msg_type = struct.unpack_from("<i", reference, 4)[0]
    table = UPSTREAM_FRAMES if dialect == "upstream" else CLOPEMA_FRAMES
    if msg_type in table:
        assert len(encoded) == table[msg_type], f"{name}: the facts' table says {table[msg_type]} bytes"
    if msg_type == 2016:
        assert len(encoded) == 24 + 132 * len(body.points)  # type: ignore[union-attr]
    if msg_type == 2020:
        assert len(encoded) == (528 if comm == 3 else 16)


def test_every_type_of_the_facts_is_covered() -> None:
    covered = {struct.unpack_from("<i", ref, 4)[0] for d, _, ref, *_ in ALL if d == "upstream"}
    assert covered == {1, 10, 11, 13, 14, 15, 2001, 2002, *range(2003, 2019), 2020} - {2019}
    assert {struct.unpack_from("<i", ref, 4)[0] for d, _, ref, *_ in ALL if d == "clopema"} == \
        {13, 14, 15, 2001, 2002}


def test_every_dialect_type_has_the_facts_size() -> None:
    for msg_type, size in UPSTREAM_FRAMES.items():
        assert sm.frame_size(msg_type, sm.UPSTREAM) == size
    for msg_type, size in CLOPEMA_FRAMES.items():
        assert sm.frame_size(msg_type, sm.CLOPEMA) == size
    assert [sm.frame_size(2016, sm.UPSTREAM, groups=n) for n in (1, 2, 3, 4)] == [156, 288, 420, 552]


def test_reply_and_topic_headers() -> None:
    """Section 2: every MotoROS reply has comm 3 and reply 1; state messages comm 1 and reply 0."""
    reply = sm.reply_frame(sm.MotionReply(0, 0, 200101, 0, 0, ()))
    assert struct.unpack_from("<iiii", reply) == (72, 2002, 3, 1)
    topic = sm.topic_frame(sm.RobotStatus(1, 0, 0, 0, 0, 2, 1))
    assert struct.unpack_from("<iiii", topic) == (40, 13, 1, 0)


# ---------------------------------------------------------------- refusals
GOOD_POINT = frame(14, ints(0, 1, 7) + floats(0.0, *(0.0,) * 30))


def refusal(data: bytes, dialect: sm.Dialect = sm.UPSTREAM) -> sm.MotorosError:
    with pytest.raises(sm.MotorosError) as info:
        sm.decode(data, dialect)
    return info.value


def test_bad_length_prefix_names_the_field() -> None:
    bad = struct.pack("<i", 999) + GOOD_POINT[4:]
    exc = refusal(bad)
    assert exc.field == "length" and "999" in exc.reason and exc.subcode == 3001


def test_unknown_type() -> None:
    exc = refusal(frame(4242, b""))
    assert exc.field == "msg_type" and "4242" in exc.reason and exc.subcode == 3003
    # the fork knows no _EX messages
    assert refusal(frame(2016, ints(1, 0) + bytes(168)), sm.CLOPEMA).subcode == 3003


def test_truncated_body() -> None:
    short = struct.pack("<i", 148) + GOOD_POINT[4:100]
    exc = refusal(short)
    assert exc.subcode == 3001 and exc.field in ("pos", "vel", "acc", "length")


def test_frame_shorter_than_a_header() -> None:
    assert refusal(b"\x0c\x00\x00\x00\x01\x00").field == "header"


@pytest.mark.parametrize("count", [-1, 0, 5, 2**31 - 1])
def test_group_count_out_of_range(count: int) -> None:
    exc = refusal(frame(2016, ints(count, 0) + bytes(132)))
    assert exc.field == "numberOfValidGroups" and str(count) in exc.reason and exc.subcode == 3004


def test_feedback_ex_group_count_out_of_range() -> None:
    exc = refusal(frame(2017, ints(-3) + bytes(4 * 132), comm=1))
    assert exc.field == "numberOfValidGroups"


def test_trailing_bytes_are_refused() -> None:
    exc = refusal(GOOD_POINT + b"\x00\x00\x00\x00")
    assert exc.field == "length"


def test_too_many_values_for_the_slots() -> None:
    with pytest.raises(sm.MotorosError) as info:
        sm.encode(sm.JointFeedback(0, 2, 0.0, (0.0,) * 11, (), ()))
    assert info.value.field == "positions"


# ---------------------------------------------------------------- framer
def test_framer_reassembles_partial_reads() -> None:
    stream = GOOD_POINT + frame(1, b"") + frame(2001, ints(0, 1, 200101) + floats(*(0.0,) * 10))
    framer = sm.Framer()
    out = []
    for k in range(len(stream)):
        out += framer.frames(stream[k:k + 1])
    assert out == [GOOD_POINT, frame(1, b""), frame(2001, ints(0, 1, 200101) + floats(*(0.0,) * 10))]
    assert framer.pending == 0


def test_framer_splits_a_chunk_of_several_frames() -> None:
    framer = sm.Framer()
    assert framer.frames(GOOD_POINT * 3 + GOOD_POINT[:20]) == [GOOD_POINT] * 3
    assert framer.pending == 20
    assert framer.frames(GOOD_POINT[20:]) == [GOOD_POINT]


def test_framer_group_count_of_2016_sets_its_size() -> None:
    pt = frame(2016, ints(2, 1) + bytes(264))
    framer = sm.Framer()
    assert framer.frames(pt[:20]) == []
    assert framer.frames(pt[20:]) == [pt]


def test_framer_refuses_what_it_cannot_frame() -> None:
    framer = sm.Framer()
    with pytest.raises(sm.MotorosError) as info:
        framer.frames(frame(77, b""))
    assert info.value.subcode == 3003
    framer.clear()
    with pytest.raises(sm.MotorosError) as info:
        framer.frames(frame(2016, ints(-1, 1)))
    assert info.value.subcode == 3004
