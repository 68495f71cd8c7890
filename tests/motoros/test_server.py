"""The MotoROS server over real loopback TCP, driven by the test's own client (tests/motoros/client.py,
written from the facts): the state stream, a small move, START_POS, BUSY and retries, malformed input,
a client killed mid-motion, the e-stop, the connection slots; both dialects."""

from __future__ import annotations

import socket
import struct
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
import pytest
import yaml

from drivers.controller.codes import Command
from drivers.controller.config import default_controller_config
from drivers.emulator.core import ControllerCore
from drivers.emulator.motoros_server import MotorosServer
from drivers.motoros.config import load_motoros_config
from drivers.robot.config import default_robot_config
from tests.conftest import REPO
from tests.motoros import client as mc
from tests.motoros.core_loop import CoreLoop

# an exception in a server thread fails the test that caused it
pytestmark = pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")

# the facts: 30 pulses start tolerance (section 7); config/motoros.yaml: 10000 pulses per radian
PULSE = 1.0e-4
GOAL_TOLERANCE = 1.0e-4  # rad; the feedback is float32


@dataclass
class Cell:
    core: ControllerCore
    lock: threading.RLock
    server: MotorosServer

    @property
    def motion_port(self) -> int:
        return self.server.ports[0]

    @property
    def state_port(self) -> int:
        return self.server.ports[1]

    def q(self) -> np.ndarray:
        with self.lock:
            return self.core.q.copy()


def running(dialect: str) -> Iterator[Cell]:
    """An emulator core stepped in real time with a MotoROS server of `dialect` on free ports."""
    core = ControllerCore(default_robot_config(), default_controller_config(), "both")
    lock = threading.RLock()
    server = MotorosServer(core, lock, load_motoros_config(), port=0, dialect=dialect)
    server.start()
    loop = CoreLoop(core, lock, server.on_tick)
    loop.start()
    yield Cell(core, lock, server)
    loop.stop()
    server.close()


@pytest.fixture
def cell() -> Iterator[Cell]:
    yield from running("upstream")


@pytest.fixture
def fork() -> Iterator[Cell]:
    yield from running("clopema")


class Clients:
    """Opens the test's clients and closes them all at teardown."""

    def __init__(self) -> None:
        self.opened: list[mc.MotionClient | mc.StateReader] = []

    def motion(self, port: int, slots: int = 10) -> mc.MotionClient:
        self.opened.append(mc.MotionClient(port, slots))
        return self.opened[-1]  # type: ignore[return-value]

    def state(self, port: int, slots: int = 10) -> mc.StateReader:
        self.opened.append(mc.StateReader(port, slots))
        return self.opened[-1]  # type: ignore[return-value]


@pytest.fixture
def clients() -> Iterator[Clients]:
    out = Clients()
    yield out
    for client in out.opened:
        client.close()


def ready(client: mc.MotionClient) -> None:
    reply = client.ctrl(mc.START_TRAJ_MODE)
    assert (reply.result, reply.subcode) == (mc.SUCCESS, 0)
    assert client.ctrl(mc.CHECK_MOTION_READY).result == mc.SUCCESS


def stream(client: mc.MotionClient, group: int, times: list[float], positions: np.ndarray,
           velocities: np.ndarray) -> int:
    """Send every point, resending on BUSY (the ROS client retries every ~5 ms); returns the BUSY count."""
    busy = 0
    for seq, (t, p, v) in enumerate(zip(times, positions, velocities, strict=True)):
        while True:
            reply = client.point(group, seq, t, p, v)
            assert (reply.command, reply.sequence, reply.group) == (14, seq, group)
            if reply.result != mc.BUSY:
                break
            busy += 1
            time.sleep(0.005)
        assert (reply.result, reply.subcode) == (mc.SUCCESS, 0), f"point {seq}: {reply}"
    return busy


def rest_to_rest(start: np.ndarray, goal: np.ndarray, duration: float,
                 count: int) -> tuple[list[float], np.ndarray, np.ndarray]:
    """Points of a cosine blend from start to goal (velocities consistent, zero at both ends)."""
    times = np.linspace(0.0, duration, count)
    s = 0.5 - 0.5 * np.cos(np.pi * times / duration)
    ds = 0.5 * np.pi / duration * np.sin(np.pi * times / duration)
    positions = start + np.outer(s, goal - start)
    velocities = np.outer(ds, goal - start)
    velocities[-1] = 0.0
    return list(times), positions, velocities


def r1(cell: Cell) -> np.ndarray:
    return cell.q()[:6]


# ---------------------------------------------------------------- state stream
def test_state_stream_sends_feedback_per_group_then_ex_then_status(cell: Cell, clients: Clients) -> None:
    state = clients.state(cell.state_port)
    assert state.wait_bursts(4)
    with state.lock:
        frames = list(state.frames)
    first = [f[0] for f in frames].index(15)
    burst = frames[first:first + 5]
    # section 9: JOINT_FEEDBACK per group (R1, R2, turn-table), the _EX message, ROBOT_STATUS
    assert [f[0] for f in burst] == [15, 15, 15, 2017, 13]
    assert [f[1] for f in burst] == [148, 148, 148, 548, 44]
    assert all(f[2] == 1 for f in burst)  # topics
    assert state.status == (0, 0, 0, 0, 0, 2, 0)  # servos off, PLAY, not ready
    assert state.positions[0] == (0.0,) * 10  # home


def shipped_state_period() -> float:
    """config/motoros.yaml's `state_period` read as plain YAML, not through the loader the server uses."""
    return float(yaml.safe_load((REPO / "config" / "motoros.yaml").read_text())["state_period"])


def test_state_stream_rate_is_motoros_rate(cell: Cell, clients: Clients) -> None:
    """Section 9: a burst, then a pause of `state_period` (config/motoros.yaml: 25 ms; about 37 Hz
    measured). A busy machine only ever delays a burst, so each bound waits, as long as it takes, for a
    run of 20 gaps that shows it: the stream is never faster than a burst a pause (some run spans 20
    pauses, less half a pause of the reader's own jitter), and it keeps the configured rate (some run
    spans under 20 x 1.6 pauses: a stream 1.6 times slower or more never shows one; a loaded machine
    that delays bursts only makes the wait longer)."""
    pause = shipped_state_period()
    assert pause == pytest.approx(0.025)   # the facts (section 9): every 25 ms plus processing time
    gaps = 20
    state = clients.state(cell.state_port)

    def spans(s: mc.StateReader) -> np.ndarray:   # called holding the reader's lock
        arrived = np.array(s.status_times)
        return arrived[gaps:] - arrived[:-gaps] if len(arrived) > gaps else np.array([])

    never_faster = state.wait_for(lambda s: bool(np.any(spans(s) >= (gaps - 0.5) * pause)), 60)
    longest = float(np.max(spans(state), initial=0.0))
    assert never_faster, f"every run of {gaps} gaps spanned under {gaps} pauses of {pause} s: {longest:.3f} s"
    at_rate = state.wait_for(lambda s: bool(np.any(spans(s) < gaps * 1.6 * pause)), 60)
    shortest, bursts = float(np.min(spans(state), initial=np.inf)), len(state.status_times)
    assert at_rate, (f"every run of {gaps} gaps spanned {gaps} x 1.6 pauses of {pause} s or more: "
                     f"{shortest:.3f} s at least, over {bursts} bursts")


# ---------------------------------------------------------------- motion
def test_not_ready_until_trajectory_mode(cell: Cell, clients: Clients) -> None:
    client = clients.motion(cell.motion_port)
    reply = client.ctrl(mc.CHECK_MOTION_READY, sequence=42)
    # FALSE with the first NOT_READY subcode: servos are off (5006)
    assert (reply.result, reply.subcode, reply.sequence, reply.command) == (mc.FAILURE, 5006, 42, 200101)
    assert (reply.comm, reply.reply_code) == (3, 1)
    reply = client.point(0, 0, 0.0, [0.0] * 6, [0.0] * 6)
    assert (reply.result, reply.subcode) == (mc.NOT_READY, 5006)
    ready(client)
    assert client.ctrl(mc.CHECK_QUEUE_CNT, group=0).subcode == 0
    reply = client.ctrl(mc.CHECK_QUEUE_CNT, group=7)
    assert (reply.result, reply.subcode) == (mc.FAILURE, -1)


def test_small_move_reaches_its_goal(cell: Cell, clients: Clients) -> None:
    client, state = clients.motion(cell.motion_port), clients.state(cell.state_port)
    ready(client)
    goal = np.array([0.1, -0.05, 0.08, 0.0, 0.1, -0.1])
    times, positions, velocities = rest_to_rest(np.zeros(6), goal, 0.6, 4)
    assert stream(client, 0, times, positions, velocities) == 0
    assert state.wait_for(lambda s: np.allclose(s.positions.get(0, (9.0,) * 10)[:6], goal,
                                                atol=GOAL_TOLERANCE))
    assert state.wait_for(lambda s: s.status[4] == 0)  # in_motion off once the queue is empty
    assert np.allclose(r1(cell), goal, atol=1e-9)
    assert np.allclose(cell.q()[6:], 0.0)  # R2 and the turn-table stayed


def test_start_position_farther_than_30_pulses_is_refused_and_nothing_moves(cell: Cell,
                                                                           clients: Clients) -> None:
    client, state = clients.motion(cell.motion_port), clients.state(cell.state_port)
    ready(client)
    off = np.zeros(6)
    off[2] = 31 * PULSE
    reply = client.point(0, 0, 0.0, off, np.zeros(6))
    assert (reply.result, reply.subcode) == (mc.INVALID, 3011)
    # without a start point, a next point is not interpolated from anywhere
    reply = client.point(0, 1, 0.5, [0.2] * 6, [0.0] * 6)
    assert reply.result == mc.INVALID
    assert state.wait_bursts(10)
    assert np.array_equal(cell.q(), np.zeros(13))
    assert state.positions[0] == (0.0,) * 10
    assert client.ctrl(mc.CHECK_QUEUE_CNT, group=0).subcode == 0
    # within 29 pulses is the same place
    off[2] = 29 * PULSE
    assert client.point(0, 0, 0.0, off, np.zeros(6)).result == mc.SUCCESS


def test_full_queue_answers_busy_and_retries_deliver_every_point(cell: Cell, clients: Clients) -> None:
    client, state = clients.motion(cell.motion_port), clients.state(cell.state_port)
    ready(client)
    goal = np.array([0.4, 0.2, -0.3, 0.5, 0.3, -0.4])
    # 2.4 s of motion against a queue of 200 increments of 4 ms (0.8 s): the client runs ahead
    times, positions, velocities = rest_to_rest(np.zeros(6), goal, 2.4, 13)
    busy = stream(client, 0, times, positions, velocities)
    assert busy > 0
    assert client.ctrl(mc.CHECK_QUEUE_CNT, group=0).subcode > 0
    assert state.wait_for(lambda s: s.status[4] == 0 and np.allclose(s.positions[0][:6], goal,
                                                                     atol=GOAL_TOLERANCE))
    assert np.allclose(r1(cell), goal, atol=1e-9)


def test_two_groups_move_with_one_ex_message(cell: Cell, clients: Clients) -> None:
    client = clients.motion(cell.motion_port)
    ready(client)
    start = [0.0] * 6
    reply = client.request(mc.point_2016(0, [(0, 0.0, start, start), (2, 0.0, [0.0], [0.0])]))
    assert (reply.command, reply.result, reply.group) == (2016, mc.SUCCESS, 2)
    reply = client.request(mc.point_2016(1, [(0, 0.4, [0.0625] * 6, start), (2, 0.4, [0.125], [0.0])]))
    assert reply.result == mc.SUCCESS

    def arrived() -> bool:
        q = cell.q()
        return bool(np.allclose(q[:6], 0.0625, atol=1e-9) and abs(q[12] - 0.125) < 1e-9)

    deadline = time.monotonic() + 10.0
    while not arrived() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert arrived()


# ---------------------------------------------------------------- malformed input
def test_malformed_input_gets_the_protocols_error_and_others_are_served(cell: Cell, clients: Clients) -> None:
    state = clients.state(cell.state_port)
    bad = clients.motion(cell.motion_port)
    # unknown type: INVALID/3003, group -1, sequence -1, command = msg_type
    reply = bad.request(mc.frame(777, b""))
    assert (reply.result, reply.subcode, reply.group, reply.sequence, reply.command) == \
        (3, 3003, -1, -1, 777)
    # a REP message MotoROS 1 does not know
    assert bad.request(mc.frame(10, struct.pack("<i10f", 0, *([0.0] * 10)))).subcode == 3003
    # bad length prefix
    good = mc.motion_ctrl(mc.CHECK_MOTION_READY)
    assert bad.request(struct.pack("<i", 500) + good[4:]).subcode == 3001
    # truncated body: the rest never comes
    reply = bad.request(mc.point_14(0, 1, 0.5, [0.0] * 6, [0.0] * 6)[:60])
    assert (reply.result, reply.subcode) == (3, 3001)
    # a negative group count in a 2016
    reply = bad.request(mc.point_2016(1, [(0, 0.4, [0.0] * 6, [0.0] * 6)], count=-2))
    assert (reply.result, reply.subcode, reply.command) == (3, 3004, 2016)
    # after all that the same connection still works
    assert bad.ctrl(mc.CHECK_MOTION_READY).command == 200101
    # a message only a controller sends: the connection is closed, no reply (section 6)
    bad.sock.sendall(mc.frame(13, struct.pack("<7i", 0, 0, 0, 0, 0, 2, 0), comm=1))
    assert bad.closed_by_server()
    assert not state.error and state.wait_bursts(3)
    other = clients.motion(cell.motion_port)
    ready(other)


def test_random_bytes_never_stop_the_server(cell: Cell, clients: Clients) -> None:
    """Garbage on the motion port gets error replies or a closed connection; the next client is served."""
    rng = np.random.default_rng(17)
    for _ in range(8):
        garbage = clients.motion(cell.motion_port)
        garbage.sock.sendall(rng.integers(0, 256, int(rng.integers(1, 3000)), dtype=np.uint8).tobytes())
        garbage.close()
        fresh = clients.motion(cell.motion_port)
        assert fresh.ctrl(mc.CHECK_MOTION_READY).command == 200101
        fresh.close()
    assert np.array_equal(cell.q(), np.zeros(13))


def test_ping_is_answered_with_a_header(cell: Cell, clients: Clients) -> None:
    client = clients.motion(cell.motion_port)
    reply = client.request(mc.frame(1, b""))
    assert (reply.msg_type, reply.comm, reply.reply_code) == (1, 3, 1)


def test_bad_group_speed_sequence_time_and_fields(cell: Cell, clients: Clients) -> None:
    client = clients.motion(cell.motion_port)
    ready(client)
    zero = [0.0] * 6
    assert client.point(5, 0, 0.0, zero, zero).subcode == 3004
    assert client.request(mc.point_14(0, 0, 0.0, zero, zero, valid=3)).subcode == 3015
    assert client.point(0, 0, 14400.0, zero, zero).subcode == 3016
    assert client.point(0, -1, 0.0, zero, zero).subcode == 3005
    assert client.point(0, 0, 0.0, zero, [100.0, *zero[1:]]).subcode == 3013
    assert client.ctrl(999999).subcode == 3006
    assert client.request(mc.frame(2018, struct.pack("<iii", 2, 0, 1))).subcode == 3004  # turn-table
    assert client.request(mc.frame(2018, struct.pack("<iii", 0, 64, 1))).subcode == 3017
    assert client.request(mc.frame(2018, struct.pack("<iii", 1, 3, 1))).result == mc.SUCCESS


# ---------------------------------------------------------------- stops
def test_killing_the_client_mid_motion_stops_the_robot(cell: Cell, clients: Clients) -> None:
    client = clients.motion(cell.motion_port)
    goal = np.array([1.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    times, positions, velocities = rest_to_rest(np.zeros(6), goal, 3.0, 7)
    ready(client)
    for seq in range(3):  # 1 s of motion queued, more to come
        assert client.point(0, seq, times[seq], positions[seq], velocities[seq]).result == mc.SUCCESS
    deadline = time.monotonic() + 10.0
    while r1(cell)[0] < 0.01 and time.monotonic() < deadline:
        time.sleep(0.005)
    assert r1(cell)[0] >= 0.01, "the robot never started"
    client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    client.close()  # as a killed process: the connection resets
    state = clients.state(cell.state_port)
    assert state.wait_for(lambda s: len(s.status) == 7 and s.status[4] == 0)
    stopped = r1(cell)
    assert state.wait_bursts(8)
    assert np.array_equal(r1(cell), stopped)
    assert stopped[0] < positions[2][0] < goal[0]  # it stopped before the end of what was queued
    with cell.lock:
        assert cell.core.lease_holder == ""


def test_stop_motion_empties_the_queue(cell: Cell, clients: Clients) -> None:
    client = clients.motion(cell.motion_port)
    ready(client)
    times, positions, velocities = rest_to_rest(np.zeros(6), np.full(6, 0.3), 2.0, 3)
    stream(client, 0, times, positions, velocities)
    assert client.ctrl(mc.STOP_MOTION).result == mc.SUCCESS
    assert client.ctrl(mc.CHECK_QUEUE_CNT).subcode == 0
    assert client.ctrl(mc.STOP_TRAJ_MODE).result == mc.SUCCESS
    assert client.ctrl(mc.CHECK_MOTION_READY).subcode == 5008  # NOT_STARTED
    assert r1(cell)[0] < 0.3


def test_after_an_estop_nothing_moves_until_start_servos(cell: Cell, clients: Clients) -> None:
    client = clients.motion(cell.motion_port)
    ready(client)
    assert client.point(0, 0, 0.0, [0.0] * 6, [0.0] * 6).result == mc.SUCCESS
    with cell.lock:
        cell.core.estop()  # the pendant's button
    reply = client.point(0, 1, 0.5, [0.05] * 6, [0.0] * 6)
    assert (reply.result, reply.subcode) == (mc.NOT_READY, 5003)
    assert client.ctrl(mc.START_TRAJ_MODE).subcode == 5003
    with cell.lock:  # the e-stop is released at the pendant
        assert cell.core.command(Command.ESTOP_RESET, cell.core.lease_holder).ok
    # START_TRAJ_MODE does not switch the servos back on after an e-stop
    reply = client.ctrl(mc.START_TRAJ_MODE)
    assert (reply.result, reply.subcode) == (mc.NOT_READY, 5006)
    reply = client.point(0, 0, 0.0, [0.0] * 6, [0.0] * 6)
    assert (reply.result, reply.subcode) == (mc.NOT_READY, 5006)
    assert np.array_equal(cell.q(), np.zeros(13))
    assert client.ctrl(mc.START_SERVOS).result == mc.SUCCESS
    ready(client)
    assert client.point(0, 0, 0.0, [0.0] * 6, [0.0] * 6).result == mc.SUCCESS
    assert client.point(0, 1, 0.4, [0.05] * 6, [0.0] * 6).result == mc.SUCCESS
    deadline = time.monotonic() + 10.0
    while not np.allclose(r1(cell), 0.05, atol=1e-9) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert np.allclose(r1(cell), 0.05, atol=1e-9)


# ---------------------------------------------------------------- connections
def test_a_second_motion_client_replaces_an_idle_one(cell: Cell, clients: Clients) -> None:
    first = clients.motion(cell.motion_port)
    ready(first)
    second = clients.motion(cell.motion_port)
    assert first.closed_by_server()
    assert second.ctrl(mc.CHECK_MOTION_READY).command == 200101


def test_a_second_motion_client_is_closed_while_increments_are_queued(cell: Cell, clients: Clients) -> None:
    first = clients.motion(cell.motion_port)
    ready(first)
    times, positions, velocities = rest_to_rest(np.zeros(6), np.full(6, 0.2), 2.0, 3)
    stream(first, 0, times, positions, velocities)
    second = clients.motion(cell.motion_port)
    assert second.closed_by_server()
    assert first.ctrl(mc.CHECK_QUEUE_CNT).subcode > 0


# ---------------------------------------------------------------- IO
def io_frame(msg_type: int, *values: int) -> bytes:
    """Section 3: IO requests, uint32 address (and value)."""
    return mc.frame(msg_type, struct.pack(f"<{len(values)}I", *values))


def io_reply(client: mc.MotionClient, data: bytes) -> tuple[int, tuple[int, ...]]:
    client.sock.sendall(data)
    msg_type, comm, reply_code, body = mc.read_frame(client.sock)
    assert (comm, reply_code) == (3, 1)
    return msg_type, struct.unpack(f"<{len(body) // 4}i", body)


def test_grippers_are_output_bits_on_the_io_port(cell: Cell, clients: Clients) -> None:
    io = clients.motion(cell.server.ports[2])
    assert cell.server.ports[2] == cell.motion_port + 2  # section 1: 50242 beside 50240
    # config/motoros.yaml: r1's gripper is OT#1 (address 10010), closed = 1
    assert io_reply(io, io_frame(2003, 10010)) == (2004, (0, 0))
    assert io_reply(io, io_frame(2005, 10010, 1)) == (2006, (0,))
    with cell.lock:
        assert cell.core.grippers == {"r1": True, "r2": False}
    assert io_reply(io, io_frame(2003, 10010)) == (2004, (1, 0))
    assert io_reply(io, io_frame(2005, 10011, 7)) == (2006, (1003,))  # a bit is 0 or 1
    # other addresses read back what was written
    assert io_reply(io, io_frame(2009, 1001, 5)) == (2010, (0,))
    assert io_reply(io, io_frame(2007, 1001)) == (2008, (5, 0))
    assert io_reply(io, io_frame(2014, 123, 9)) == (2015, (0,))
    assert io_reply(io, io_frame(2012, 123)) == (2013, (9, 0))
    # motion messages do not belong on the IO port
    reply = io.ctrl(mc.CHECK_MOTION_READY)
    assert (reply.result, reply.subcode) == (mc.INVALID, 3003)
    # IO on the motion port too (section 3), and the motion client shares the host's lease
    motion = clients.motion(cell.motion_port)
    assert io_reply(motion, io_frame(2005, 10010, 0)) == (2006, (0,))
    ready(motion)


# ---------------------------------------------------------------- the CloPeMa fork
def test_fork_state_stream_and_move(fork: Cell, clients: Clients) -> None:
    client = clients.motion(fork.motion_port, slots=13)
    state = clients.state(fork.state_port, slots=13)
    assert state.wait_bursts(3)
    with state.lock:
        kinds = [(f[0], f[1]) for f in state.frames]
    first = kinds.index((15, 184))
    assert kinds[first:first + 2] == [(15, 184), (13, 44)]  # one aggregated feedback, then status
    assert len(fork.server.ports) == 2  # the fork has no IO port
    reply = client.ctrl(mc.CHECK_MOTION_READY)
    assert (reply.result, reply.subcode) == (mc.FAILURE, 0)  # FALSE without a subcode
    assert client.ctrl(mc.START_SERVOS).subcode == 3006  # the fork has no START_SERVOS
    ready(client)
    # one 13-slot point: r1 s..t, r2 s..t, ext_axis; robot_id ignored
    assert client.point(5, 0, 0.0, [0.0] * 13, [0.0] * 13).result == mc.SUCCESS
    goal = [0.02] * 6 + [-0.02] * 6 + [0.05]
    assert client.point(5, 1, 0.5, goal, [0.0] * 13).result == mc.SUCCESS
    assert state.wait_for(lambda s: np.allclose(s.positions.get(0, (9.0,) * 13), goal,
                                                atol=GOAL_TOLERANCE))
    # the fork's start tolerance is 10 pulses
    off = np.array(goal)
    off[12] += 11 * PULSE
    assert client.point(0, 0, 0.0, off, [0.0] * 13).subcode == 3011
    # a second motion client is refused
    second = clients.motion(fork.motion_port, slots=13)
    assert second.closed_by_server()
    assert client.ctrl(mc.CHECK_MOTION_READY).result == mc.SUCCESS
