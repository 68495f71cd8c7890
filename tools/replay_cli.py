"""`foldcell replay BAG`: republish a logged session on Zenoh, like `ros2 bag play`.

With `--perceive`, run perception again offline on every logged image and compare with the log.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import sys
import threading
from typing import Any

from tqdm import tqdm

from drivers.sessions.mcap.errors import McapLogError
from drivers.sessions.replay import (
    NS,
    CellRefusedError,
    ReplayConfig,
    Replayer,
    ReplayError,
    Selection,
    TopicFilter,
    WireSink,
    load_replay_config,
    open_session,
)
from drivers.sessions.replay import (
    select as select_messages,
)
from tools.common import (
    StopSignal,
    add_wire_arguments,
    check_seconds,
    error_exit,
    path_argument,
    print_json,
    terminal_keys,
    wire_settings,
)

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "replay",
        help="republish a logged session (a rosbag2 bag, or an MCAP file) on Zenoh with its original timing",
        description="Republish every recorded sample of a session log on its key expression, with the "
        "original timing and sender stamps, like `ros2 bag play`. In a terminal: space pauses "
        "and resumes, 's' publishes the next sample while paused, 'q' quits. A file cut short "
        "by a crash is replayed up to its last complete chunk. The process holds the "
        "liveliness token alive/cli-replay-<pid> in every cell it replays into. "
        "With --perceive, nothing is published: perception runs again on every logged image.",
    )
    p.add_argument("file", metavar="BAG|FILE", type=path_argument,
                   help="the session: a bag folder (every file, in order), any of its files, or a .mcap file")
    p.add_argument(
        "-r",
        "--rate",
        default="1",
        metavar="R",
        help="speed factor (default 1; 5 = five times faster; 'max' = as fast as possible)",
    )
    p.add_argument("--start", type=float, metavar="S", help="begin S seconds into the session")
    p.add_argument("--end", type=float, metavar="S", help="stop S seconds into the session")
    p.add_argument(
        "--topics",
        action="append",
        default=[],
        metavar="GLOB",
        help="replay only keys matching GLOB (repeatable; relative like 'controller/*' or full; "
        "a leading '!' excludes)",
    )
    p.add_argument(
        "--exclude", action="append", default=[], metavar="GLOB", help="leave out keys matching GLOB"
    )
    p.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    p.add_argument(
        "--perceive",
        action="store_true",
        help="run perception again on every logged image; print logged vs new landmarks",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="with --perceive: one JSON document on stdout; " "otherwise a JSON summary at the end",
    )
    add_wire_arguments(p)
    p.epilog = ("--cell ID replays into that cell's key space (default: a cell of its own, <recorded "
                "cell>-replay; on a secured cell only ids ending in -replay); a cell where the cell daemon "
                "or a controller is alive is refused.")
    p.set_defaults(func=cmd_replay)


def parse_rate(text: str) -> float | None:
    if text.strip().lower() in ("max", "inf"):
        return None
    try:
        rate = float(text)
    except ValueError:
        raise ReplayError(f"--rate: {text!r} is not a number or 'max'") from None
    if not rate > 0 or rate == float("inf"):
        raise ReplayError(f"--rate: must be > 0 or 'max', got {text!r}")
    return rate


def cmd_replay(args: argparse.Namespace) -> int:
    check_seconds("--start", args.start, zero_allowed=True)
    check_seconds("--end", args.end, zero_allowed=True)
    try:
        rate = parse_rate(args.rate)
        selection = Selection(args.start, args.end, TopicFilter.parse(args.topics, args.exclude))
        config = load_replay_config()
        session = open_session(args.file)
    except ReplayError as exc:
        return error_exit(str(exc))
    try:
        if args.perceive:
            return _perceive(args, session, selection)
        return _replay(args, session, selection, rate, config)
    except CellRefusedError as exc:
        return error_exit(str(exc))
    except (ReplayError, McapLogError) as exc:
        return error_exit(str(exc), 1)
    finally:
        session.close()


def _replay(
    args: argparse.Namespace, session: Any, selection: Selection, rate: float | None, config: ReplayConfig
) -> int:
    settings = wire_settings(args, "player")
    stop = StopSignal()
    sink = WireSink(settings, cell=args.cell, process=f"cli-replay-{os.getpid()}")
    start_ns, end_ns = selection.window_ns(session)
    first = start_ns if start_ns is not None else session.start_ns
    last = min(end_ns, session.end_ns) if end_ns is not None else session.end_ns
    replayer = Replayer(
        lambda: select_messages(session, selection), sink, rate=rate, loop=args.loop, config=config
    )
    bar = tqdm(
        total=round(max(0, last - first) / NS, 1),
        unit="s",
        desc="replay",
        file=sys.stderr,
        disable=None,
        leave=False,
        mininterval=config.progress_update_s,
        bar_format="{desc} {percentage:3.0f}%|{bar}| {n:.1f}/{total:.1f} s " "[{elapsed}<{remaining}]",
    )

    def progress(log_ns: int) -> None:
        position = round(max(0, log_ns - first) / NS, 1)
        if position > bar.n:
            bar.update(position - bar.n)  # tqdm throttles its own redraws

    def stop_on_request() -> None:
        stop.wait()
        replayer.stop()

    stopper = threading.Thread(target=stop_on_request, name="replay-stop", daemon=True)
    stopper.start()
    try:
        sink.prepare([t for t in session.topics if selection.topics.keeps(t)], config.subscriber_wait_s)
        if session.recovered:
            print(f"foldcell: {session.source} is cut short or damaged; replaying its intact chunks",
                  file=sys.stderr)
        with _keyboard(replayer, config, bar):
            stats = replayer.run(progress)
    finally:
        bar.close()
        sink.close()
    summary = {
        "file": str(session.source),
        "recovered": session.recovered,
        "published": stats.published,
        "skipped": stats.skipped,
        "loops": stats.loops,
        "stopped": stats.stopped,
    }
    if args.json:
        print_json(summary)
    else:
        print(
            f"replayed {stats.published} samples ({stats.skipped} skipped) from {session.source}",
            file=sys.stderr,
        )
    if stats.published == 0 and not stats.stopped:
        print("foldcell: nothing was replayed: the selection (--topics, --exclude, --start, --end) "
              "keeps no sample "
              "of a published key", file=sys.stderr)
        return 1
    return 0


def _keyboard(replayer: Replayer, config: ReplayConfig, bar: Any) -> contextlib.AbstractContextManager:
    """Space pauses/resumes, 's' steps, 'q' quits, when stdin is a terminal; else nothing."""
    def on_key(key: str) -> None:
        if key in config.pause_keys:
            paused = replayer.toggle_pause()
            bar.set_description("paused" if paused else "replay")
        elif key in config.step_keys:
            replayer.step()
            bar.set_description("paused")
        elif key in config.quit_keys:
            replayer.stop()

    return terminal_keys(on_key, config.max_sleep_s)


def _perceive(args: argparse.Namespace, session: Any, selection: Selection) -> int:
    from cell.evaluation.replay_check import compare_session, format_comparison

    results = compare_session(session, selection)
    if args.json:
        print_json({"file": str(session.source), "images": [r.to_json() for r in results]})
    else:
        for r in results:
            sys.stdout.write(format_comparison(r))
    if not results:
        print("foldcell: no images in the selection: nothing was compared", file=sys.stderr)
        return 1
    return 0
