"""Rate limits on queryables: a stranger's flood of commands is refused at the door with the key and the
limit, while the e-stop and the lease renewals (the urgent lane) still go through and the lease holder
(known by its credential) is served all along. A real controller process, a real second Zenoh session
flooding it."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Any

import pytest
import yaml

from drivers.common.configfile import ConfigError, config_dir
from drivers.controller import codec
from drivers.controller.codes import Command
from drivers.controller.zenoh_client import ZenohController
from drivers.wire import messages
from drivers.wire.limits import load_query_rates
from drivers.wire.registry import KEYS, query_rate, spec_for
from drivers.wire.transport import REFUSAL_ENCODING, Wire, cdr_encoding
from tests.conftest import Endpoint, Proc, foldcell_argv, wait_until

KEY = "controller/command"
COMMAND_TYPE = "foldcell_msgs/msg/ControllerCommand"
FLOOD_S = 1.5                # long enough for several lease renewals (every 0.1 s) under the flood


class Flood:
    """A stranger's session sending status-query commands as fast as it can, without waiting for answers."""

    def __init__(self, wire: Wire):
        self.wire = wire
        self.lock = threading.Lock()
        self.sent = 0
        self.answered = 0
        self.last_answer = time.monotonic()
        self.refusals: list[str] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="flood", daemon=True)

    def _on_reply(self, reply: Any) -> None:
        with self.lock:
            self.answered += 1
            self.last_answer = time.monotonic()
            if reply.err is not None and reply.err.encoding == REFUSAL_ENCODING:
                self.refusals.append(reply.err.payload.to_string())

    def _run(self) -> None:
        key = self.wire.key(KEY)
        payload = messages.encode(COMMAND_TYPE, codec.command_msg(Command.CHECK_QUEUE_CNT, "alive/stranger"))
        while not self.stop.is_set():
            self.wire.session.get(key, self._on_reply, payload=payload, encoding=cdr_encoding(COMMAND_TYPE),
                                  timeout=30)
            with self.lock:
                self.sent += 1

    def quiet_for(self) -> float:
        """Seconds since the last answer came."""
        with self.lock:
            return time.monotonic() - self.last_answer

    def refused(self) -> int:
        with self.lock:
            return len(self.refusals)


@pytest.fixture
def controller(tmp_path):
    endpoint = Endpoint("ratelimit")
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", *endpoint.args()),
                tmp_path / "serve.log")
    wire = Wire(endpoint.settings(), "operator")
    ctl = ZenohController(wire)
    try:
        ctl.connect(timeout=60)
        ctl.acquire_lease()
        yield endpoint, ctl
    finally:
        wire.close()
        proc.stop()


def test_a_flood_is_refused_while_the_estop_and_the_lease_holder_get_through(controller):
    endpoint, ctl = controller
    rate = query_rate(spec_for(KEY))
    # the status stream carries the grant on its next tick, not at once
    assert ctl.wait_status(lambda s: s.lease_holder == ctl.client, 10) is not None, ctl.status()
    with Wire(endpoint.settings(), "stranger") as stranger:
        flood = Flood(stranger)
        started = time.monotonic()
        flood.thread.start()
        try:
            # the bucket is empty once the first refusal comes back; the e-stop goes in while it stays so
            assert wait_until(lambda: flood.refused() > 0, 30), "the flood was never refused"
            ctl.command(Command.ESTOP)
            assert ctl.wait_status(lambda s: s.e_stopped, 5) is not None
            flooding_until = time.monotonic() + FLOOD_S
            refused_before = flood.refused()
            for _ in range(20):   # the holder's own commands: none refused for the stranger's flood
                ctl.command(Command.CHECK_QUEUE_CNT)
            ctl.command(Command.ESTOP_RESET)
            assert flood.refused() > refused_before, "the flood was not on while the holder was served"
            assert wait_until(lambda: time.monotonic() >= flooding_until, FLOOD_S + 5)
        finally:
            flood.stop.set()
            flood.thread.join()
        # a flood may lose a few queries on the way (Zenoh drops when a queue is full): wait for
        # every answer, or until none has come for 3 s
        assert wait_until(lambda: flood.answered == flood.sent or flood.quiet_for() > 3.0, 30)
        answered_by = time.monotonic()
        assert flood.answered >= 0.99 * flood.sent, (flood.answered, flood.sent)
    # every request let through was let through between the first sent and the last answered
    served = flood.answered - flood.refused()
    assert served <= rate.burst + rate.per_second * (answered_by - started), (served, flood.sent)
    assert flood.refused() > flood.answered // 2, (flood.refused(), flood.answered)
    full_key = ctl.wire.key(KEY)
    expected = (f"{full_key}: over the rate limit of {rate.per_second:g} requests a second "
                f"(bursts of {rate.burst}); refused, not run")
    assert set(flood.refusals) == {expected}
    # the renewals went through the flood: the lease is still ours
    assert ctl.wait_status(lambda s: s.lease_holder == ctl.client, 10) is not None, ctl.status()
    assert ctl.wait_status(lambda s: not s.e_stopped, 5) is not None


def test_every_queryable_has_a_rate_and_a_bad_one_is_named(tmp_path: Path):
    queryables = [spec.pattern for spec in KEYS if spec.kind == "queryable"]
    assert set(load_query_rates(queryables)) == set(queryables)
    shipped = yaml.safe_load((config_dir() / "limits.yaml").read_text())
    cases: list[tuple[dict[str, Any], str, str]] = [
        ({"camera/capture": None}, "query_rates.camera/capture", "missing"),
        ({"camera/capture": {"per_second": 0, "burst": 30}}, "query_rates.camera/capture.per_second",
         "must be > 0"),
        ({"camera/capture": {"per_second": 30, "burst": "many"}}, "query_rates.camera/capture.burst",
         "must be an integer"),
        ({"camera/image": {"per_second": 1, "burst": 1}}, "query_rates.camera/image", "unknown field"),
    ]
    for change, field, reason in cases:
        rates = {**shipped["query_rates"], **change}
        (tmp_path / "limits.yaml").write_text(yaml.safe_dump(
            {**shipped, "query_rates": {key: rate for key, rate in rates.items() if rate is not None}}))
        with pytest.raises(ConfigError) as err:
            load_query_rates(queryables, tmp_path)
        assert f"{field}: {reason}" in str(err.value), str(err.value)
