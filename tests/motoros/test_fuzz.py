"""The decoder and the framer against random bytes and mutated valid frames: a frame decodes or is
refused with a `MotorosError` naming a field, never another exception (the server answers the error)."""

from __future__ import annotations

import os
import struct

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.motoros import messages as sm

FUZZ = settings(max_examples=int(os.environ.get("FOLDCELL_FUZZ_EXAMPLES", "150")), deadline=None,
                derandomize=not os.environ.get("FOLDCELL_FUZZ_EXAMPLES"),
                suppress_health_check=[HealthCheck.too_slow])
DIALECTS = st.sampled_from([sm.UPSTREAM, sm.CLOPEMA])
TYPES = st.sampled_from(sorted(sm.MsgType))


def decoded_or_refused(data: bytes, dialect: sm.Dialect) -> None:
    try:
        message = sm.decode(data, dialect)
    except sm.MotorosError as exc:
        assert exc.field and exc.reason and exc.subcode in (3001, 3003, 3004)
        return
    # the same size back (bytes may differ: a signalling NaN comes back quiet)
    assert len(sm.encode(message.body, dialect, message.comm_type, message.reply_code)) == len(data)


@FUZZ
@given(st.binary(max_size=700), DIALECTS)
def test_random_bytes(data: bytes, dialect: sm.Dialect) -> None:
    decoded_or_refused(data, dialect)


@FUZZ
@given(TYPES, st.integers(0, 3), st.binary(max_size=700), st.integers(-8, 8), DIALECTS)
def test_a_valid_header_with_a_random_body(msg_type: int, comm: int, body: bytes, length_error: int,
                                           dialect: sm.Dialect) -> None:
    data = struct.pack("<iiii", 12 + len(body) + length_error, msg_type, comm, 0) + body
    decoded_or_refused(data, dialect)
    framer = sm.Framer(dialect)
    try:
        for frame in framer.frames(data):
            decoded_or_refused(frame, dialect)
    except sm.MotorosError as exc:
        assert exc.subcode in (3001, 3003, 3004)
