"""A tiny MotoROS client for the tests, written straight from `shared/facts/motoros-simple-message.md`
with struct.pack (none of drivers/motoros): motion requests one at a time (over TLS given an
`ssl.SSLContext`: a secured controller's ports), a state stream reader."""

from __future__ import annotations

import socket
import ssl
import struct
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

# section 5
CHECK_MOTION_READY, CHECK_QUEUE_CNT, STOP_MOTION = 200101, 200102, 200111
START_SERVOS, STOP_SERVOS, RESET_ALARM = 200112, 200113, 200114
START_TRAJ_MODE, STOP_TRAJ_MODE, DISCONNECT = 200121, 200122, 200130
SUCCESS, BUSY, FAILURE, INVALID, NOT_READY = 0, 1, 2, 3, 5
REPLY_TIMEOUT_S = 10.0


def frame(msg_type: int, body: bytes, comm: int = 2) -> bytes:
    """Section 2: length (12 + body), msg_type, comm_type, reply_code 0."""
    return struct.pack("<iiii", 12 + len(body), msg_type, comm, 0) + body


def padded(values: Sequence[float], slots: int) -> list[float]:
    return [float(v) for v in values] + [0.0] * (slots - len(values))


def point_14(group: int, sequence: int, time_s: float, pos: Sequence[float], vel: Sequence[float],
             slots: int = 10, valid: int = 7) -> bytes:
    """Section 4, 14: robot_id, sequence, valid_fields, time, pos[s], vel[s], acc[s]."""
    return frame(14, struct.pack(f"<iiif{3 * slots}f", group, sequence, valid, time_s, *padded(pos, slots),
                                 *padded(vel, slots), *([0.0] * slots)))


def point_2016(sequence: int, blocks: Sequence[tuple[int, float, Sequence[float], Sequence[float]]],
               count: int | None = None) -> bytes:
    """Section 4, 2016: numberOfValidGroups, sequence, then per group: group, valid, time, pos, vel, acc."""
    body = struct.pack("<ii", len(blocks) if count is None else count, sequence)
    for group, time_s, pos, vel in blocks:
        body += struct.pack("<iif30f", group, 7, time_s, *padded(pos, 10), *padded(vel, 10), *([0.0] * 10))
    return frame(2016, body)


def motion_ctrl(command: int, group: int = 0, sequence: int = 0, slots: int = 10) -> bytes:
    return frame(2001, struct.pack(f"<iii{slots}f", group, sequence, command, *([0.0] * slots)))


@dataclass(frozen=True)
class Reply:
    msg_type: int
    comm: int
    reply_code: int
    group: int = 0
    sequence: int = 0
    command: int = 0
    result: int = 0
    subcode: int = 0


def recv_exact(sock: socket.socket, count: int) -> bytes:
    out = b""
    while len(out) < count:
        chunk = sock.recv(count - len(out))
        if not chunk:
            raise ConnectionError("closed by the server")
        out += chunk
    return out


def read_frame(sock: socket.socket) -> tuple[int, int, int, bytes]:
    """(msg_type, comm, reply_code, body): the length prefix tells the rest."""
    (length,) = struct.unpack("<i", recv_exact(sock, 4))
    rest = recv_exact(sock, length)
    msg_type, comm, reply_code = struct.unpack_from("<iii", rest)
    return msg_type, comm, reply_code, rest[12:]


class MotionClient:
    def __init__(self, port: int, slots: int = 10, tls: ssl.SSLContext | None = None):
        sock = socket.create_connection(("127.0.0.1", port), timeout=REPLY_TIMEOUT_S)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        # with `tls` the handshake is done here, within REPLY_TIMEOUT_S
        self.sock = tls.wrap_socket(sock, server_hostname="127.0.0.1") if tls else sock
        self.slots = slots

    def request(self, data: bytes) -> Reply:
        """Section 6: send each message in one write and wait for its reply."""
        self.sock.sendall(data)
        return self.read_reply()

    def read_reply(self) -> Reply:
        msg_type, comm, reply_code, body = read_frame(self.sock)
        if msg_type != 2002:
            return Reply(msg_type, comm, reply_code)
        group, sequence, command, result, subcode = struct.unpack_from("<5i", body)
        assert len(body) == 20 + 4 * self.slots
        return Reply(msg_type, comm, reply_code, group, sequence, command, result, subcode)

    def ctrl(self, command: int, group: int = 0, sequence: int = 0) -> Reply:
        return self.request(motion_ctrl(command, group, sequence, self.slots))

    def point(self, group: int, sequence: int, time_s: float, pos: Sequence[float],
              vel: Sequence[float]) -> Reply:
        return self.request(point_14(group, sequence, time_s, pos, vel, self.slots))

    def closed_by_server(self, timeout: float = REPLY_TIMEOUT_S) -> bool:
        self.sock.settimeout(timeout)
        try:
            return self.sock.recv(1) == b""
        except ConnectionResetError:
            return True
        except TimeoutError:
            return False

    def close(self) -> None:
        self.sock.close()


@dataclass
class StateReader:
    """Reads the state port on a thread: every frame's (msg_type, size, comm), the last feedback per group,
    the last ROBOT_STATUS and the monotonic time each arrived (a burst's last frame)."""

    port: int
    slots: int = 10
    frames: list[tuple[int, int, int]] = field(default_factory=list)
    positions: dict[int, tuple[float, ...]] = field(default_factory=dict)
    status: tuple[int, ...] = ()
    status_times: list[float] = field(default_factory=list)
    error: str = ""

    def __post_init__(self) -> None:
        self.sock = socket.create_connection(("127.0.0.1", self.port), timeout=REPLY_TIMEOUT_S)
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            while True:
                msg_type, comm, _, body = read_frame(self.sock)
                with self.changed:
                    self.frames.append((msg_type, 16 + len(body), comm))
                    if msg_type == 15:
                        group = struct.unpack_from("<i", body)[0]
                        self.positions[group] = struct.unpack_from(f"<{self.slots}f", body, 12)
                    elif msg_type == 13:
                        self.status = struct.unpack_from("<7i", body)
                        self.status_times.append(time.monotonic())
                    self.changed.notify_all()
        except (OSError, ConnectionError) as exc:
            with self.changed:
                self.error = str(exc)
                self.changed.notify_all()

    def wait_for(self, predicate, timeout: float = REPLY_TIMEOUT_S) -> bool:  # type: ignore[no-untyped-def]
        deadline = time.monotonic() + timeout
        with self.changed:
            while not predicate(self):
                left = deadline - time.monotonic()
                if left <= 0 or self.error:
                    return bool(predicate(self))
                self.changed.wait(left)
            return True

    def bursts(self) -> int:
        with self.lock:
            return sum(1 for f in self.frames if f[0] == 13)

    def wait_bursts(self, count: int) -> bool:
        start = self.bursts()
        return self.wait_for(lambda s: sum(1 for f in s.frames if f[0] == 13) >= start + count)

    def close(self) -> None:
        self.sock.close()
