"""Fuzz payloads for a decoder or a queryable that takes `type_name`: random bytes, a valid message cut
short, bit-flipped or extended, or another type's valid message (hypothesis strategies)."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st

from drivers.wire import messages
from tests.wire.examples import random_message, registry_types

TYPES = registry_types()


def valid_payload(type_name: str, seed: int) -> bytes:
    return messages.encode(type_name, random_message(type_name, np.random.default_rng(seed)), "fuzz/key")


@st.composite
def payloads(draw: st.DrawFn, type_name: str) -> bytes:
    """Random bytes, or a valid `type_name` message cut, flipped or extended, or another type's."""
    kind = draw(st.sampled_from(["bytes", "cut", "flip", "extend", "other"]))
    if kind == "bytes":
        return draw(st.binary(max_size=2048))
    seed = draw(st.integers(0, 2**16))
    if kind == "other":
        return valid_payload(draw(st.sampled_from(TYPES)), seed)
    payload = bytearray(valid_payload(type_name, seed))
    if kind == "cut":
        return bytes(payload[:draw(st.integers(0, max(len(payload) - 1, 0)))])
    if kind == "flip":
        for _ in range(draw(st.integers(1, 8))):
            index = draw(st.integers(0, len(payload) - 1))
            payload[index] ^= 1 << draw(st.integers(0, 7))
        return bytes(payload)
    return bytes(payload + draw(st.binary(min_size=1, max_size=256)))
