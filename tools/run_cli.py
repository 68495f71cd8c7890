"""`foldcell run`: the cell daemon."""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import logging
import sys
from typing import Any

from drivers.camera.model import MOUNTS
from tools.common import (
    StopSignal,
    add_json_log,
    add_wire_arguments,
    announce,
    error_exit,
    path_argument,
    run_at_priority,
    wire_settings,
)

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "run", help="the cell daemon: state machine, perception, planning, session recording",
        description="Run the cell: take commands on cell/command (fold CATEGORY, pause, resume, abort, "
                    "status, reset), drive the camera over Zenoh and the controller over Zenoh or MotoROS, "
                    "publish cell/state, cell/log, perception/*, plan/trajectory (and over MotoROS the "
                    "robot's controller/*), and record the session to MCAP. "
                    "Runs until Ctrl-C.")
    p.add_argument("-o", "--output", "--record", dest="record", type=path_argument, metavar="BAG",
                   help="the session log written, a rosbag2 bag folder (default <runs>/<cell>-<UTC time>; "
                        "X.mcap records to the folder X)")
    p.add_argument("--no-record", action="store_true", help="do not record the session")
    p.add_argument("--job", type=path_argument, metavar="FILE",
                   help="the job file: the garment being folded, kept so a restarted cell resumes it "
                        "after its last completed fold (default <folder of the session log, or runs>/"
                        "<cell>.job.json)")
    p.add_argument("--table-model", type=path_argument, metavar="FILE",
                   help="table colour model (default from config)")
    p.add_argument("--camera", choices=MOUNTS,
                   help="where the cell's camera is: fixed above the table, or on r1's wrist, looking from "
                        "the views of config/camera.yaml (default: its mount)")
    p.add_argument("--controller", metavar="URL",
                   help="the controller: zenoh (the emulator or an adapter on the cell's Zenoh), or "
                        "motoros://HOST[:PORT] (a DX100's MotoROS, or `controller serve --motoros`; the "
                        "state port is PORT + 1, default port 50240); default config/cell.yaml's")
    add_wire_arguments(p)
    add_json_log(p)
    p.set_defaults(func=cmd_run)


def cmd_run(args: argparse.Namespace) -> int:
    # heavy imports here, not at the top: every `foldcell` command imports this module for its --help
    from cell.config import load_cell_config
    from cell.daemon import PROCESS_NAME, CellDaemon
    from cell.perception.config import load_perception_config
    from cell.perception.pipeline import load_garment_models, load_table_model
    from cell.planning.folds import FoldPlanner
    from cell.runner import Perception
    from cell.wrist import wrist_camera
    from drivers.camera.model import default_camera_config
    from drivers.common.scheduling import load_priorities
    from drivers.controller.link import controller_address
    from drivers.robot.table import default_table_config
    from drivers.sessions.mcap.bag import bag_folder
    from drivers.sessions.mcap.config import load_session_log_config
    from drivers.wire.transport import Wire

    settings = wire_settings(args, "cell")
    config = load_cell_config(args.config)
    if args.controller is not None:
        try:
            controller_address(args.controller)
        except ValueError as exc:
            return error_exit(f"--controller: {exc}")
        config = dataclasses.replace(config, controller=args.controller)
    perception_config = load_perception_config()
    perception = Perception(perception_config, load_table_model(args.table_model, perception_config),
                            load_garment_models(perception_config))
    planner = FoldPlanner()
    camera_config = default_camera_config()
    wrist = None
    if (args.camera or camera_config.mount) == "wrist":
        wrist = wrist_camera(planner.motion, camera_config, default_table_config())
    record = None
    if not args.no_record:
        stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
        record = bag_folder(args.record or settings.runs_directory / f"{settings.cell_id}-{stamp}")
    job_folder = record.parent if record else settings.runs_directory  # the job sits beside the session log
    job_file = args.job or job_folder / f"{settings.cell_id}.job.json"
    stop = StopSignal()
    run_at_priority(args, "cell", PROCESS_NAME)
    with Wire(settings, PROCESS_NAME, announce=False) as wire:
        daemon = CellDaemon(wire, config, perception, planner, default_table_config(), record,
                            load_session_log_config(settings.config_file), wrist, job_file,
                            load_priorities(args.config).perception)
        daemon.start()
        wire.announce()  # alive only once cell/command is served
        recording = f", recording to {record}" if record else ""
        announce(args, f"cell {settings.cell_id} ready{recording}; job file {job_file}: {daemon.restored}",
                 cell=settings.cell_id, record=record, job_file=job_file, job=daemon.restored)
        stop.wait()
        daemon.close()
    if daemon.recorder is not None:
        stats = daemon.recorder.close()
        files = ", ".join(p.name for p in stats.files)
        print(f"session log: {stats.bag} ({files}; {stats.recorded} samples)", file=sys.stderr)
    return 0
