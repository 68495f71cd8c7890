"""A failed query is typed by what went wrong: nobody serves the key, the server refused it, or no reply
came in time. Real Zenoh sessions on loopback."""

from __future__ import annotations

import threading
import time

import pytest

from drivers.wire import messages
from drivers.wire.messages import ErrorReply, NobodyServes, NoReply, WireError
from drivers.wire.transport import RequestInfo, Wire
from tests.conftest import wait_until

KEY = "controller/command"
TYPE = "foldcell_msgs/msg/ControllerCommand"


def request() -> object:
    return messages.new(TYPE, header=messages.header(), command=200101, client="alive/asker")


def served(endpoint, handler) -> Wire:
    """A session serving KEY with `handler`, alive (and so routed) once the caller sees its token."""
    server = Wire(endpoint.settings(), "server", announce=False)
    server.serve(KEY, handler)
    server.announce()
    return server


def test_nobody_serves_is_told_at_once(endpoint):
    with Wire(endpoint.settings(), "asker") as asker:
        started = time.monotonic()
        with pytest.raises(NobodyServes, match="nobody serves"):
            asker.request(KEY, request(), timeout=30.0)
        assert time.monotonic() - started < 15.0  # not the timeout: Zenoh ends the query at once


def test_a_refusal_is_an_error_reply_carrying_the_servers_text(endpoint):
    def refuse(msg: object, info: RequestInfo) -> object:
        raise ValueError("values[0] is nan, must be finite")

    with served(endpoint, refuse) as server, Wire(endpoint.settings(), "asker") as asker:
        assert wait_until(lambda: any(k.endswith("alive/server") for k in asker.alive()), 10)
        with pytest.raises(ErrorReply) as err:
            asker.request(KEY, request(), timeout=10.0)
        assert isinstance(err.value, WireError)
        assert "values[0] is nan" in err.value.remote and server.key(KEY) in err.value.remote


def test_silence_is_no_reply(endpoint):
    release = threading.Event()

    def hang(msg: object, info: RequestInfo) -> object:
        release.wait(30.0)
        raise TimeoutError("released")

    try:
        with served(endpoint, hang), Wire(endpoint.settings(), "asker") as asker:
            assert wait_until(lambda: any(k.endswith("alive/server") for k in asker.alive()), 10)
            with pytest.raises(NoReply, match="no reply within 1 s"):
                asker.request(KEY, request(), timeout=1.0)
            release.set()
    finally:
        release.set()
