"""The Foxglove bridge's front door: it also admits clients that ask for the protocol's old name.

The Foxglove SDK's WebSocket server (0.30) accepts only the subprotocol `foxglove.sdk.v1`. Lichtblick
and Foxglove Studio before 2.x ask for `foxglove.websocket.v1`, which is the same protocol under its
former name, and get HTTP 400. This proxy listens where the bridge is reached. It renames the
subprotocol in an upgrade request that asks only for the old name, and renames it back in the answer.
After the handshake it passes the bytes both ways unchanged (a WebSocket frame does not carry the name).
Every other request (an asset fetch, a new client) passes through untouched.
"""

from __future__ import annotations

import contextlib
import logging
import re
import socket
import threading

log = logging.getLogger(__name__)

CURRENT = b"foxglove.sdk.v1"
FORMER = b"foxglove.websocket.v1"
MAX_HEAD = 16 * 1024   # bytes of an HTTP request or response head
_PROTOCOL_HEADER = re.compile(rb"^(sec-websocket-protocol:[ \t]*)([^\r\n]*?)[ \t]*\r?$", re.I | re.M)
_BUFFER = 64 * 1024


class SubprotocolProxy:
    """Listens on `host:port` (0: any free port) and forwards to `upstream_port` on loopback."""

    def __init__(self, host: str, port: int, upstream_port: int):
        self.upstream = ("127.0.0.1", upstream_port)
        self.listener = socket.create_server((host, port), reuse_port=False)
        self.port = self.listener.getsockname()[1]
        self.closed = threading.Event()
        self.connections: set[socket.socket] = set()
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, name="foxglove-door", daemon=True).start()

    def _accept(self) -> None:
        while not self.closed.is_set():
            try:
                client, _ = self.listener.accept()
            except OSError:
                return   # closed
            threading.Thread(target=self._serve, args=(client,), name="foxglove-door-client",
                             daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        upstream = None
        try:
            head, rest = _read_head(client)
            request, former = _renamed_request(head)
            upstream = socket.create_connection(self.upstream, timeout=10)
            upstream.settimeout(None)
            upstream.sendall(request + rest)
            answer, rest = _read_head(upstream)
            client.sendall((_renamed_answer(answer) if former else answer) + rest)
        except (OSError, ValueError) as exc:
            log.debug("foxglove client refused at the door: %s", exc)
            client.close()
            if upstream is not None:
                upstream.close()
            return
        with self.lock:
            self.connections.update((client, upstream))
        threading.Thread(target=self._pump, args=(upstream, client), name="foxglove-door-down",
                         daemon=True).start()
        self._pump(client, upstream)

    def _pump(self, source: socket.socket, sink: socket.socket) -> None:
        try:
            while data := source.recv(_BUFFER):
                sink.sendall(data)
        except OSError:
            pass
        finally:
            for end in (source, sink):   # one side gone: the other goes too
                _hang_up(end)
            with self.lock:
                self.connections.difference_update((source, sink))

    def close(self) -> None:
        self.closed.set()
        self.listener.close()
        with self.lock:
            for conn in list(self.connections):
                _hang_up(conn)


def _hang_up(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    sock.close()


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """An HTTP head (through its blank line) and whatever came after it in the same reads."""
    sock.settimeout(10)
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk:
            raise ValueError("closed before the end of the HTTP head")
        data += chunk
        if len(data) > MAX_HEAD and b"\r\n\r\n" not in data[:MAX_HEAD]:
            raise ValueError(f"HTTP head longer than {MAX_HEAD} bytes")
    sock.settimeout(None)
    end = data.index(b"\r\n\r\n") + 4
    return data[:end], data[end:]


def _renamed_request(head: bytes) -> tuple[bytes, bool]:
    """The request with the former name replaced, when the client offers it and not the current one."""
    match = _PROTOCOL_HEADER.search(head)
    if match is None:
        return head, False
    offered = [p.strip() for p in match.group(2).split(b",")]
    if CURRENT in offered or FORMER not in offered:
        return head, False
    return head[:match.start(2)] + CURRENT + head[match.end(2):], True


def _renamed_answer(head: bytes) -> bytes:
    match = _PROTOCOL_HEADER.search(head)
    if match is None or match.group(2).strip() != CURRENT:
        return head
    return head[:match.start(2)] + FORMER + head[match.end(2):]
