"""Property-based fuzzing of every decoder on the wire: whatever bytes arrive (random, a valid message
cut short, flipped or extended, another type's message), a decoder answers with a message or a
`WireError` naming the key, never another exception; the controller's cheap look at a command's code
(its e-stop and renewal lane) never fails at all.

`make test` runs 150 derandomized cases per property (the same every run); FOLDCELL_FUZZ_EXAMPLES=N
runs N random ones (1500 found nothing more after the quaternion-norm overflow this fuzzer caught)."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers.controller import codec
from drivers.wire import messages
from drivers.wire.messages import WireError
from tests.wire.fuzz_payloads import TYPES, payloads, valid_payload

CDR_HEADER = b"\x00\x01\x00\x00"
FUZZ = settings(max_examples=int(os.environ.get("FOLDCELL_FUZZ_EXAMPLES", "150")), deadline=None,
                derandomize=not os.environ.get("FOLDCELL_FUZZ_EXAMPLES"),
                suppress_health_check=[HealthCheck.too_slow])


def _decodes_or_refuses(type_name: str, payload: bytes) -> None:
    try:
        messages.decode(type_name, payload, "fuzz/key")
    except WireError as err:
        assert "fuzz/key" in str(err), err


@pytest.mark.parametrize("type_name", TYPES)
@FUZZ
@given(body=st.binary(max_size=512), headed=st.booleans())
def test_random_bytes_decode_or_are_refused(type_name: str, body: bytes, headed: bool) -> None:
    _decodes_or_refuses(type_name, (CDR_HEADER if headed else b"") + body)


@pytest.mark.parametrize("type_name", TYPES)
@FUZZ
@given(data=st.data())
def test_mutated_valid_messages_decode_or_are_refused(type_name: str, data: st.DataObject) -> None:
    _decodes_or_refuses(type_name, data.draw(payloads(type_name)))


@FUZZ
@given(payload=st.binary(max_size=256), seed=st.integers(0, 2**16), cut=st.integers(0, 200))
def test_the_command_code_look_never_fails(payload: bytes, seed: int, cut: int) -> None:
    assert codec.command_code(payload) is None or isinstance(codec.command_code(payload), int)
    valid = valid_payload(codec.COMMAND_TYPE, seed)
    decoded = messages.decode(codec.COMMAND_TYPE, valid)
    assert codec.command_code(valid) == decoded.command   # the look agrees with the decoder
    look = codec.command_code(valid[:cut])
    assert look is None or look == decoded.command
