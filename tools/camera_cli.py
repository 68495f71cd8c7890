"""`foldcell camera serve|capture`: the camera process and a one-shot capture over Zenoh."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
from pathlib import Path
from typing import Any

from drivers.camera.base import Camera
from drivers.camera.directory import DirectoryCamera
from drivers.camera.errors import CameraError, CameraSourceError
from drivers.camera.model import MOUNTS
from drivers.camera.node import PROCESS_NAME, CameraNode
from drivers.camera.opencv_device import OpenCVDeviceCamera
from drivers.camera.source import SOURCE_HELP, parse_source
from drivers.camera.zenoh_client import ZenohCamera
from drivers.common.garments import CATEGORIES
from drivers.sim.config import FOLDINGS
from drivers.wire.transport import Wire
from tools.common import (
    StopSignal,
    add_json_log,
    add_wire_arguments,
    announce,
    check_seconds,
    error_exit,
    meeting_point_note,
    path_argument,
    print_json,
    run_at_priority,
    wire_settings,
)

INFO_PERIOD_S = 1.0  # camera/info, camera/pose and sim/truth are repeated this often for late joiners


def register(subparsers: Any) -> None:
    cam = subparsers.add_parser("camera", help="the camera process, and captures over Zenoh",
                                description="Serve a camera on a cell's key space, or take one image "
                                            "from it.")
    group = cam.add_subparsers(dest="camera_command", metavar="COMMAND", required=True)

    p = group.add_parser("serve",
                         help="answer camera/capture; publish camera/image, camera/info, camera/pose",
                         description="The camera process. `sim` renders the simulated garment world, "
                                     "which follows the emulated grippers; `dir:PATH` serves a folder's "
                                     "images in order; `device:N` reads an OpenCV capture device.")
    p.add_argument("--source", default="sim", help=f"{SOURCE_HELP} (default sim)")
    p.add_argument("--seed", type=int, default=0, help="sim: the scene's seed (default 0)")
    p.add_argument("--garment", choices=CATEGORIES, default="towel", help="sim: the garment category")
    p.add_argument("--folded", action="store_true", help="sim: start from a garment folded by its recipe")
    p.add_argument("--folding", choices=FOLDINGS, help="sim: how the world folds: physics (cloth, "
                   "config/physics.yaml) or geometric (fast, blind to the path); default config/sim.yaml's")
    p.add_argument("--mount", choices=MOUNTS,
                   help="sim: the camera fixed above the table or on r1's wrist, following the arm "
                        "(default: config/camera.yaml's mount)")
    add_wire_arguments(p)
    add_json_log(p)
    p.set_defaults(func=cmd_serve)

    p = group.add_parser("capture", help="take one image from the cell's camera process")
    p.add_argument("-o", "--output", type=path_argument, default=Path("capture.png"),
                   help="PNG file (default capture.png)")
    p.add_argument("--timeout", type=float, default=5.0, metavar="S")
    p.add_argument("--json", action="store_true", help="print the camera info as JSON")
    add_wire_arguments(p)
    p.set_defaults(func=cmd_capture)


def open_source(text: str, seed: int = 0, category: str = "towel", folded: bool = False,
                folding: str | None = None, mount: str | None = None) -> Camera:
    """A (not yet connected) camera for a `--source` string; `seed`/`category` pick the sim scene,
    `folding` how its world folds and `mount` where its camera sits (None: as configured)."""
    spec = parse_source(text)
    if spec.kind == "sim":
        from drivers.sim.camera import SimCamera  # the simulated world is heavy: only when asked for

        return SimCamera(seed=seed, category=category, folded=folded, folding=folding, mount=mount)
    if spec.kind == "dir":
        return DirectoryCamera(spec.path)
    return OpenCVDeviceCamera(spec.index)


def cmd_serve(args: argparse.Namespace) -> int:
    if args.seed < 0:
        raise ValueError(f"--seed: must be >= 0, got {args.seed}")
    settings = wire_settings(args, "camera")
    camera = open_source(args.source, seed=args.seed, category=args.garment, folded=args.folded,
                         folding=args.folding, mount=args.mount)
    stop = StopSignal()
    run_at_priority(args, "camera", PROCESS_NAME)
    with contextlib.ExitStack() as opened:
        try:
            opened.enter_context(camera)
        except CameraSourceError as exc:
            raise CameraSourceError(f"--source: {exc}") from exc
        wire = opened.enter_context(Wire(settings, PROCESS_NAME, announce=False))
        nodes: list[Any] = []
        if parse_source(args.source).kind == "sim":
            from drivers.sim.camera import SimCamera  # the simulated world is heavy: only when asked for
            from drivers.sim.node import SimWorldNode

            assert isinstance(camera, SimCamera)
            nodes.append(SimWorldNode(wire, camera, INFO_PERIOD_S))  # the world follows the grippers first
        nodes.append(CameraNode(wire, camera, INFO_PERIOD_S))
        for node in nodes:
            node.start()
        wire.announce()  # alive only once camera/capture is served
        announce(args, f"camera ({args.source}) serving foldcell/{settings.cell_id}/camera/capture",
                 cell=settings.cell_id, source=args.source)
        stop.wait()
        for node in reversed(nodes):
            node.close()
    return 0


def cmd_capture(args: argparse.Namespace) -> int:
    check_seconds("--timeout", args.timeout)
    settings = wire_settings(args, "operator")
    alone = meeting_point_note(settings)
    try:
        with Wire(settings, f"cli-camera-capture-{os.getpid()}") as wire, \
                ZenohCamera(wire, args.timeout) as camera:
            frame = camera.capture()
    except CameraError as exc:   # no camera, or one too slow: a runtime failure, not a usage error
        return error_exit(f"no image: {exc}{alone}", 1)
    args.output.write_bytes(frame.png)
    if args.json:
        print_json({"file": str(args.output), "stamp": frame.stamp, "width": frame.info.width,
                    "height": frame.info.height, "k": frame.info.k,
                    "pose_in_world": frame.info.pose_in_world})
    else:
        print(f"{args.output}: {frame.info.width}x{frame.info.height}", file=sys.stderr)
    return 0
