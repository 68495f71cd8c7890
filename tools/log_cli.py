"""`foldcell log ...`: session-log subcommands (`info`, `recover`; `record` is added by the recorder).

`register(subparsers, extra=...)` creates the `log` group; each function in `extra` gets the group's
subparsers action and adds one more subcommand, so `log record` plugs in without editing this file.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import json
import sys
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, TypeVar

from tqdm import tqdm

from drivers.sessions.mcap.bag import bag_folder, find_session
from drivers.sessions.mcap.errors import LogFileError, McapLogError
from drivers.sessions.mcap.info import LogInfo
from drivers.sessions.mcap.recover import RecoverReport, recover
from drivers.sessions.mcap.session import SessionRecoverReport, read_session_info, recover_bag, session_size
from tools.common import error_exit, path_argument

EXIT_OK = 0
EXIT_RUNTIME = 1
EXIT_BAD_INPUT = 2
EXIT_DATA_LOST = 3  # as the reference Rust `mcap recover`
RECOVERED_SUFFIX = ".recovered.mcap"

SubparserAdder = Callable[[Any], None]


def register(subparsers: Any, extra: Iterable[SubparserAdder] = ()) -> None:
    """Add the `log` command group with `info` and `recover` (and whatever `extra` adds)."""
    log = subparsers.add_parser(
        "log", help="session logs (MCAP): inspect, recover",
        description="Work with foldcell session logs (MCAP files, ROS 2 messages in CDR).")
    group = log.add_subparsers(dest="log_command", metavar="COMMAND", required=True)
    _add_info(group)
    _add_recover(group)
    for add in extra:
        add(group)


def _add_info(group: Any) -> None:
    p = group.add_parser(
        "info", help="topics, types, counts, rates and duration of a session",
        description="Describe a session log, a rosbag2 bag (every split file, as one) or a lone MCAP file: "
                    "per topic its type, message count and rate; the time span, size and compression. "
                    "Every chunk is read and its CRC checked, so a file cut short by a crash or with a "
                    "damaged chunk is reported as such.")
    p.add_argument("file", metavar="BAG|FILE", type=path_argument,
                   help="the bag folder, any of its files, or a .mcap file")
    p.add_argument("--json", action="store_true", help="print one JSON document on stdout")
    p.add_argument("--quick", action="store_true",
                   help="trust the file's summary instead of reading every chunk (damage goes unseen)")
    p.set_defaults(func=cmd_info)


def _add_recover(group: Any) -> None:
    p = group.add_parser(
        "recover", help="rewrite a session cut short by a crash into valid files",
        description="Read a cut or damaged MCAP file linearly, keep every complete chunk and message, "
                    "and write a valid file with schemas, channels, metadata, indexes and summary. "
                    "A bag (its folder or any of its files) is recovered in place: each cut or damaged "
                    "file is replaced by what survives of it and metadata.yaml is rebuilt from the files "
                    "(as `ros2 bag reindex`); with -o, a new bag is written there instead. "
                    "Exit status: 0 nothing lost, 3 data was lost (cut or damaged), 2 bad input, "
                    "1 failure while writing.")
    p.add_argument("file", metavar="BAG|FILE", type=path_argument,
                   help="the bag folder, any of its files, or a .mcap file")
    p.add_argument("-o", "--output", type=path_argument, metavar="OUT",
                   help=f"where to write (a lone file: default FILE with suffix {RECOVERED_SUFFIX}; "
                        "a bag: default in place, else the new bag folder)")
    p.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    p.add_argument("--json", action="store_true", help="print the report as one JSON document on stdout")
    p.set_defaults(func=cmd_recover)



class _Progress:
    """A tqdm byte bar on stderr, created on first use (reading a summary needs none)."""

    def __init__(self, total: int, desc: str):
        self.total = total
        self.desc = desc
        self.bar: tqdm | None = None

    def __call__(self, n: int) -> None:
        if self.bar is None:
            self.bar = tqdm(total=self.total, unit="B", unit_scale=True, desc=self.desc,
                            file=sys.stderr, disable=None, leave=False)
        self.bar.update(n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _file_size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def cmd_info(args: argparse.Namespace) -> int:
    path = Path(args.file)
    progress = _Progress(session_size(path), "scanning")
    try:
        info = read_session_info(path, progress=progress, verify=not args.quick)
    except LogFileError as exc:
        return error_exit(str(exc), EXIT_BAD_INPUT)
    except McapLogError as exc:
        return error_exit(str(exc), EXIT_RUNTIME)
    finally:
        progress.close()
    if args.json:
        json.dump(info.to_json_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(format_info(info))
    # a session cut short or damaged is described, and a script checking it is told by the exit code
    return EXIT_OK if info.complete else EXIT_DATA_LOST


def cmd_recover(args: argparse.Namespace) -> int:
    src = Path(args.file)
    try:
        bag = find_session(src).bag
    except LogFileError as exc:
        return error_exit(str(exc), EXIT_BAD_INPUT)
    if bag is None:
        dst = Path(args.output) if args.output else src.with_name(src.name + RECOVERED_SUFFIX)
        if dst.exists() and not args.force:
            return error_exit(f"{dst}: already exists (use --force to overwrite, or -o to choose another "
                              "name)", EXIT_BAD_INPUT)
        return _recovering(args, src, _file_size(src), lambda progress: recover(src, dst, progress=progress),
                           format_report)
    out = bag_folder(args.output) if args.output else None
    if out is not None and out.is_dir() and any(out.iterdir()) and not args.force:
        return error_exit(f"{out}: already exists (use --force to replace what is there, or -o to choose "
                      "another name)", EXIT_BAD_INPUT)
    return _recovering(args, src, session_size(src),
                       lambda progress: recover_bag(src, args.output, progress=progress), format_bag_report)


Report = TypeVar("Report", RecoverReport, SessionRecoverReport)


def _recovering(args: argparse.Namespace, src: Path, size: int, run: Callable[[_Progress], Report],
                describe: Callable[[Report], str]) -> int:
    """Run a recovery with a progress bar; print its report; exit 3 when data was lost."""
    progress = _Progress(size, "recovering")
    try:
        report = run(progress)
    except LogFileError as exc:
        # A bad output path is a bad argument too; both name the path.
        return error_exit(str(exc), EXIT_BAD_INPUT)
    except (McapLogError, OSError) as exc:
        return error_exit(f"recovering {src} failed: {exc}", EXIT_RUNTIME)
    finally:
        progress.close()
    if args.json:
        json.dump(report.to_json_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        sys.stdout.write(describe(report))
    return EXIT_DATA_LOST if report.data_lost else EXIT_OK


def _time(ns: int | None) -> str:
    if ns is None:
        return "-"
    stamp = _dt.datetime.fromtimestamp(ns / 1e9, _dt.timezone.utc)
    return f"{stamp.isoformat(timespec='milliseconds')} ({ns} ns)"


def _size(n: int) -> str:
    for unit in ("B", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024  # type: ignore[assignment]
    return f"{n} B"


def format_info(info: LogInfo) -> str:
    """The human-readable `log info` text."""
    if info.complete:
        state = "complete, " + ("with summary" if info.has_summary else "no summary (scanned)")
    elif info.incomplete_files:
        state = (f"CUT SHORT OR DAMAGED: {', '.join(Path(f).name for f in info.incomplete_files)} "
                 f"(run `foldcell log recover {info.path}`)")
    elif info.unreadable_bytes or not info.has_summary:
        state = (f"CUT SHORT: {info.unreadable_bytes} bytes unreadable at the end "
                 f"(run `foldcell log recover {info.path}`)")
    else:
        state = f"DAMAGED (run `foldcell log recover {info.path}` to keep the rest)"
    if info.damaged_chunks:
        state += f"; {info.damaged_chunks} damaged chunk(s) (CRC or compression) skipped"
    lines = [
        f"{'bag:' if info.bag else 'file:':10} {info.path} ({_size(info.size_bytes)})",
        *([f"files:     {len(info.files)}: " + ", ".join(Path(f).name for f in info.files)]
          if info.bag else []),
        f"library:   {info.library} (profile {info.profile or '-'})",
        f"state:     {state}",
        f"start:     {_time(info.start_ns)}",
        f"end:       {_time(info.end_ns)}",
        f"duration:  {info.duration_s:.3f} s",
        f"messages:  {info.message_count} in {info.chunk_count} chunk(s), "
        f"compression {', '.join(info.compression) or '-'}",
    ]
    for meta in info.metadata:
        lines.append(f"metadata:  {meta.name}: " + ", ".join(f"{k}={v}" for k, v in meta.entries))
    headers = ("topic", "type", "count", "rate Hz")
    rows = [(c.topic, c.type_name or "-", str(c.message_count), f"{c.rate_hz:.2f}") for c in info.channels]
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h) for i, h in enumerate(headers)]
    lines.append("")
    for row in (headers, *rows):  # text columns left-aligned, numbers right-aligned
        lines.append("  ".join(v.ljust(w) if i < 2 else v.rjust(w)
                               for i, (v, w) in enumerate(zip(row, widths, strict=True))).rstrip())
    if not rows:
        lines.append("(no channels)")
    return "\n".join(lines) + "\n"


def format_report(report: RecoverReport) -> str:
    """The human-readable `log recover` text."""
    lines = [
        f"recovered: {report.source} -> {report.output}",
        f"kept:      {report.messages_kept} messages in {report.chunks_kept} chunk(s)",
    ]
    if report.source_complete:
        lines.append("source:    complete (nothing was lost)")
    else:
        lines.append(f"source:    stopped after {report.bytes_read} bytes: {report.stop_reason}")
        lines.append(f"dropped:   {report.bytes_dropped} bytes at the end")
    if report.chunks_damaged:
        lines.append(f"damaged:   {report.chunks_damaged} chunk(s) failed their CRC or decompression")
    if report.messages_without_channel:
        lines.append(f"orphans:   {report.messages_without_channel} message(s) whose channel was lost")
    lines.append("result:    DATA WAS LOST" if report.data_lost else "result:    nothing lost")
    return "\n".join(lines) + "\n"


def format_bag_report(report: SessionRecoverReport) -> str:
    """The human-readable `log recover` text for a bag."""
    where = f" -> {report.output}" if report.output != report.bag else " (in place)"
    lines = [f"bag:       {report.bag}{where}"]
    if report.untouched:
        lines.append(f"whole:     {', '.join(Path(p).name for p in report.untouched)} (left as they were)")
    for r in report.recovered:
        where = (f"stopped after {r.bytes_read} bytes: {r.stop_reason}" if not r.source_complete
                 else "complete")
        damaged = f", {r.chunks_damaged} damaged chunk(s)" if r.chunks_damaged else ""
        lines.append(f"recovered: {Path(r.output).name}: {r.messages_kept} messages kept ({where}{damaged})")
    lines.append(f"metadata:  {report.metadata}")
    lines.append("result:    DATA WAS LOST" if report.data_lost else "result:    nothing lost")
    return "\n".join(lines) + "\n"
