"""What every `foldcell` subcommand shares: connection flags, errors, signals, JSON output."""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import logging
import math
import os
import select
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from drivers.common.configfile import ConfigError
from drivers.wire.security import SecurityError
from drivers.wire.settings import (
    ENV_CELL,
    ENV_CONNECT,
    ENV_LISTEN,
    ENV_SECURITY,
    MODES,
    WireSettings,
    load_wire_settings,
    settings_from_environment,
)


class UsageError(Exception):
    """Bad command-line input: printed as `foldcell: error: ...`, exit code 2."""


def check_seconds(flag: str, value: float | None, zero_allowed: bool = False) -> None:
    """A duration, timeout or offset given as `flag`: a finite number > 0 (>= 0 with `zero_allowed`);
    None (not given) passes. NaN and infinity fail every comparison, so they are named here rather
    than left to a sleep or a deadline far from the flag."""
    if value is None:
        return
    if not math.isfinite(value) or value < 0 or (value == 0 and not zero_allowed):
        raise UsageError(f"{flag}: must be a finite number of seconds {'>=' if zero_allowed else '>'} 0, "
                         f"got {value:g}")


def path_argument(value: str) -> Path:
    """An argparse type for a path: an empty one names nothing (as `.` it would write into, or
    replace what is in, the current directory)."""
    if not value.strip():
        raise argparse.ArgumentTypeError("an empty path names no file or directory")
    return Path(value)


def cell_argument(value: str) -> str:
    """An argparse type for `--cell`: empty is refused rather than taken as not given."""
    if not value.strip():
        raise argparse.ArgumentTypeError("an empty cell id names no cell (leave the flag out: the default)")
    return value


def add_wire_arguments(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("connection (like Zenoh's own tools)")
    group.add_argument("--cell", metavar="ID", type=cell_argument,
                       help=f"cell id, the key chunk after foldcell/ (env {ENV_CELL}; "
                       "default from config/cell.yaml); '*' = every cell, for commands that watch")
    group.add_argument("--listen", "-l", metavar="ENDPOINT", action="append",
                       help="Zenoh endpoint to listen on as well as the process's own port, repeatable; "
                       "one that cannot be bound is an error, unless also given to --connect (a meeting "
                       f"point: the first process gets it) (env {ENV_LISTEN}, comma-separated)")
    group.add_argument("--connect", "-e", metavar="ENDPOINT", action="append",
                       help="Zenoh endpoint to connect to instead of config/cell.yaml's meeting point (then "
                       "not listened on either), repeatable; a warning names one nobody answers, and Zenoh "
                       f"keeps trying it (env {ENV_CONNECT}, comma-separated)")
    group.add_argument("--config", metavar="FILE", type=path_argument,
                       help="cell configuration (default config/cell.yaml)")
    group.add_argument("--mode", choices=MODES,
                       help="Zenoh mode: peer (default: config/zenoh/peer.json5's) or client of the router "
                       "given by --connect (a machine that meets the cell through a router)")
    group.add_argument("--security", metavar="DIR", type=path_argument,
                       help=f"run secured: mutual TLS and access control with this process's role's "
                       f"directory, DIR/<role> of `foldcell security init DIR` (env {ENV_SECURITY}); "
                       "tcp/ endpoints become tls/")


def run_at_priority(args: argparse.Namespace, role: str, process: str) -> None:
    """This process runs at its role's nice (`priorities:` in config/cell.yaml), set before its Zenoh
    session so Zenoh's threads inherit it; its timing report is written as `process`."""
    from drivers.common.scheduling import load_priorities, name_process, set_thread_nice

    name_process(process)
    set_thread_nice(load_priorities(getattr(args, "config", None)).of(role), process)


def wire_settings(args: argparse.Namespace, role: str) -> WireSettings:
    """Config file, then environment, then command line, each overriding the one before. `role`:
    what this process may do on a secured wire (config/security.yaml)."""
    settings = load_wire_settings(getattr(args, "config", None))
    settings = settings_from_environment(settings)
    return settings.overridden(cell_id=getattr(args, "cell", None), listen=getattr(args, "listen", None),
                               connect=getattr(args, "connect", None),
                               security_dir=getattr(args, "security", None), role=role,
                               mode=getattr(args, "mode", None))


ALL_CELLS = "*"
PROBE_S = 0.3   # a meeting point on this machine answers a TCP connect at once


def meeting_point_note(settings: WireSettings) -> str:
    """Why a tool hears nobody, when that is the cause: nobody listens at the cell's meeting point (no cell
    runs on this machine, or it meets elsewhere). '' when someone is there or it cannot be told. Asked
    before the tool's own session opens, which would take the meeting point itself."""
    for endpoint in settings.listen:
        if endpoint in settings.connect and _nobody_at(endpoint):
            return (f" (nobody was at {endpoint}, the cell's meeting point, when this tool started: no cell "
                    "runs there; give --connect to reach one elsewhere)")
    return ""


def _nobody_at(endpoint: str) -> bool:
    """A TCP endpoint on which a connect is refused (True); False when it answers or cannot be told."""
    protocol, _, address = endpoint.split("#", 1)[0].partition("/")
    host, _, port = address.rpartition(":")
    if protocol not in ("tcp", "tls") or not port.isdigit():
        return False
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=PROBE_S).close()
    except ConnectionRefusedError:
        return True
    except OSError:
        return False
    return False


def wire_settings_watching(args: argparse.Namespace, role: str) -> tuple[WireSettings, str]:
    """The settings and the cell a watching command looks at: `--cell '*'` looks at every cell (the
    process itself joins the configured one)."""
    every = getattr(args, "cell", None) == ALL_CELLS
    if every:
        args = argparse.Namespace(**{**vars(args), "cell": None})
    settings = wire_settings(args, role)
    return settings, ALL_CELLS if every else settings.cell_id


def wire_arguments(args: argparse.Namespace) -> list[str]:
    """The connection flags again, to pass to child processes."""
    out: list[str] = []
    if getattr(args, "config", None):
        out += ["--config", str(args.config)]
    if getattr(args, "cell", None):
        out += ["--cell", args.cell]
    for endpoint in getattr(args, "listen", None) or []:
        out += ["--listen", endpoint]
    for endpoint in getattr(args, "connect", None) or []:
        out += ["--connect", endpoint]
    if getattr(args, "security", None):
        out += ["--security", str(args.security)]
    if getattr(args, "mode", None):
        out += ["--mode", args.mode]
    return out


class StopSignal:
    """Set by SIGINT or SIGTERM; long-running commands wait on it and then shut down cleanly."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.signal_name = ""
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, self._handle)

    def _handle(self, signum: int, _frame: Any) -> None:
        self.signal_name = signal.Signals(signum).name
        self.event.set()

    def wait(self, timeout: float | None = None) -> bool:
        return self.event.wait(timeout)

    def is_set(self) -> bool:
        return self.event.is_set()


def print_json(data: Any) -> None:
    json.dump(data, sys.stdout, indent=2, sort_keys=False, default=_json_default)
    sys.stdout.write("\n")
    sys.stdout.flush()


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def setup_logging(verbose: int, json_lines: bool = False) -> None:
    """Log to stderr from WARNING (INFO with -v, DEBUG with -vv); `json_lines`: one JSON object a line."""
    level = logging.WARNING - 10 * verbose
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonLines() if json_lines else
                         logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    logging.basicConfig(level=max(level, logging.DEBUG), handlers=[handler])


def log_entry(created: float, level: str, logger: str, message: str) -> dict[str, Any]:
    """One JSON log line's fields: time (UTC ISO 8601, from `created`, epoch s), level, logger, message,
    process."""
    when = dt.datetime.fromtimestamp(created, dt.timezone.utc)
    return {"time": when.isoformat(timespec="milliseconds"), "level": level, "logger": logger,
            "message": message, "process": os.getpid()}


class JsonLines(logging.Formatter):
    """A log record as one JSON object (time in UTC ISO 8601, level, logger, message, the exception's
    text when there is one), for a log collector to read line by line."""

    def format(self, record: logging.LogRecord) -> str:
        entry = log_entry(record.created, record.levelname, record.name, record.getMessage())
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, ensure_ascii=False)


def announce(args: argparse.Namespace, message: str, **fields: Any) -> None:
    """A service's line that it is up and what it serves, on stderr: the text, or with --json one JSON
    object (`event` "ready", the message and `fields`)."""
    if getattr(args, "json_log", False):
        entry = {**log_entry(time.time(), "INFO", "foldcell", message), "event": "ready", **fields}
        print(json.dumps(entry, default=_json_default), file=sys.stderr, flush=True)
    else:
        print(message, file=sys.stderr, flush=True)


def add_json_log(parser: argparse.ArgumentParser) -> None:
    """`--json` for a service (it prints no result): its log as JSON lines on stderr."""
    parser.add_argument("--json", dest="json_log", action="store_true",
                        help="log as JSON lines on stderr (one object a line: time, level, logger, message), "
                             "for a log collector")


KNOWN_ERRORS: tuple[type[BaseException], ...] = (UsageError, ConfigError, ValueError, FileNotFoundError,
                                                  SecurityError)


def error_exit(message: str, code: int = 2) -> int:
    print(f"foldcell: error: {message}", file=sys.stderr)
    return code


@contextlib.contextmanager
def terminal_keys(on_key: Callable[[str], None], poll_s: float) -> Iterator[None]:
    """Each key pressed on a terminal stdin goes to `on_key` (cbreak mode, restored after);
    nothing happens when stdin is not a terminal (a pipe, CI)."""
    if not sys.stdin.isatty():
        yield
        return
    import termios
    import tty

    fd = sys.stdin.fileno()
    saved = termios.tcgetattr(fd)
    done = threading.Event()

    def read_keys() -> None:
        while not done.is_set():
            ready, _, _ = select.select([fd], [], [], poll_s)
            if ready:
                on_key(os.read(fd, 1).decode(errors="replace"))

    tty.setcbreak(fd)
    reader = threading.Thread(target=read_keys, name="keys", daemon=True)
    reader.start()
    try:
        yield
    finally:
        done.set()
        reader.join(1.0)
        termios.tcsetattr(fd, termios.TCSADRAIN, saved)

