"""A failed query is typed by what went wrong: nobody serves the key, the server refused it, or no reply
came in time. Real Zenoh sessions on loopback."""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

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


def test_zenohs_own_timeout_reply_from_the_servers_session_is_no_reply(endpoint):
    """What the server's session sends when its end of a query times out (seen on the wire: payload
    'Timeout', encoding zenoh/bytes, the session as replier), sent here at once and deterministically."""
    server = Wire(endpoint.settings(), "server", announce=False)

    def time_out(query: zenoh.Query) -> None:
        query.reply_err(b"Timeout", encoding=zenoh.Encoding.ZENOH_BYTES)
        query.drop()

    queryable = server.session.declare_queryable(server.key(KEY), time_out)
    server.announce()
    try:
        with Wire(endpoint.settings(), "asker") as asker:
            assert wait_until(lambda: any(k.endswith("alive/server") for k in asker.alive()), 10)
            with pytest.raises(NoReply):
                asker.request(KEY, request(), timeout=30.0)
    finally:
        queryable.undeclare()
        server.close()


def test_silence_is_no_reply(endpoint):
    """Zenoh's timeout comes as an error reply from the asker's session or the server's, whichever
    fires first; both are a timeout, not a refusal."""
    release = threading.Event()

    def hang(msg: object, info: RequestInfo) -> object:
        release.wait(60.0)
        raise TimeoutError("released")

    try:
        with served(endpoint, hang), Wire(endpoint.settings(), "asker") as asker:
            assert wait_until(lambda: any(k.endswith("alive/server") for k in asker.alive()), 10)
            for timeout in (0.5, 0.8, 1.1, 1.4, 1.7):
                with pytest.raises(NoReply, match=f"no reply within {timeout:g} s"):
                    asker.request(KEY, request(), timeout=timeout)
    finally:
        release.set()
