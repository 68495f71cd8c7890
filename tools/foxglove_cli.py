"""`foldcell foxglove`: serve a live cell to the Foxglove app; or prepare a session log for it."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

from drivers.robot.config import default_robot_config
from drivers.sessions.foxglove import BridgeError, FoxgloveBridge, load_foxglove_config
from drivers.wire.transport import Wire
from tools.common import (
    ALL_CELLS,
    StopSignal,
    add_json_log,
    add_wire_arguments,
    announce,
    error_exit,
    path_argument,
    print_json,
    wire_settings,
    wire_settings_watching,
)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "foxglove",
        help="serve a live cell to the Foxglove app (WebSocket), or annotate a log for it",
        description="Bridge a live cell to Foxglove over its WebSocket protocol: every key of the cell on "
        "the topic it has in a session log (/foldcell/<cell>/<key>), plus /robot_description "
        "(the URDF), /tf (link frames from the joint states) and the matched polygon of each "
        "perception/observation as foxglove_msgs/ImageAnnotations. In Foxglove: Open connection, "
        "Foxglove WebSocket, ws://HOST:PORT; then Import layout docs/foxglove_layout.json. "
        "With --export BAG, write a copy of a session log (every file of a rosbag2 bag, or one .mcap "
        "file) with the same additions into one MCAP file instead (open it in Foxglove with Open local "
        "file).",
    )
    p.add_argument(
        "--port", type=int, metavar="P", help="WebSocket port (default from config, 8765; 0: any free)"
    )
    p.add_argument("--host", metavar="H", help="address to listen on (default 127.0.0.1; 0.0.0.0 for all)")
    p.add_argument(
        "--export", type=path_argument, metavar="BAG",
        help="annotate this session log (a bag folder, any of its files, or a .mcap file) instead of bridging"
    )
    p.add_argument(
        "-o",
        "--output",
        type=path_argument,
        metavar="OUT.mcap",
        help="with --export: where to write (default BAG.foxglove.mcap beside the bag folder or file)",
    )
    p.add_argument(
        "--layout",
        action="store_true",
        help="print a Foxglove layout (JSON) for --cell on stdout and exit; "
        "docs/foxglove_layout.json is the one for the default cell",
    )
    add_wire_arguments(p)
    p.epilog = "--cell '*' bridges every cell on the network."
    add_json_log(p)
    p.set_defaults(func=cmd_foxglove)


def cmd_foxglove(args: argparse.Namespace) -> int:
    if args.port is not None and not 0 <= args.port <= 65535:
        return error_exit(f"--port: must be 0..65535, got {args.port}")
    config = load_foxglove_config()
    urdf = default_robot_config().urdf_path
    if args.export is not None:
        return _export(args, config, urdf)
    if args.layout:
        from drivers.sessions.foxglove import default_layout

        cell = args.cell if args.cell and args.cell != ALL_CELLS else wire_settings(args, "observer").cell_id
        sys.stdout.write(default_layout(cell, config, list(default_robot_config().joint_names)))
        return 0
    settings, watch = wire_settings_watching(args, "observer")
    stop = StopSignal()
    with Wire(settings, f"cli-foxglove-{os.getpid()}") as wire:
        try:
            bridge = FoxgloveBridge(wire, watch, config, Path(urdf), port=args.port, host=args.host)
        except BridgeError as exc:
            return error_exit(str(exc), 1)
        try:
            host = args.host or config.host
            url = f"ws://{host}:{bridge.port}"
            announce(args, f"serving foldcell/{watch} to Foxglove at {url} (Ctrl-C to stop)",
                     cell=watch, url=url)
            stop.wait()
        finally:
            bridge.close()
    return 0


def _export(args: argparse.Namespace, config: Any, urdf: Path) -> int:
    from drivers.sessions.foxglove import export_for_foxglove
    from drivers.sessions.mcap.bag import find_session
    from drivers.sessions.mcap.errors import LogFileError
    from drivers.sessions.replay import ReplayError

    try:
        session = find_session(args.export)
    except LogFileError as exc:
        return error_exit(str(exc))
    name = session.path.name if session.bag is not None else session.path.stem
    out = args.output or session.path.with_name(name + ".foxglove.mcap")
    if out.resolve() in {p.resolve() for p in session.files}:
        return error_exit("--output: must differ from the session's files")
    try:
        counts = export_for_foxglove(args.export, out, config, Path(urdf))
    except (ReplayError, BridgeError) as exc:
        return error_exit(str(exc))
    if args.json_log:   # the export's result on stdout, as every command that prints one
        print_json({"output": str(out), **counts})
    else:
        print(f"wrote {out}: {counts['messages']} messages, {counts['annotations']} annotations, "
              f"{counts['tf']} frame sets", file=sys.stderr)
    if not counts["messages"]:
        print(f"foldcell: {args.export} holds no readable message: nothing was exported", file=sys.stderr)
        return 1
    return 0
