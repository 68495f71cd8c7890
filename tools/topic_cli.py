"""`foldcell topic list|echo|hz|pub|call`: look at and poke a cell's key space, like `ros2 topic`."""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections import defaultdict
from typing import Any

import yaml

from drivers.common.configfile import yaml_problem
from drivers.controller.codes import Result
from drivers.wire import messages
from drivers.wire.messages import NobodyServes, WireError
from drivers.wire.registry import KEYS, spec_for, split_key
from drivers.wire.transport import Wire, process_of
from tools.common import (
    StopSignal,
    add_wire_arguments,
    check_seconds,
    meeting_point_note,
    print_json,
    wire_settings,
    wire_settings_watching,
)

SERVER_POLL_S = 0.1  # between asks while no server is known yet
QUIET_NOTICE_S = 2.0  # `topic echo` says what it waits for after this long without a message

def register(subparsers: Any) -> None:
    topic = subparsers.add_parser("topic", help="list, echo, measure and publish on a cell's keys",
                                  description="Inspect a cell's key space over Zenoh, like `ros2 topic`.")
    group = topic.add_subparsers(dest="topic_command", metavar="COMMAND", required=True)

    p = group.add_parser("list", help="keys seen during a short listen, with type, rate and process tokens")
    p.add_argument("--duration", type=float, default=1.0, metavar="S", help="listen this long (default 1 s)")
    p.add_argument("--registry", action="store_true", help="print the key registry instead of listening")
    p.add_argument("--json", action="store_true", help="one JSON document on stdout")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_list)

    p = group.add_parser("echo", help="print decoded messages of a key")
    p.add_argument("key", help="key relative to foldcell/<cell>/, e.g. controller/status")
    p.add_argument("-n", "--count", type=int, metavar="N", help="stop after N messages")
    p.add_argument("--timeout", type=float, metavar="S",
                   help="stop after S seconds; exit 1 if no message came by then (default: wait)")
    p.add_argument("--json", action="store_true", help="JSON lines instead of YAML documents")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_echo)

    p = group.add_parser("hz", help="rate and inter-arrival jitter of a key")
    p.add_argument("key", help="key relative to foldcell/<cell>/")
    p.add_argument("--duration", type=float, default=5.0, metavar="S", help="measure this long (default 5 s)")
    p.add_argument("--json", action="store_true", help="one JSON document on stdout")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_hz)

    p = group.add_parser("pub", help="publish a message given as YAML")
    p.add_argument("key", help="key relative to foldcell/<cell>/")
    p.add_argument("message", nargs="?", default="{}",
                   help="the message as YAML/JSON, e.g. '{name: [a], position: [0]}'")
    p.add_argument("-r", "--rate", type=float, metavar="HZ", help="repeat at this rate (default: once)")
    p.add_argument("-n", "--count", type=int, metavar="N", help="with --rate: stop after N messages")
    p.add_argument("--json", action="store_true", help="print what was published as JSON on stdout")
    p.add_argument("--wait", type=float, default=1.0, metavar="S",
                   help="wait up to S seconds for a subscriber before the first message (default 1)")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_pub)

    p = group.add_parser("call", help="query a queryable with a request given as YAML, print the reply")
    p.add_argument("key", help="key relative to foldcell/<cell>/, e.g. controller/command")
    p.add_argument("message", nargs="?", default="{}", help="the request as YAML/JSON")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S",
                   help="how long to wait for a server and its reply (default 5)")
    p.add_argument("--json", action="store_true", help="the reply as JSON")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_call)


def _parse_message(type_name: str, text: str) -> Any:
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"message: not valid YAML: {yaml_problem(exc)}") from exc
    return messages.from_dict(type_name, data)


def _print_message(key: str, msg: Any, as_json: bool) -> None:
    data = messages.to_dict(msg)
    if as_json:
        print(json.dumps({"key": key, "message": data}), flush=True)
    else:
        print(yaml.safe_dump(data, sort_keys=False, width=120).rstrip() + "\n---", flush=True)


def cmd_list(args: argparse.Namespace) -> int:
    check_seconds("--duration", args.duration)
    if args.registry:
        rows = [{"key": s.pattern, "kind": s.kind, "type": s.type_name, "reply_type": s.reply_type,
                 "description": s.description} for s in KEYS]
        if args.json:
            print_json(rows)
        else:
            for r in rows:
                reply = f" -> {r['reply_type']}" if r["reply_type"] else ""
                print(f"{r['key']:32} {r['kind']:10} {r['type']}{reply}")
        return 0
    settings, cell = wire_settings_watching(args, "observer")
    counts: dict[str, int] = defaultdict(int)
    types: dict[str, str] = {}
    lock = threading.Lock()

    def on_sample(raw: Any) -> None:
        with lock:
            counts[raw.key] += 1
            types[raw.key] = raw.type_name

    with Wire(settings, f"cli-topic-list-{time.time_ns() % 100000}") as wire:
        wire.subscribe_raw(f"foldcell/{cell}/**", on_sample, drop=True)
        time.sleep(args.duration)
        alive = sorted(wire.alive(cell=cell))
    with lock:
        rows = [{"key": k, "type": types[k], "rate_hz": round(counts[k] / args.duration, 2)}
                for k in sorted(counts)]
    if args.json:
        print_json({"keys": rows, "alive": alive})
    else:
        for r in rows:
            print(f"{r['key']:48} {r['type']:40} {r['rate_hz']:9.1f} Hz")
        for a in alive:
            print(f"{a:48} (liveliness)")
    return 0


def cmd_echo(args: argparse.Namespace) -> int:
    spec = spec_for(args.key)
    settings = wire_settings(args, "observer")
    stop = StopSignal()
    seen = 0
    done = threading.Event()
    reader_gone = threading.Event()

    def on_message(key: str, msg: Any, _raw: Any) -> None:
        nonlocal seen
        if done.is_set():
            return
        try:
            _print_message(key, msg, args.json)
        except BrokenPipeError:   # `... | head -1`: the reader has what it wanted
            reader_gone.set()
        seen += 1
        if reader_gone.is_set() or (args.count and seen >= args.count):
            done.set()
            stop.event.set()

    def on_error(err: WireError) -> None:
        print(f"foldcell: bad sample: {err}", file=sys.stderr, flush=True)

    if spec.kind != "pub":
        raise ValueError(f"{args.key}: is a {spec.kind}; use `foldcell topic call` for queryables")
    if args.count is not None and args.count < 1:
        raise ValueError(f"--count: must be at least 1, got {args.count}")
    check_seconds("--timeout", args.timeout)
    alone = meeting_point_note(settings)
    with Wire(settings, f"cli-topic-echo-{time.time_ns() % 100000}") as wire:
        wire.subscribe(args.key, on_message, on_error=on_error)
        quiet_for = QUIET_NOTICE_S if args.timeout is None else min(QUIET_NOTICE_S, args.timeout)
        if not stop.wait(quiet_for) and seen == 0:
            processes = sorted(name for name in map(process_of, wire.alive()) if name != wire.process)
            print(f"foldcell: waiting for a message on {wire.key(args.key)} (processes of cell "
                  f"{settings.cell_id!r} seen: {', '.join(processes) or 'none'}; Ctrl-C to stop){alone}",
                  file=sys.stderr, flush=True)
        if args.timeout is None:
            stop.wait()
        elif not stop.wait(max(0.0, args.timeout - quiet_for)) and seen == 0:
            print(f"foldcell: no message on {wire.key(args.key)} within {args.timeout:g} s{alone}",
                  file=sys.stderr)
            return 1
    if reader_gone.is_set():
        raise BrokenPipeError   # main() ends quietly, as a Unix filter does
    return 0


def cmd_hz(args: argparse.Namespace) -> int:
    import numpy as np

    check_seconds("--duration", args.duration)
    spec_for(args.key)
    settings = wire_settings(args, "observer")
    arrivals: list[int] = []
    lock = threading.Lock()

    def on_sample(raw: Any) -> None:
        with lock:
            arrivals.append(raw.receive_ns)

    with Wire(settings, f"cli-topic-hz-{time.time_ns() % 100000}") as wire:
        wire.subscribe_raw(wire.key(args.key), on_sample)
        time.sleep(args.duration)
    with lock:
        t = np.array(arrivals, dtype=np.int64)
    if len(t) < 2:
        result = {"key": args.key, "count": len(t), "rate_hz": 0.0}
    else:
        gaps = np.diff(t) / 1e6
        rate_hz = round((len(t) - 1) / ((t[-1] - t[0]) / 1e9), 2)
        result = {"key": args.key, "count": len(t), "rate_hz": rate_hz,
                  "gap_ms": {"p50": round(float(np.median(gaps)), 3),
                             "p99": round(float(np.percentile(gaps, 99)), 3),
                             "max": round(float(gaps.max()), 3)}}
    if args.json:
        print_json(result)
    elif "gap_ms" in result:
        gaps = result["gap_ms"]
        print(f"{args.key}: {result['rate_hz']} Hz over {result['count']} samples; gaps p50 "
              f"{gaps['p50']} ms, p99 {gaps['p99']} ms, max {gaps['max']} ms")
    else:
        print(f"{args.key}: {result['count']} samples in {args.duration} s: no rate")
    return 0


def cmd_pub(args: argparse.Namespace) -> int:
    check_seconds("--wait", args.wait, zero_allowed=True)
    spec = spec_for(args.key)
    if spec.kind != "pub":
        raise ValueError(f"{args.key}: is a {spec.kind}, not a published key")
    msg = _parse_message(spec.type_name, args.message)
    messages.validate(spec.type_name, msg, args.key)
    if args.rate is not None and args.rate <= 0:
        raise ValueError(f"--rate: must be > 0, got {args.rate}")
    settings = wire_settings(args, "player")
    stop = StopSignal()
    with Wire(settings, f"cli-topic-pub-{time.time_ns() % 100000}") as wire:
        pub = wire.publisher(args.key)
        heard = pub.wait_for_subscribers(args.wait)
        if not heard:
            print(f"foldcell: nobody subscribes to {wire.key(args.key)} (waited {args.wait:g} s): "
                  "publishing anyway", file=sys.stderr)
        sent = 0
        next_t = time.monotonic()
        while not stop.is_set():
            pub.put(msg)
            sent += 1
            if args.rate is None or (args.count and sent >= args.count):
                break
            next_t += 1.0 / args.rate
            stop.wait(max(0.0, next_t - time.monotonic()))
        time.sleep(0.1)
    if args.json:
        print_json({"key": wire.key(args.key), "published": sent, "subscribed": bool(heard)})
    else:
        print(f"published {sent} message(s) on {wire.key(args.key)}", file=sys.stderr)
    return 0


def cmd_call(args: argparse.Namespace) -> int:
    check_seconds("--timeout", args.timeout)
    spec = spec_for(args.key)
    if spec.kind != "queryable":
        raise ValueError(f"{args.key}: is a {spec.kind}, not a queryable")
    request = _parse_message(spec.type_name, args.message)
    settings = wire_settings(args, "operator")
    with Wire(settings, f"cli-topic-call-{time.time_ns() % 100000}") as wire:
        deadline = time.monotonic() + args.timeout
        while True:
            try:
                reply = wire.request(args.key, request, timeout=max(0.1, deadline - time.monotonic()))
                break
            except NobodyServes as err:
                # a session just opened may not have heard of the queryable yet: ask again until the timeout
                if time.monotonic() >= deadline:
                    print(f"foldcell: error: {err}", file=sys.stderr)
                    return 1
                time.sleep(SERVER_POLL_S)
            except WireError as err:
                print(f"foldcell: error: {err}", file=sys.stderr)
                return 1
    _print_message(wire.key(args.key), reply, args.json)
    refusal = _refusal(reply)
    if refusal:
        print(f"foldcell: {args.key} refused the request: {refusal}", file=sys.stderr)
        return 1
    return 0


def _refusal(reply: object) -> str:
    """Why a reply refuses its request ('' when it does not): a cell reply not accepted, a controller
    reply whose result is not SUCCESS."""
    if getattr(reply, "accepted", True) is False:
        return str(getattr(reply, "text", "")) or "not accepted"
    result = int(getattr(reply, "result", 0))
    if result:
        name = Result(result).name if result in Result._value2member_map_ else str(result)
        return f"result {name}: {getattr(reply, 'text', '')}"
    return ""


__all__ = ["register", "split_key"]
