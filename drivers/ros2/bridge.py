"""The bridge of `foldcell ros2`: the cell's topics and services on rmw_zenoh_cpp's terms.

Two Zenoh sessions: the process's `Wire` on the cell's own network, and a session shaped like an
rmw_zenoh node's on the ROS 2 network (its router, `rmw_zenohd`). Every sample of a published key of the
registry is checked as every foldcell reader checks it and its bytes (already ROS 2 CDR) go out again on
the topic's rmw_zenoh key with rmw_zenoh's attachment; the first sample of a key declares its publisher
token, so `ros2 topic list` shows what the cell publishes. Each service of config/ros2.yaml is a queryable
on its rmw_zenoh key that forwards the request to the cell's queryable and returns the reply.
"""

from __future__ import annotations

import itertools
import json
import logging
import threading
import time
from typing import Any

import zenoh

from drivers.common.configfile import ConfigError
from drivers.ros2 import names, types
from drivers.ros2.config import Ros2Config
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.registry import KEYS, KeySpec, check_size, spec_for, split_key
from drivers.wire.settings import CONNECT_WARNING_S, same_place
from drivers.wire.transport import QUERY_DEPTH, Lane, Pump, RawSample, Wire

log = logging.getLogger(__name__)
CDR = zenoh.Encoding.APPLICATION_CDR
CLOSE_TIMEOUT_S = 3.0


def ros_session_config(config: Ros2Config, connect: tuple[str, ...]) -> zenoh.Config:
    try:
        conf = zenoh.Config.from_file(str(config.zenoh_config))
    except Exception as exc:
        raise ConfigError(config.zenoh_config, "", f"not a valid Zenoh config: {exc}") from exc
    conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return conf


class _Publisher:
    """One ROS topic: its Zenoh publisher, its token and its own sequence numbers."""

    def __init__(self, session: zenoh.Session, key: str, token: str, drop: bool):
        self.gid = names.gid_of(token)
        self.seq = itertools.count(1)
        self.publisher = session.declare_publisher(
            key, encoding=CDR, express=drop,
            congestion_control=zenoh.CongestionControl.DROP if drop else zenoh.CongestionControl.BLOCK)
        self.token = session.liveliness().declare_token(token)

    def put(self, payload: bytes, stamp_ns: int) -> None:
        self.publisher.put(payload, attachment=names.attachment(next(self.seq), stamp_ns, self.gid))

    def undeclare(self) -> None:
        self.token.undeclare()
        self.publisher.undeclare()


class Ros2Bridge:
    def __init__(self, wire: Wire, config: Ros2Config, domain_id: int, connect: tuple[str, ...]):
        names.check_token(wire.cell_id, "--cell")
        for key, srv_type in config.services.items():   # before anything is declared: fail early
            types.check_layout(srv_type, spec_for(key))
        self.wire = wire
        self.config = config
        self.domain_id = domain_id
        self.session = zenoh.open(ros_session_config(config, connect))
        self.node = names.Node(domain_id, str(self.session.info.zid()), 0,
                               f"{config.namespace}/{wire.cell_id}", config.node_name)
        self.lock = threading.Lock()
        self.entity_ids = itertools.count(1)
        self.publishers: dict[str, _Publisher] = {}
        self.refused: set[str] = set()          # keys whose bad samples were logged once
        self.declared: list[Any] = [self.session.liveliness().declare_token(self.node.token())]
        self.lanes: list[Lane | Pump] = []
        self.closed = False
        for key, srv_type in config.services.items():
            self._serve(key, srv_type)
        for spec in KEYS:
            if spec.kind == "pub":
                wire.subscribe_raw(wire.key(spec.pattern), self._forward, drop=spec.drop_when_congested,
                                   name=f"ros2:{spec.pattern}")
        self._warn_unanswered(connect)

    def topic_name(self, relative_key: str) -> str:
        return names.ros_name(self.config.namespace, self.wire.cell_id, relative_key)

    # ------------------------------------------------------------------ topics
    def _forward(self, raw: RawSample) -> None:
        if raw.is_delete or self.closed:
            return
        relative = split_key(raw.key)[1]
        try:
            spec = spec_for(relative)
            if raw.type_name and raw.type_name != spec.type_name:
                raise WireError(raw.key, f"sample is a {raw.type_name}, this key carries {spec.type_name}")
            check_size(raw.key, spec.type_name, len(raw.payload))
            messages.decode(spec.type_name, raw.payload, raw.key)   # ROS readers get what foldcell's would
            publisher = self._publisher(relative, spec)
        except (WireError, names.RosNameError) as err:
            if raw.key not in self.refused:   # once per key: a stranger's flood must not flood the log
                self.refused.add(raw.key)
                log.warning("not bridged to ROS 2: %s", err)
            return
        publisher.put(raw.payload, raw.stamp_ns or time.time_ns())

    def _publisher(self, relative_key: str, spec: KeySpec) -> _Publisher:
        with self.lock:
            publisher = self.publishers.get(relative_key)
            if publisher is None:
                if self.closed:
                    raise WireError(relative_key, "the bridge is closing")
                name = self.topic_name(relative_key)
                type_hash = types.message_hash(spec.type_name)
                qos = self.config.stream_qos if spec.drop_when_congested else self.config.other_qos
                token = self.node.entity_token(next(self.entity_ids), names.PUBLISHER, name, spec.type_name,
                                               type_hash, qos)
                publisher = _Publisher(self.session, names.data_key(self.domain_id, name, spec.type_name,
                                                                    type_hash),
                                       token, spec.drop_when_congested)
                self.publishers[relative_key] = publisher
                log.info("ROS 2 topic %s (%s)", name, spec.type_name)
            return publisher

    # ------------------------------------------------------------------ services
    def _serve(self, relative_key: str, srv_type: str) -> None:
        spec = spec_for(relative_key)
        name = self.topic_name(relative_key)
        type_hash = types.service_hash(srv_type)
        token = self.node.entity_token(next(self.entity_ids), names.SERVICE_SERVER, name, srv_type, type_hash,
                                       self.config.service_qos)

        def answer(query: zenoh.Query) -> None:
            try:
                attachment = query.attachment.to_bytes() if query.attachment is not None else b""
                try:
                    seq, _stamp, gid = names.parse_attachment(attachment)
                except ValueError as exc:
                    raise WireError(name, f"not an rmw_zenoh request: {exc}") from exc
                payload = query.payload.to_bytes() if query.payload is not None else b""
                check_size(name, spec.type_name, len(payload))
                request = messages.decode(spec.type_name, payload, name)
                if hasattr(request, "client") and not request.client:
                    request.client = f"ros2:{gid.hex()}"    # the cell logs who asked
                reply = self.wire.request(relative_key, request, timeout=self.config.service_timeout_s)
                data = messages.encode(spec.reply_type, reply, name)
                query.reply(query.key_expr, data, encoding=CDR,
                            attachment=names.attachment(seq, time.time_ns(), gid))
            except WireError as err:
                query.reply_err(str(err).encode(), encoding=zenoh.Encoding.TEXT_PLAIN)
            finally:
                query.drop()

        lane = Lane(f"ros2:serve:{relative_key}", answer)
        key = names.data_key(self.domain_id, name, srv_type, type_hash)
        queryable = self.session.declare_queryable(key, zenoh.handlers.FifoChannel(QUERY_DEPTH),
                                                   complete=True)
        self.declared.append(queryable)
        self.declared.append(self.session.liveliness().declare_token(token))
        self.lanes.extend([lane, Pump(f"ros2:serve:{relative_key}", queryable.handler, lane.push)])
        log.info("ROS 2 service %s (%s)", name, srv_type)

    # ------------------------------------------------------------------ life cycle
    def _warn_unanswered(self, connect: tuple[str, ...]) -> None:
        def check() -> None:
            try:
                reached = [link.dst for link in self.session.info.links()]
            except zenoh.ZError:   # closed meanwhile
                return
            for endpoint in connect:
                if not any(same_place(endpoint, dst) for dst in reached):
                    log.warning("--ros-connect %s: nobody answers after %g s (is rmw_zenohd running?); "
                                "Zenoh keeps trying", endpoint, CONNECT_WARNING_S)

        timer = threading.Timer(CONNECT_WARNING_S, check)
        timer.daemon = True
        timer.start()

    def close(self) -> None:
        with self.lock:
            self.closed = True
            publishers = list(self.publishers.values())
            self.publishers.clear()
        for entity in [*publishers, *reversed(self.declared)]:
            try:
                entity.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        for lane in self.lanes:
            lane.close(CLOSE_TIMEOUT_S)
        closer = threading.Thread(target=self.session.close, name="zenoh-close", daemon=True)
        closer.start()
        closer.join(CLOSE_TIMEOUT_S)
