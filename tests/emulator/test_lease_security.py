"""The control lease against the cell's neighbours: a real controller process (`foldcell controller serve
--role both`) commanded by a client holding the lease, beside an operator's client, a stranger's raw Zenoh
session serving the controller's own key, and a hung holder. Every verdict is read from the controller's
side of the wire: its replies, its status and its joint stream."""

from __future__ import annotations

import logging
import re
import subprocess
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field

import pytest
import zenoh

from drivers.controller import codec
from drivers.controller.codes import Command, Mode, Reply, Result, Subcode
from drivers.controller.credential import Credential, PinnedKey, ReplayWindow, Signer
from drivers.controller.errors import LeaseHeld
from drivers.controller.interface import MotionStatus
from drivers.controller.zenoh_client import ZenohController
from drivers.emulator.commands import EmulatorCommand
from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.conftest import REPO, Endpoint, Proc, foldcell_argv, request_once_served, wait_until
from tests.emulator.test_process import CFG, NAMES, Recorder, make_ready, still_for

COMMAND_TYPE = "foldcell_msgs/msg/ControllerCommand"
REPLY_TYPE = "foldcell_msgs/msg/MotionReply"
KEY = "foldcell/t/controller/command"


# ---------------------------------------------------------------- the credential, without a wire
def test_a_signature_covers_the_name_the_sequence_the_key_and_the_payload() -> None:
    signer = Signer("alive/cell")
    payload = b"\x00\x01 a command"
    credential = Credential.from_attachment(signer.attachment(KEY, payload))
    pin = PinnedKey("alive/cell", signer.public_key)
    assert pin.vouches(credential, KEY, payload)
    assert not pin.vouches(credential, KEY.replace("command", "trajectory"), payload)
    assert not pin.vouches(credential, KEY, payload + b"!")
    assert not PinnedKey("alive/cell", Signer("alive/cell").public_key).vouches(credential, KEY, payload)
    attachment = signer.attachment(KEY, payload)
    renamed = Credential.from_attachment(attachment.replace(b"alive/cell", b"alive/celm"))
    assert not PinnedKey("alive/celm", signer.public_key).vouches(renamed, KEY, payload)
    assert pin.admits(credential, KEY, payload)
    assert not pin.admits(credential, KEY, payload), "the same signed request was admitted twice"


def test_an_unreadable_attachment_is_an_empty_credential_not_an_error() -> None:
    negative = b"alive/cell\n-1\n" + b"00" * 32 + b"\n" + b"00" * 64
    for data in (b"", b"alive/cell", b"alive/cell\n1\nzz\nzz", negative, b"x" * 600, bytes(range(256))):
        credential = Credential.from_attachment(data)
        assert not credential.signature, data
        assert not PinnedKey(credential.client, b"k").vouches(credential, KEY, b"")


def test_the_replay_window_takes_each_number_once_in_any_order_and_none_too_old() -> None:
    window = ReplayWindow()
    assert window.admit(5) and window.admit(3) and window.admit(4)   # threads overtake each other
    assert not window.admit(5) and not window.admit(3)
    assert window.admit(5 + ReplayWindow.SIZE)
    assert not window.admit(5), "a number below the window was admitted"
    for n in range(6 + ReplayWindow.SIZE, 6 + 4 * ReplayWindow.SIZE):
        assert window.admit(n)
    assert len(window.seen) <= 2 * ReplayWindow.SIZE + 1


# ---------------------------------------------------------------- a controller and its neighbours
@pytest.fixture(scope="module")
def cell(tmp_path_factory):
    ep = Endpoint("leasesec")
    proc = Proc(foldcell_argv("controller", "serve", "--role", "both", "--time-scale", "4", *ep.args()),
                tmp_path_factory.mktemp("lease") / "serve.log")
    wire = Wire(ep.settings(), "holder")
    ctl = ZenohController(wire)
    try:
        ctl.connect(timeout=30)
        ctl.acquire_lease()
        make_ready(ctl)
        yield ep, wire, ctl, Recorder(wire)
    finally:
        wire.close()
        proc.stop()


@pytest.fixture
def operator(cell) -> Iterator[ZenohController]:
    ep = cell[0]
    wire = Wire(ep.settings(), "operator")
    ctl = ZenohController(wire)
    try:
        ctl.connect(timeout=30)
        yield ctl
    finally:
        wire.close()


LEASED = [
    (EmulatorCommand.FAULT_FREEZE_FEEDBACK_ON, ()), (EmulatorCommand.FAULT_ALARM_ON, ()),
    (EmulatorCommand.FAULT_REPLY_LATENCY_ON, (0.5, 0.0)), (EmulatorCommand.FAULT_SLOW_LOOP_ON, (2.0,)),
    (EmulatorCommand.FAULT_DROP_SLAVE_LINK_ON, ()), (EmulatorCommand.FAULT_ALARM_OFF, ()),
    (EmulatorCommand.FAULT_SLOW_LOOP_OFF, ()), (EmulatorCommand.PENDANT_TEACH, ()),
    (EmulatorCommand.PENDANT_REMOTE_OFF, ()), (EmulatorCommand.PENDANT_PLAY, ()),
]


def test_an_operator_without_the_lease_can_neither_inject_a_fault_nor_switch_the_pendant(cell, operator):
    """While the holder (another process) holds the lease, every fault and pendant command of an operator
    is refused, naming the holder, and the controller's status shows none of them; the operator's e-stop
    still stops the robot. With no holder, the operator must take the lease first, as for motion."""
    ep, _, ctl, _ = cell
    make_ready(ctl)
    for code, values in LEASED:
        with pytest.raises(LeaseHeld, match="alive/holder"):
            operator.command(code, values=values)
    status = ctl.status_message()
    assert not status.faults, status.faults
    assert ctl.status().motion_possible and ctl.status().mode == Mode.AUTO, ctl.status()
    flags = ["--cell", ep.cell, "--listen", "tcp/127.0.0.1:0", "--connect", ep.url]
    done = subprocess.run(foldcell_argv("controller", "fault", "freeze-feedback", "on", *flags), cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 1 and "alive/holder" in done.stderr and "lease" in done.stderr, done.stderr
    assert not ctl.status_message().faults
    operator.command(Command.ESTOP)
    assert ctl.wait_status(lambda s: s.e_stopped, 10), ctl.status()
    ctl.release_lease()
    try:
        with pytest.raises(LeaseHeld, match="acquire the control lease first"):
            operator.command(EmulatorCommand.FAULT_ALARM_ON)
        assert not ctl.status().error_code and not ctl.status().faults
    finally:
        ctl.acquire_lease()
    make_ready(ctl)


@dataclass
class Stranger:
    """A raw Zenoh session that serves `controller/command` too, claiming to be complete, answers every
    request at once with a refusal, and keeps what it received."""

    session: zenoh.Session
    key: str
    caught: list[tuple[bytes, bytes]] = field(default_factory=list)   # (payload, attachment)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def answer(self, query: zenoh.Query) -> None:
        payload = query.payload.to_bytes() if query.payload is not None else b""
        attachment = query.attachment.to_bytes() if query.attachment is not None else b""
        with self.lock:
            self.caught.append((payload, attachment))
        refusal = codec.reply_msg(Reply(Result.FAILURE, Subcode.LEASE_HELD, "the stranger says no"), 1)
        query.reply(self.key, messages.encode(REPLY_TYPE, refusal, self.key))

    def requests(self, code: int) -> list[tuple[bytes, bytes]]:
        with self.lock:
            caught = list(self.caught)
        return [(p, a) for p, a in caught if messages.decode(COMMAND_TYPE, p, self.key).command == code]


def raw_session(ep: Endpoint) -> zenoh.Session:
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("listen/endpoints", '["tcp/127.0.0.1:0"]')
    conf.insert_json5("connect/endpoints", f'["{ep.url}"]')
    return zenoh.open(conf)


def send_again(session: zenoh.Session, key: str, payload: bytes, attachment: bytes) -> list[Reply]:
    """A request sent as caught (to every queryable but the sender's own); the replies it got."""
    replies = session.get(key, payload=payload, attachment=attachment, timeout=5,
                          target=zenoh.QueryTarget.ALL, allowed_destination=zenoh.Locality.REMOTE)
    return [codec.reply_from_msg(messages.decode(REPLY_TYPE, r.ok.payload.to_bytes(), key))
            for r in replies if r.ok is not None]


def test_a_stranger_serving_the_controllers_key_catches_nothing_usable_and_stops_nothing(
        cell, caplog: pytest.LogCaptureFixture):
    """On an open cell a stranger serves `controller/command` beside the controller and receives the
    holder's requests. The holder's commands still succeed (its client counts only the controller that
    granted its lease, and names the stranger in its log); every request the stranger replays, as caught
    or with a payload of its own, is refused and moves nothing (the joint stream), and the holder keeps
    the lease."""
    ep, wire, ctl, rec = cell
    make_ready(ctl)
    caplog.set_level(logging.ERROR, logger="drivers.wire.transport")
    session = raw_session(ep)
    stranger = Stranger(session, wire.key("controller/command"))
    # complete: it claims to answer for the whole key, which a best-match query would then ask alone
    queryable = session.declare_queryable(stranger.key, stranger.answer, complete=True)
    try:
        assert wait_until(lambda: len(stranger.requests(Command.LEASE_RENEW)) >= 2, 20), stranger.caught
        joint = NAMES[0]
        q0 = ctl.joint_state().positions.copy()
        assert ctl.jog(joint, 0.05).wait(30) == MotionStatus.SUCCEEDED
        q1 = ctl.joint_state().positions.copy()
        assert q1[0] == pytest.approx(q0[0] + 0.05, abs=CFG.goal_tolerance)
        stranger_id = str(session.info.zid())
        assert any(stranger_id in r.getMessage() for r in caplog.records), "the stranger was not named"
        caught = stranger.requests(Command.JOG) + stranger.requests(Command.LEASE_RENEW)[-2:]
        assert len(caught) == 3, caught
        queryable.undeclare()
        jog_attachment = caught[0][1]
        forged = messages.encode(COMMAND_TYPE, codec.command_msg(Command.JOG, ctl.client, joint=joint,
                                                                 values=(0.3,)), stranger.key)
        for payload, attachment in [*caught, (forged, jog_attachment)]:
            replies = send_again(session, stranger.key, payload, attachment)
            assert len(replies) == 1, replies   # the controller's
            assert not replies[0].ok, replies[0]
        still_for(rec, q1, 0.8)
        assert ctl.status().lease_holder == "alive/holder"
        assert ctl.jog(joint, -0.05).wait(30) == MotionStatus.SUCCEEDED   # the holder still commands
    finally:
        session.close()


def test_a_hung_holder_loses_the_lease_after_the_silence_timeout_whatever_reply_latency_it_injected(cell):
    """A holder injects a reply latency longer than the watchdog's timeout, then sends nothing: the
    controller drops its lease after `lease.silence_timeout` of silence, as it measured it, not that
    plus the latency. (Last in the module: the controller answers late from here on.)"""
    ep, _, ctl, _ = cell
    latency = 4.0
    silence = CFG.lease_silence_timeout
    ctl.release_lease()
    hung = Wire(ep.settings(), "hung")
    signer = Signer("alive/hung")
    try:
        acquired = request_once_served(hung, "controller/command",
                                       codec.command_msg(Command.LEASE_ACQUIRE, "alive/hung"), timeout=10,
                                       sign=signer.attachment)
        assert acquired.result == Result.SUCCESS, acquired.text
        injected = hung.request("controller/command", codec.command_msg(
            EmulatorCommand.FAULT_REPLY_LATENCY_ON, "alive/hung", values=(latency, 0.0)), timeout=2 * latency,
            sign=signer.attachment)
        assert injected.result == Result.SUCCESS, injected.text
        status = ctl.wait_status(lambda s: s.lease_holder == "" and "alive/hung" in s.lease_note, 60)
        assert status is not None, ctl.status()
        found = re.search(r"sent nothing for ([0-9.]+) s", status.lease_note)
        assert found is not None, status.lease_note
        assert silence <= float(found.group(1)) < silence + latency / 2, status.lease_note
    finally:
        hung.close()
