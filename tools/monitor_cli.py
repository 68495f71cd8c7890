"""`foldcell monitor`: a live terminal dashboard of one cell or all, like `ros2 topic hz/echo` at once."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import os
import shutil
import sys
import threading
import time
from typing import Any

from drivers.sessions.monitor.config import load_monitor_config
from drivers.sessions.monitor.keys import CommandKeys
from drivers.sessions.monitor.live import MonitorSession
from drivers.sessions.monitor.render import render_text
from tools.common import (
    ALL_CELLS,
    StopSignal,
    add_wire_arguments,
    check_seconds,
    path_argument,
    print_json,
    terminal_keys,
    wire_settings_watching,
)

CLEAR = "\x1b[H\x1b[2J"


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "monitor",
        help="live dashboard of a cell (or every cell) over Zenoh",
        description="Watch a cell live: state machine state and history, garment (with its elapsed "
        "time) and fold step, grippers open or closed, every joint against its limits, controller "
        "status (servo, e-stop, alarm, motion, lease), rate and age of every key, which processes "
        "are alive (a cell whose processes all died shows as GONE within a second; one fed by "
        "`foldcell replay` shows as replay; the cell's gone processes stay listed a while, those of "
        "one command not at all), and the last errors (cell/log at WARN and above, malformed "
        "samples; a repeated one once, with its count and last time). In a terminal watching one cell, "
        "'p', 'r' and 'a' pause, resume and abort it (each asks for confirmation: 'y'); 'q' quits. "
        "Use --cell '*' for every cell on the network.",
    )
    p.add_argument(
        "--once", action="store_true", help="listen briefly (--duration), print one snapshot, exit"
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="JSON: with --once one document; otherwise one document per line at the refresh rate",
    )
    p.add_argument(
        "--duration",
        type=float,
        metavar="S",
        help="with --once: listen S seconds first (default: until the cell's state is heard, at most "
        "`once_listen_s` of config/replay_monitor.yaml); otherwise stop after S",
    )
    p.add_argument("-o", "--output", "--record", dest="record", type=path_argument, metavar="BAG",
                   help="also record the watched key space to a rosbag2 bag folder (X.mcap: the folder X)")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_monitor)


ONCE_POLL_S = 0.1   # how often `--once` looks whether it has heard enough


def cmd_monitor(args: argparse.Namespace) -> int:
    check_seconds("--duration", args.duration, zero_allowed=True)
    config = load_monitor_config()
    disabled = _keys_disabled(args)
    # commanding the cell is an operator's right on a secured wire; watching only, an observer's
    settings, watch = wire_settings_watching(args, "observer" if disabled else "operator")
    # given an observer's directory (as on a machine that only watches), it watches rather than refuse
    if not disabled and settings.security is not None and (settings.security / "observer.pem").is_file():
        disabled = "an observer's --security directory"
        settings = dataclasses.replace(settings, role="observer")
    stop = StopSignal()
    process = f"cli-monitor-{os.getpid()}"
    with MonitorSession(settings, watch, process, config=config, record=args.record) as session:
        if args.once:
            if args.duration is None:   # until every cell heard from has told its state (2 Hz)
                deadline = time.monotonic() + config.once_listen_s
                while not stop.wait(ONCE_POLL_S) and time.monotonic() < deadline:
                    cells = session.snapshot()["cells"].values()
                    if cells and all(cell["state"] is not None for cell in cells):
                        break
            else:
                stop.wait(args.duration)
            snap = session.snapshot()
            if args.json:
                print_json(snap)
            else:
                print("\n".join(render_text(snap, width=shutil.get_terminal_size().columns, live=False)))
            if not snap.get("cells"):
                print(f"foldcell: no cell {watch!r} heard from on this network", file=sys.stderr)
                return 1
            return 0
        keys = CommandKeys(config, watch, disabled)
        return _live(session, args, stop, keys, process)


def _keys_disabled(args: argparse.Namespace) -> str:
    """Why the live view takes no command keys ("" when it does)."""
    if args.once or args.json:
        return "not in --once or --json"
    if getattr(args, "cell", None) == ALL_CELLS:
        return "watching every cell (--cell ID to command one)"
    if not sys.stdin.isatty():
        return "stdin is not a terminal"
    return ""


def _live(session: MonitorSession, args: argparse.Namespace, stop: StopSignal, keys: CommandKeys,
          process: str) -> int:
    redraw = sys.stdout.isatty() and not args.json and os.environ.get("TERM") != "dumb"
    deadline = None if args.duration is None else time.monotonic() + args.duration
    period = 1.0 / session.config.refresh_hz
    with _keys(session, keys, stop, process, period):
        while not stop.is_set():
            snap = session.snapshot()
            if args.json:
                sys.stdout.write(json.dumps(snap, separators=(",", ":")) + "\n")
            else:
                size = shutil.get_terminal_size()
                lines = render_text(snap, colour=redraw, width=size.columns, status=keys.line())
                if redraw:
                    sys.stdout.write(CLEAR + "\n".join(lines[: size.lines - 1]) + "\n")
                else:
                    sys.stdout.write("\n".join(lines) + "\n\n")
            sys.stdout.flush()
            if deadline is not None and time.monotonic() >= deadline:
                break
            stop.wait(period if deadline is None else max(0.0, min(period, deadline - time.monotonic())))
    return 0


def _keys(session: MonitorSession, keys: CommandKeys, stop: StopSignal, process: str,
          period: float) -> contextlib.AbstractContextManager:
    """Keys from a terminal stdin: quit, or a command to the cell once confirmed, sent off the key
    thread so the view goes on while the cell answers."""

    def send(command: str) -> None:
        keys.on_reply(command, *session.command(command, process))

    def on_key(key: str) -> None:
        if keys.quits(key):
            stop.event.set()
        elif command := keys.on_key(key):
            threading.Thread(target=send, args=(command,), name=f"command-{command}", daemon=True).start()

    return terminal_keys(on_key, period)
