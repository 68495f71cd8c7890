"""`foldcell log record`: the session recorder as a process (joins the `log` command group)."""

from __future__ import annotations

import argparse
import datetime as dt
import logging
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

from drivers.sessions.mcap.config import load_session_log_config
from drivers.sessions.recorder import SessionRecorder
from drivers.wire.transport import Wire
from tools import log_cli
from tools.common import (
    StopSignal,
    add_wire_arguments,
    check_seconds,
    path_argument,
    print_json,
    wire_settings_watching,
)

log = logging.getLogger(__name__)

PROGRESS_PERIOD_S = 10.0   # how often `log record -v` says how far it is


def register(subparsers: Any) -> None:
    log_cli.register(subparsers, extra=[_add_record])


def _add_record(group: Any) -> None:
    p = group.add_parser(
        "record", help="record a cell's key space to a rosbag2 bag (MCAP) until Ctrl-C",
        description="Subscribe to foldcell/<cell>/** and write every sample to a rosbag2 bag: a folder BAG "
                    "with BAG_0.mcap, BAG_1.mcap, ... (ROS 2 messages in CDR, ros2msg schemas, chunked and "
                    "compressed, split by size per config/cell.yaml) and metadata.yaml, as `ros2 bag record "
                    "-s mcap -o BAG` leaves it. SIGINT and SIGTERM finish the file and the metadata.")
    p.add_argument("-o", "--output", type=path_argument, metavar="BAG",
                   help="the bag folder (default <runs>/<cell>-<UTC time>; X.mcap records to the folder X; "
                        "a session recorded there before is replaced)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--json", action="store_true", help="at the end, the files and counts as JSON on stdout")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_record)


def default_log_path(runs: Path, cell: str) -> Path:
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    return runs / f"{cell}-{stamp}"


def cmd_record(args: argparse.Namespace) -> int:
    check_seconds("--duration", args.duration)
    settings, watch = wire_settings_watching(args, "observer")
    stop = StopSignal()
    path = args.output or default_log_path(settings.runs_directory, settings.cell_id)
    wire = Wire(settings, f"cli-recorder-{os.getpid()}")
    try:
        log_config = load_session_log_config(settings.config_file)
        recorder = SessionRecorder(wire, path, log_config, cell=watch)
        print(f"recording foldcell/{recorder.cell}/** to the bag {recorder.writer.bag} (Ctrl-C to stop)",
              file=sys.stderr, flush=True)
        until = math.inf if args.duration is None else time.monotonic() + args.duration
        while (not stop.wait(min(PROGRESS_PERIOD_S, max(0.0, until - time.monotonic())))
               and time.monotonic() < until):
            stats, (waiting, waiting_bytes) = recorder.stats(), recorder.backlog()
            log.info("recorded %d samples, %d rejected, %d dropped while behind; %d waiting (%.1f MB)",
                     stats.recorded, stats.rejected, stats.dropped, waiting, waiting_bytes / 1e6)
    finally:
        wire.close()  # drains what was received before the file is finished
    stats = recorder.close()
    if args.json:
        print_json({"bag": str(stats.bag), "files": [str(p) for p in stats.files], "recorded": stats.recorded,
                    "rejected": stats.rejected, "dropped": stats.dropped})
    else:
        files = ", ".join(p.name for p in stats.files)
        dropped = f", {stats.dropped} dropped while behind" if stats.dropped else ""
        print(f"recorded {stats.recorded} samples ({stats.rejected} rejected{dropped}, see "
              f"/diagnostics/rejected) to {stats.bag} ({files})", file=sys.stderr)
    return 0
