"""Zenoh sessions with typed publishers, subscribers, queryables and queries over the registry.

Zenoh's threads only copy a sample into a lane (a queue with its own thread); decoding and user
callbacks run there, so a slow callback never blocks Zenoh. Each sample carries an attachment of
16 bytes, `<q seq><q stamp_ns>` little-endian: a per-publisher sequence number (loss detection)
and the sender's stamp (the message header's, else the wall clock at publication). Samples from
other clients without it are accepted; their stamp is then the receive time.
"""

from __future__ import annotations

import collections
import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh

from drivers.wire import messages
from drivers.wire.limits import QueryRate
from drivers.wire.messages import ErrorReply, NobodyServes, NoReply, WireError
from drivers.wire.registry import check_size, full_key, query_rate, spec_for, split_key, type_for_full_key
from drivers.wire.settings import WireSettings, open_session

log = logging.getLogger(__name__)

ATTACHMENT = struct.Struct("<qq")
CDR_ENCODING_PREFIX = "application/cdr"
STREAM_LANE_DEPTH = 64          # a drop lane keeps the newest samples only
# What Zenoh keeps for a pump that is behind (a busy interpreter): a stream keeps its newest samples, a
# reliable subscription or a queryable waits (Zenoh's thread blocks only once this many are waiting).
RELIABLE_DEPTH = 4096
QUERY_DEPTH = 1024
# A queryable's refusal (a request it cannot use, a handler that failed) is text/plain; Zenoh's own error
# replies (its query timeout, sent by the querier's session or the queryable's) never are.
REFUSAL_ENCODING = zenoh.Encoding.TEXT_PLAIN
CLOSE_TIMEOUT_S = 3.0


@dataclass(frozen=True)
class RawSample:
    """A sample as received: what the recorder writes and the monitor inspects."""

    key: str
    payload: bytes
    encoding: str
    seq: int | None
    stamp_ns: int | None
    receive_ns: int
    is_delete: bool = False

    @property
    def type_name(self) -> str:
        """The type named by the sample's encoding (`application/cdr;pkg/msg/Type`), or ''."""
        head, _, schema = self.encoding.partition(";")
        return schema if head == CDR_ENCODING_PREFIX else ""


def cdr_encoding(type_name: str) -> zenoh.Encoding:
    return zenoh.Encoding.APPLICATION_CDR.with_schema(type_name)


def _raw_from_sample(sample: zenoh.Sample) -> RawSample:
    seq = stamp = None
    attachment = sample.attachment
    if attachment is not None:
        data = attachment.to_bytes()
        if len(data) == ATTACHMENT.size:
            seq, stamp = ATTACHMENT.unpack(data)
    return RawSample(
        key=str(sample.key_expr),
        payload=sample.payload.to_bytes(),
        encoding=str(sample.encoding),
        seq=seq,
        stamp_ns=stamp,
        receive_ns=time.time_ns(),
        is_delete=sample.kind == zenoh.SampleKind.DELETE,
    )


class Lane:
    """A queue drained by its own thread. `maxlen` makes it drop the oldest item when full;
    `max_bytes` (with `size_of`) refuses a new item that would take the queue past that many bytes,
    so a consumer that falls behind holds a bounded backlog (what it refused is counted)."""

    def __init__(self, name: str, handler: Callable[[Any], None], maxlen: int | None = None,
                 max_bytes: int | None = None, size_of: Callable[[Any], int] = lambda _item: 0):
        self.name = name
        self.handler = handler
        self.idle = False   # the thread waits for an item (it is not handling one)
        self.items: collections.deque = collections.deque(maxlen=maxlen)
        self.ready = threading.Condition()
        self.closed = False
        self.dropped = 0
        self.max_bytes = max_bytes
        self.size_of = size_of
        self.bytes = 0                # of the items waiting
        self.thread = threading.Thread(target=self.run, name=f"lane:{name}", daemon=True)
        self.thread.start()

    def push(self, item: Any) -> bool:
        """Queue `item`; False when it was refused (the byte bound)."""
        size = self.size_of(item)
        with self.ready:
            if self.max_bytes is not None and self.items and self.bytes + size > self.max_bytes:
                self.dropped += 1
                return False
            if self.items.maxlen is not None and len(self.items) == self.items.maxlen:
                self.dropped += 1
                self.bytes -= self.size_of(self.items[0])
            self.items.append(item)
            self.bytes += size
            if self.idle:
                self.ready.notify()
            return True

    def backlog(self) -> tuple[int, int]:
        """(items, bytes) waiting."""
        with self.ready:
            return len(self.items), self.bytes

    def run(self) -> None:
        while True:
            with self.ready:
                while not self.items and not self.closed:
                    self.idle = True
                    self.ready.wait()
                    self.idle = False
                if self.closed and not self.items:
                    return
                item = self.items.popleft()
                self.bytes -= self.size_of(item)
            try:
                self.handler(item)
            except Exception:  # a handler bug must not kill the lane
                log.exception("handler of %s failed", self.name)

    def close(self, timeout: float) -> None:
        with self.ready:
            self.closed = True
            self.ready.notify()
        if threading.current_thread() is not self.thread:
            self.thread.join(timeout)


class Pump:
    """Hands on what Zenoh keeps in a channel of a subscriber or queryable (`zenoh.handlers`), on a
    thread of ours. Zenoh's own threads then never run Python: an interpreter kept busy for a second
    (a planning step holding the GIL) cannot hold up the links' reading and keep-alives, which once let
    a link expire under a busy process. With `batch_s` the thread, having taken what was waiting, rests
    that long: a stream of hundreds of samples a second wakes it a few dozen times."""

    def __init__(self, name: str, receiver: Any, deliver: Callable[[Any], object], batch_s: float = 0.0):
        self.receiver = receiver
        self.deliver = deliver
        self.batch_s = batch_s
        self.closed = threading.Event()
        self.thread = threading.Thread(target=self.run, name=f"pump:{name}", daemon=True)
        self.thread.start()

    def run(self) -> None:
        try:
            while True:
                self._deliver(self.receiver.recv())   # waits inside Zenoh, the GIL released
                while (item := self.receiver.try_recv()) is not None:
                    self._deliver(item)
                if self.batch_s and self.closed.wait(self.batch_s):
                    return
        except zenoh.ZError:   # the channel closed: undeclared, or the session closed
            return

    def _deliver(self, item: Any) -> None:
        try:
            self.deliver(item)
        except Exception:  # a bug in one delivery must not stop the pump
            log.exception("delivery of %s failed", self.thread.name)

    def close(self, timeout: float) -> None:
        self.closed.set()
        if threading.current_thread() is not self.thread:
            self.thread.join(timeout)


class TokenBucket:
    """`rate.burst` requests at once, refilled at `rate.per_second`; `take()` says whether one may go."""

    def __init__(self, rate: QueryRate):
        self.rate = rate
        self.tokens = float(rate.burst)
        self.updated = time.monotonic()
        self.lock = threading.Lock()

    def take(self) -> bool:
        with self.lock:
            now = time.monotonic()
            refilled = self.tokens + (now - self.updated) * self.rate.per_second
            self.tokens, self.updated = min(float(self.rate.burst), refilled), now
            if self.tokens < 1.0:
                return False
            self.tokens -= 1.0
            return True


class TypedPublisher:
    def __init__(self, wire: Wire, relative_key: str, type_name: str, drop: bool):
        self.key = wire.key(relative_key)
        self.type_name = type_name
        self.seq = 0
        self.lock = threading.Lock()
        self.publisher = wire.session.declare_publisher(
            self.key,
            encoding=cdr_encoding(type_name),
            congestion_control=zenoh.CongestionControl.DROP if drop else zenoh.CongestionControl.BLOCK,
            express=drop,
        )

    def put(self, msg: Any) -> None:
        payload = messages.encode(self.type_name, msg, self.key)
        self.put_encoded(payload, messages.message_stamp_ns(msg))

    def put_encoded(self, payload: bytes, stamp_ns: int | None = None) -> None:
        with self.lock:
            self.seq += 1
            seq = self.seq
        attachment = ATTACHMENT.pack(seq, stamp_ns if stamp_ns else time.time_ns())
        self.publisher.put(payload, attachment=attachment)

    def wait_for_subscribers(self, timeout: float) -> bool:
        """Block until some subscriber matches this key (or the timeout); True when one does."""
        deadline = time.monotonic() + timeout
        # zenoh's stub types matching_status as bool; it is a MatchingStatus
        while not self.publisher.matching_status.matching:  # type: ignore[attr-defined]
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def undeclare(self) -> None:
        self.publisher.undeclare()


def decode_sample(raw: RawSample) -> Any:
    """The message of a sample on a foldcell key, checked (type, size, content); raises WireError."""
    type_name = type_for_full_key(raw.key)
    if raw.type_name and raw.type_name != type_name:
        raise WireError(raw.key, f"sample is a {raw.type_name}, this key carries {type_name}")
    check_size(raw.key, type_name, len(raw.payload))
    return messages.decode(type_name, raw.payload, raw.key)


class SampleBuffer:
    """The samples on a key, kept by Zenoh in a ring of `capacity` (the oldest dropped past it) with no
    Python run per sample, until `drain()` takes them: a 250 Hz stream read in batches, or (capacity 1)
    only its newest sample when needed (`latest()`), costs its reader no thread woken per sample."""

    def __init__(self, session: zenoh.Session, key_expr: str, capacity: int):
        self.key_expr = key_expr
        self.subscriber = session.declare_subscriber(key_expr, zenoh.handlers.RingChannel(capacity))

    def drain(self) -> list[RawSample]:
        """Every sample kept since the last drain, oldest first."""
        out = []
        while True:
            try:
                sample = self.subscriber.try_recv()
            except zenoh.ZError:   # the session closed
                break
            if sample is None:
                break
            out.append(_raw_from_sample(sample))
        return out

    def latest(self) -> RawSample | None:
        """The newest sample since the last look, or None."""
        samples = self.drain()
        return samples[-1] if samples else None

    def undeclare(self) -> None:
        self.subscriber.undeclare()


class LateReplies:
    """The replies still to come to requests already answered by the session they were meant for, read
    on one thread of its own (every `period` s) until Zenoh closes them: another session serving the same
    key (a stranger, on an open cell) is named even when it answers after the one that counts."""

    MAX_WATCHED = 256   # requests watched at once; the oldest are let go past it

    def __init__(self, foreign: Callable[[str, str, str], None], period: float = 0.05):
        self.foreign = foreign   # (key, sender, the replier meant)
        self.period = period
        self.watched: collections.deque = collections.deque(maxlen=self.MAX_WATCHED)
        self.ready = threading.Condition()
        self.closed = False
        self.thread: threading.Thread | None = None

    def watch(self, key: str, replier: str, replies: Any) -> None:
        with self.ready:
            self.watched.append((key, replier, replies))
            self.ready.notify()
            if self.thread is None:
                self.thread = threading.Thread(target=self.run, name="late-replies", daemon=True)
                self.thread.start()

    def run(self) -> None:
        while True:
            with self.ready:
                self.ready.wait_for(lambda: self.watched or self.closed)   # idle while nothing is due
                if self.closed:
                    return
            time.sleep(self.period)
            with self.ready:
                watched = list(self.watched)
            done = []
            for item in watched:
                key, replier, replies = item
                try:
                    while (reply := replies.try_recv()) is not None:
                        sender = replier_of(reply)
                        if answers(reply) and sender != replier:
                            self.foreign(key, sender, replier)
                except zenoh.ZError:   # every replier has answered, or the query timed out
                    done.append(item)
            with self.ready:
                for item in done:
                    if item in self.watched:   # (not let go meanwhile, past MAX_WATCHED)
                        self.watched.remove(item)

    def close(self) -> None:
        with self.ready:
            self.closed = True
            self.ready.notify()


def answers(reply: zenoh.Reply) -> bool:
    """A queryable's answer: its reply, or its refusal (not Zenoh's own error, its query timeout)."""
    return reply.ok is not None or (reply.err is not None and reply.err.encoding == REFUSAL_ENCODING)


def replier_of(reply: zenoh.Reply) -> str:
    """The id of the Zenoh session that sent a reply ('' when Zenoh does not say)."""
    return str(reply.replier_id.zid) if reply.replier_id is not None else ""


@dataclass(frozen=True)
class RequestInfo:
    key: str
    attachment: bytes
    payload: bytes   # as it came, undecoded (what a signature in the attachment covers)


class Wire:
    """One process's Zenoh session for one cell, holding its liveliness token `alive/<process>`."""

    def __init__(self, settings: WireSettings, process: str, *, announce: bool = True):
        """Open the session. With `announce=False` the liveliness token waits for `announce()`, so a
        process that needs set-up shows itself alive only once it serves what it offers."""
        self.settings = settings
        self.cell_id = settings.cell_id
        self.process = process
        self.session = open_session(settings)
        self.lock = threading.Lock()
        self.declared: list[Any] = []
        self.lanes: list[Lane | Pump] = []   # closed after what they take from is undeclared
        self.closed = False
        self.token: Any = None
        self._foreign_repliers: set[tuple[str, str]] = set()   # (key, replier) already logged
        self._late_replies = LateReplies(self._foreign_reply)
        if announce:
            self.announce()

    def announce(self) -> None:
        """Declare this process's liveliness token `alive/<process>` (once)."""
        if self.token is None:
            self.token = self.session.liveliness().declare_token(self.key(f"alive/{self.process}"))

    # keys
    def key(self, relative_key: str, cell: str | None = None) -> str:
        return full_key(cell or self.cell_id, relative_key)

    def _keep(self, entity: Any, *lanes: Lane | Pump) -> None:
        with self.lock:
            self.declared.append(entity)
            self.lanes.extend(lanes)

    # publish
    def publisher(self, relative_key: str) -> TypedPublisher:
        spec = spec_for(relative_key)
        if spec.kind != "pub":
            raise WireError(relative_key, f"is a {spec.kind}, not a published key")
        pub = TypedPublisher(self, relative_key, spec.type_name, spec.drop_when_congested)
        self._keep(pub)
        return pub

    # subscribe
    def subscribe_raw(self, key_expr: str, callback: Callable[[RawSample], None], *,
                      drop: bool = False, name: str = "", max_backlog_bytes: int | None = None,
                      batch_s: float = 0.0) -> Lane:
        """Every sample on a full key expression, undecoded, handed to `callback` on its own lane
        (`max_backlog_bytes`: payload bytes it may hold while `callback` is behind; the lane counts
        what it refused; `batch_s`: see `Pump`)."""
        name = name or key_expr
        lane = Lane(name, callback, STREAM_LANE_DEPTH if drop else None,
                    max_bytes=max_backlog_bytes, size_of=lambda raw: len(raw.payload))
        channel = zenoh.handlers.RingChannel(STREAM_LANE_DEPTH) if drop else \
            zenoh.handlers.FifoChannel(RELIABLE_DEPTH)
        sub = self.session.declare_subscriber(key_expr, channel)
        pump = Pump(name, sub.handler, lambda s: lane.push(_raw_from_sample(s)), batch_s)
        self._keep(sub, lane, pump)
        return lane

    def buffer(self, relative_key: str, capacity: int = 1, cell: str | None = None) -> SampleBuffer:
        """The samples on `relative_key`, kept by Zenoh until read (`SampleBuffer`): for a stream read
        in batches, or (capacity 1) one whose reader needs only the newest value."""
        spec_for(relative_key)   # a known key
        buffer = SampleBuffer(self.session, self.key(relative_key, cell), capacity)
        self._keep(buffer)
        return buffer

    def subscribe(self, relative_key: str, callback: Callable[[str, Any, RawSample], None], *,
                  cell: str | None = None, on_error: Callable[[WireError], None] | None = None) -> None:
        """Decoded messages on `relative_key` (may hold `*`) of one cell, or of all with cell='*'.

        `callback(full_key, msg, raw)` runs on the subscription's own thread. A bad sample goes to
        `on_error` (default: a warning in the log) and the subscription goes on.
        """
        spec = spec_for(relative_key)
        report = on_error or (lambda err: log.warning("dropped a bad sample: %s", err))

        def handle(raw: RawSample) -> None:
            if raw.is_delete:
                return
            try:
                msg = decode_sample(raw)
            except WireError as err:
                report(err)
                return
            callback(raw.key, msg, raw)

        self.subscribe_raw(self.key(relative_key, cell), handle, drop=spec.drop_when_congested,
                           name=f"sub:{relative_key}")

    # queryables
    def serve(self, relative_key: str, handler: Callable[[Any, RequestInfo], Any], *,
              urgent: Callable[[bytes], bool] | None = None,
              unlimited: Callable[[RequestInfo], bool] | None = None) -> None:
        """Answer queries on `relative_key` with `handler(request, info) -> reply message`.

        Runs on the queryable's own thread. A request above the key's size bound, or over its rate
        (config/limits.yaml `query_rates`), is refused as it arrives, undecoded and its handler not run;
        one that does not decode, or a handler that raises, is answered with `reply_err` naming the
        problem; the queryable goes on. With `urgent`, a request whose payload `urgent(payload)` picks
        out (a cheap look, not a decode: it runs as each request arrives) is answered on a lane of its
        own, never queued behind the others (an e-stop behind a flood) and never rate-limited. With
        `unlimited`, a request `unlimited(info)` vouches for (the controller's lease holder, by the
        credential in its attachment) is not rate-limited either: a stranger's flood cannot use up the
        commander's share.
        """
        spec = spec_for(relative_key)
        if spec.kind != "queryable":
            raise WireError(relative_key, f"is a {spec.kind}, not a queryable")
        key = self.key(relative_key)
        rate = query_rate(spec)
        bucket = TokenBucket(rate)

        def answer(query: zenoh.Query) -> None:
            try:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                encoding = str(query.encoding) if query.encoding is not None else ""
                head, _, schema = encoding.partition(";")
                if head == CDR_ENCODING_PREFIX and schema and schema != spec.type_name:
                    raise WireError(key, f"request is a {schema}, this queryable takes {spec.type_name}")
                if not payload and spec.type_name == "std_msgs/msg/Empty":
                    request = messages.new(spec.type_name)
                else:
                    request = messages.decode(spec.type_name, payload, key)
                attachment = query.attachment.to_bytes() if query.attachment is not None else b""
                reply = handler(request, RequestInfo(key, attachment, payload))
                data = messages.encode(spec.reply_type, reply, key)
                query.reply(key, data, encoding=cdr_encoding(spec.reply_type))
            except WireError as err:
                query.reply_err(str(err).encode(), encoding=REFUSAL_ENCODING)
            except Exception as exc:  # the handler's failure is the client's answer, not a crash
                log.exception("handler of %s failed", key)
                query.reply_err(f"{key}: {type(exc).__name__}: {exc}".encode(), encoding=REFUSAL_ENCODING)
            finally:
                query.drop()

        lane = Lane(f"serve:{relative_key}", answer)
        urgent_lane = Lane(f"serve:{relative_key}:urgent", answer) if urgent is not None else None

        def refuse(query: zenoh.Query, err: WireError) -> None:
            try:
                query.reply_err(str(err).encode(), encoding=REFUSAL_ENCODING)
            finally:
                query.drop()

        def arrive(query: zenoh.Query) -> None:
            try:
                check_size(key, spec.type_name, len(query.payload) if query.payload is not None else 0)
            except WireError as err:
                refuse(query, err)
                return
            if urgent is not None and urgent_lane is not None and query.payload is not None \
                    and urgent(query.payload.to_bytes()):
                urgent_lane.push(query)
            elif bucket.take() or (unlimited is not None and query.attachment is not None and unlimited(
                    RequestInfo(key, query.attachment.to_bytes(),
                                query.payload.to_bytes() if query.payload is not None else b""))):
                lane.push(query)
            else:
                refuse(query, WireError(key, f"over the rate limit of {rate.per_second:g} requests a second "
                                             f"(bursts of {rate.burst}); refused, not run"))

        queryable = self.session.declare_queryable(key, zenoh.handlers.FifoChannel(QUERY_DEPTH))
        pump = Pump(f"serve:{relative_key}", queryable.handler, arrive)
        self._keep(queryable, lane, *([urgent_lane] if urgent_lane is not None else []), pump)

    def request(self, relative_key: str, msg: Any, *, timeout: float = 2.0, cell: str | None = None,
                attachment: bytes | None = None, sign: Callable[[str, bytes], bytes] | None = None) -> Any:
        """Send a query and return the decoded reply. Raises `ErrorReply` (the server refused),
        `NobodyServes`, `NoReply` (timeout) or `WireError` (a request or reply that does not encode).
        `sign(full key, payload)`, when given, makes the attachment (a credential signing the request)."""
        return self.request_from(relative_key, msg, timeout=timeout, cell=cell, attachment=attachment,
                                 sign=sign)[0]

    def request_from(self, relative_key: str, msg: Any, *, timeout: float = 2.0, cell: str | None = None,
                     attachment: bytes | None = None, sign: Callable[[str, bytes], bytes] | None = None,
                     replier: str = "") -> tuple[Any, str]:
        """`request`, and the id of the session that answered. With `replier`, only that session's
        answer counts: one from another (a stranger serving the same key) is dropped, and logged once."""
        spec = spec_for(relative_key)
        if spec.kind != "queryable":
            raise WireError(relative_key, f"is a {spec.kind}, not a queryable")
        key = self.key(relative_key, cell)
        payload = messages.encode(spec.type_name, msg, key)
        if sign is not None:
            attachment = sign(key, payload)
        return self._query(key, payload, spec.type_name, spec.reply_type, timeout, attachment, replier)

    def request_raw(self, key: str, payload: bytes, type_name: str, reply_type: str, *,
                    timeout: float = 2.0, attachment: bytes | None = None) -> Any:
        """`request` of a payload already encoded (or not a message at all) on a full key."""
        return self._query(key, payload, type_name, reply_type, timeout, attachment, "")[0]

    def _query(self, key: str, payload: bytes, type_name: str, reply_type: str, timeout: float,
               attachment: bytes | None, replier: str) -> tuple[Any, str]:
        started = time.monotonic()
        # every queryable on the key gets the query: with Zenoh's best match, a stranger's queryable
        # could be the only one asked; each reply is handed on as it comes (no consolidation)
        replies = self.session.get(
            key, payload=payload, encoding=cdr_encoding(type_name), timeout=timeout,
            attachment=attachment, target=zenoh.QueryTarget.ALL, consolidation=zenoh.ConsolidationMode.NONE,
        )
        for reply in replies:
            sender = replier_of(reply)
            if replier and answers(reply) and sender != replier:
                self._foreign_reply(key, sender, replier)
                continue
            if replier:
                self._late_replies.watch(key, replier, replies)
            if reply.ok is not None:
                check_size(key, reply_type, len(reply.ok.payload))
                return messages.decode(reply_type, reply.ok.payload.to_bytes(), key), sender
            if answers(reply):
                raise ErrorReply(key, reply.err.payload.to_string())
            raise NoReply(key, f"no reply within {timeout:g} s")  # Zenoh's own error: its timeout
        # no reply at all: Zenoh ends a query at once when no queryable matches
        if time.monotonic() - started < timeout * 0.9:
            raise NobodyServes(key, "nobody serves this key (is the serving process running and connected?)")
        raise NoReply(key, f"no reply within {timeout:g} s")

    def _foreign_reply(self, key: str, sender: str, replier: str) -> None:
        with self.lock:
            first = (key, sender) not in self._foreign_repliers
            self._foreign_repliers.add((key, sender))
        if first:
            log.error("%s: Zenoh session %s answers too, and is not the one this process's requests go to "
                      "(%s): a stranger serves the key; its replies are ignored. It receives every request: "
                      "secure the cell (--security)", key, sender, replier)

    # liveliness
    def alive(self, relative_pattern: str = "alive/*", cell: str | None = None,
              timeout: float = 1.0) -> set[str]:
        """Full keys of the liveliness tokens alive now."""
        found = set()
        for reply in self.session.liveliness().get(self.key(relative_pattern, cell), timeout=timeout):
            if reply.ok is not None:
                found.add(str(reply.ok.key_expr))
        return found

    def watch_alive(self, callback: Callable[[str, bool], None], relative_pattern: str = "alive/*",
                    cell: str | None = None) -> None:
        """`callback(full_key, alive)` for tokens present now and every later appearance and loss."""
        def handle(raw: RawSample) -> None:
            callback(raw.key, not raw.is_delete)

        lane = Lane(f"alive:{relative_pattern}", handle)
        sub = self.session.liveliness().declare_subscriber(
            self.key(relative_pattern, cell), zenoh.handlers.FifoChannel(QUERY_DEPTH), history=True)
        pump = Pump(f"alive:{relative_pattern}", sub.handler, lambda s: lane.push(_raw_from_sample(s)))
        self._keep(sub, lane, pump)

    # life cycle
    def close(self) -> None:
        """Undeclare everything and close the session; bounded in time."""
        with self.lock:
            if self.closed:
                return
            self.closed = True
            declared, lanes = list(self.declared), list(self.lanes)
        self._late_replies.close()
        deadline = time.monotonic() + CLOSE_TIMEOUT_S
        for entity in reversed(declared):
            try:
                entity.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        for lane in lanes:
            lane.close(max(0.05, deadline - time.monotonic()))
        try:
            if self.token is not None:
                self.token.undeclare()
        except Exception:
            log.debug("token undeclare failed", exc_info=True)
        closer = threading.Thread(target=self.session.close, name="zenoh-close", daemon=True)
        closer.start()
        closer.join(max(0.1, deadline - time.monotonic()))
        if closer.is_alive():
            log.warning("the Zenoh session did not close within %.1f s", CLOSE_TIMEOUT_S)

    def __enter__(self) -> Wire:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def process_of(alive_key: str) -> str:
    """`foldcell/<cell>/alive/<process>` -> `<process>`."""
    return split_key(alive_key)[1].removeprefix("alive/")
