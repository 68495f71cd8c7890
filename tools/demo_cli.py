"""`foldcell demo`: the embedded default. Starts the controller emulator (master and slave), the simulated
camera and the cell daemon as separate processes on loopback Zenoh, folds simulated garments end to
end, and writes the session log, a summary and an HTML report."""

from __future__ import annotations

import argparse
import ctypes
import datetime as dt
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from cell.evaluation.demo_run import GarmentRun, Observer, summarise
from drivers.camera.model import MOUNTS, default_camera_config
from drivers.common.garments import CATEGORIES
from drivers.common.outcomes import GarmentOutcome
from drivers.sim.config import FOLDINGS, load_sim_config
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.security import ROUTER_ROLE, role_directory
from drivers.wire.transport import Wire, process_of
from tools.common import (
    StopSignal,
    add_wire_arguments,
    error_exit,
    path_argument,
    print_json,
    wire_arguments,
    wire_settings,
)

DEFAULT_TIME_SCALE = 10.0      # robot time runs 10x faster, so `make demo` folds all four garments in minutes
STARTUP_TIMEOUT_S = 60.0       # processes import numpy, OpenCV, pinocchio, OMPL...
GARMENT_TIMEOUT_S = 240.0      # wall time for one garment, a hang guard
TRUTH_TIMEOUT_S = 5.0   # the ground truth is published every second (camera_cli INFO_PERIOD_S)
RESET_TIMEOUT_S = 10.0  # a reset refused (an alarm kept while a controller comes back) is asked again
RESET_POLL_S = 0.5
CONTROLLER_LINKS = ("zenoh", "motoros")
MOTOROS_PORTS = 3              # motion, state and IO ports: PORT, PORT + 1, PORT + 2


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "demo", help="fold simulated garments end to end with every process on loopback Zenoh",
        description="The main job on the embedded default: starts `controller serve` (master and slave, "
                    "or one serving MotoROS with --controller motoros), "
                    "`camera serve --source sim` and `run` as separate processes on a private loopback "
                    "endpoint, folds the garment(s), prints a summary per garment and writes the session "
                    "log (MCAP), summary.json and report.html under --output. The summary scores each "
                    "garment done against the simulated world's truth: IoU with the recipe's perfect "
                    "folds, and (physics world) the fold-success measure: every landmark within 5 cm of "
                    "its place after the recipe, the area within 15 %.")
    p.add_argument("--garment", default="all", choices=(*CATEGORIES, "all"),
                   help="category to fold (default all)")
    p.add_argument("--seed", type=int, default=1, help="scene seed of the simulated world (default 1)")
    p.add_argument("--time-scale", type=float, metavar="K",
                   help=f"robot time runs K times faster than wall time (default {DEFAULT_TIME_SCALE:g}; "
                        "1 for the cloth physics over --controller motoros)")
    p.add_argument("--camera", choices=MOUNTS,
                   help="the cell's camera fixed above the table, or on r1's wrist as in the paper, "
                        "looking from the views of config/camera.yaml (default: its mount)")
    p.add_argument("-o", "--output", type=path_argument, metavar="DIR",
                   help="output folder (default a new folder under runs/)")
    p.add_argument("--json", action="store_true", help="print the summary as JSON on stdout")
    p.add_argument("--controller", choices=CONTROLLER_LINKS, default="zenoh",
                   help="how the cell drives the emulator: zenoh (master and slave on the cell's Zenoh, "
                        "default) or motoros (one `controller serve --motoros` on a free loopback port, "
                        "off the cell's Zenoh like a real DX100; the cell runs with --controller "
                        "motoros://127.0.0.1:PORT)")
    p.add_argument("--folding", choices=FOLDINGS, help="how the simulated world folds: physics (cloth) or "
                   "geometric (fast, blind to the path); default config/sim.yaml's")
    add_wire_arguments(p)
    p.epilog = ("--security DIR: the demo starts every role, so it takes the top directory of `foldcell "
                "security init DIR` and gives each process its role's directory there.")
    p.set_defaults(func=cmd_demo)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def free_ports(count: int = MOTOROS_PORTS) -> int:
    """The first of `count` consecutive free loopback ports (MotoROS: motion, state, IO)."""
    for _ in range(50):
        first = free_port()
        probes = [socket.socket() for _ in range(count)]
        try:
            for offset, probe in enumerate(probes):
                probe.bind(("127.0.0.1", first + offset))
        except OSError:
            continue
        finally:
            for probe in probes:
                probe.close()
        return first
    raise RuntimeError(f"no {count} consecutive free loopback ports")


def _die_with_parent() -> None:
    """In a child before exec: Linux sends it SIGTERM when the demo dies, even by SIGKILL, so no
    controller, camera or cell outlives a demo killed from outside (a CI timeout)."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
    except (OSError, AttributeError):  # not Linux: the demo's own SIGINT/SIGTERM handling remains
        pass


PR_SET_PDEATHSIG = 1  # <sys/prctl.h>


class StartupFailed(Exception):
    """A child process the demo needs did not come up: the message ends with the last line of the
    log of each child that died."""

    def __init__(self, what: str, processes: Processes):
        last_words = []
        for name in processes.dead():
            lines = (processes.log_dir / f"{name}.log").read_text(errors="replace").strip().splitlines()
            last_words.append(f"{name}: {lines[-1] if lines else 'exited without a word'}")
        super().__init__("; ".join([what, *last_words, f"logs in {processes.log_dir}"]))


def _wait_listening(endpoint: str, timeout: float, stop: StopSignal, processes: Processes) -> bool:
    """Until something accepts TCP connections at `endpoint` (tcp/HOST:PORT)."""
    host, _, port = endpoint.split("/", 1)[1].rpartition(":")
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not stop.is_set() and not processes.dead():
        try:
            with socket.create_connection((host.strip("[]"), int(port)), timeout=1.0):
                return True
        except OSError:
            stop.wait(0.1)
    return False


class Processes:
    """The demo's child processes: started with the same connection flags, stopped with SIGINT. On a
    secured cell each is given its role's directory in `security`, the top one of `security init`."""

    def __init__(self, wire_args: list[str], log_dir: Path, verbose: int = 0, security: Path | None = None):
        self.wire_args = wire_args
        self.security = security
        self.log_dir = log_dir
        self.verbose = ["-v"] * verbose   # `foldcell -v demo`: the children's logs as detailed as ours
        self.children: dict[str, subprocess.Popen] = {}

    def start(self, name: str, *args: str, role: str, wire_args: list[str] | None = None) -> None:
        """`role`: the process's on a secured cell (config/security.yaml); `wire_args`: other
        connection flags than the demo's."""
        wire_args = self.wire_args if wire_args is None else wire_args
        if self.security is not None:
            wire_args = [*wire_args, "--security", str(role_directory(self.security, role))]
        # the child writes to its own copy of the log's descriptor; ours closes once it has started
        with open(self.log_dir / f"{name}.log", "ab") as log:
            # own process group: Ctrl-C in the terminal reaches the demo, which stops the children in order
            self.children[name] = subprocess.Popen(
                [sys.executable, "-m", "tools.cli", *self.verbose, *args, *wire_args], stdout=log, stderr=log,
                start_new_session=True, preexec_fn=_die_with_parent,
                env=dict(os.environ, PYTHONUNBUFFERED="1"))

    def stop(self, name: str, timeout: float = 15.0) -> int | None:
        proc = self.children.pop(name, None)
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        return proc.returncode

    def dead(self) -> list[str]:
        return [n for n, p in self.children.items() if p.poll() is not None]

    def stop_all(self) -> None:
        for name in reversed(list(self.children)):
            self.stop(name)


def cmd_demo(args: argparse.Namespace) -> int:
    args.time_scale = demo_time_scale(args)
    if not 0 < args.time_scale < math.inf:
        raise ValueError(f"--time-scale: must be a finite number > 0, got {args.time_scale}")
    if args.seed < 0:
        raise ValueError(f"--seed: must be >= 0, got {args.seed}")
    if not args.listen and not args.connect:
        # a private endpoint: the demo never joins (or disturbs) a cell already running on this machine
        port = free_port()
        args.listen = [f"tcp/127.0.0.1:{port}", "tcp/127.0.0.1:0"]
        args.connect = [f"tcp/127.0.0.1:{port}"]
    settings = wire_settings(args, "operator")
    # the demo starts every role: it is given the top directory of `security init`, and each process
    # (itself too) its own role's directory there
    security = settings.security
    if security is not None:
        settings = replace(settings, security=role_directory(security, "operator"))
        args.security = None
    stamp = dt.datetime.now(dt.timezone.utc).strftime("%Y%m%dT%H%M%SZ")
    out = args.output or settings.runs_directory / f"demo-{stamp}"
    (out / "logs").mkdir(parents=True, exist_ok=True)
    garments = CATEGORIES if args.garment == "all" else (args.garment,)
    mount = args.camera or default_camera_config().mount
    meeting_point = settings.connect[0] if settings.connect else settings.listen[0]
    stop = StopSignal()   # from here on Ctrl-C ends with the summary
    say(f"foldcell demo: cell {settings.cell_id} on {meeting_point}, time scale {args.time_scale:g}, "
        f"{mount} camera, output {out}")
    say(f"  watch it live: foldcell monitor --cell {settings.cell_id} --connect {meeting_point}")
    processes = Processes(wire_arguments(args), out / "logs", args.verbose, security)
    session = out / "session"  # a rosbag2 bag: session/session_0.mcap, metadata.yaml
    runs: list[GarmentRun] = []
    started = time.monotonic()
    try:
        if settings.security is not None:   # a secured cell meets at its router (drivers/wire/security.py)
            processes.start("router", "router", role=ROUTER_ROLE)
            if not _wait_listening(settings.listen[0], STARTUP_TIMEOUT_S, stop, processes):
                raise StartupFailed(f"the router did not serve {settings.listen[0]}", processes)
        controller_url, on_zenoh = start_controllers(args, settings.cell_id, processes, stop)
        processes.start("cell", "run", "--record", str(session), "--camera", mount,
                        "--controller", controller_url, role="cell")
        with Wire(settings, f"cli-demo-{os.getpid()}") as wire:
            observer = Observer(wire, progress=not args.json or sys.stderr.isatty())
            need = {"cell", *on_zenoh}
            if not _wait_alive(wire, need, STARTUP_TIMEOUT_S, stop, processes):
                if not stop.is_set():
                    raise StartupFailed(f"processes did not start: {sorted(need - _alive(wire))}", processes)
                say("interrupted before the cell's processes were all up: no garment was begun")
            for category in garments:
                if stop.is_set():
                    break
                run = fold_one(wire, observer, processes, stop, category, args.seed, mount, args.folding)
                runs.append(run)
                if run.outcome is not None and run.outcome.ends_the_run:
                    break
    except StartupFailed as exc:
        return error_exit(str(exc))
    finally:
        # the controllers' logs after this say how they were stopped (a slave stopped first is a lost
        # link to its master), not how the garments went
        stopping = dt.datetime.now().isoformat(sep=" ", timespec="milliseconds")
        processes.stop_all()
    summary = {
        "time_scale": args.time_scale, "seed": args.seed, "camera": mount,
        "wall_time_s": round(time.monotonic() - started, 1), "processes_stopped_at": stopping,
        "session_log": str(session), "report": str(out / "report.html"),
        "garments": [summarise(r) for r in runs],
    }
    write_outputs(summary, session, out)
    if args.json:
        print_json(summary)
    else:
        print_summary(summary)
    if stop.is_set():   # cut short: the shell's convention, 128 + the signal's number
        return 128 + int(getattr(signal, stop.signal_name or "SIGINT"))
    ok = runs and all(r.outcome is GarmentOutcome.DONE for r in runs) and len(runs) == len(garments)
    return 0 if ok else 1


def start_controllers(args: argparse.Namespace, cell_id: str, processes: Processes,
                      stop: StopSignal) -> tuple[str, set[str]]:
    """The emulator: master and slave on the cell's Zenoh, or one controller serving MotoROS on free
    loopback ports and kept off the cell's keys (another cell id), as a real DX100 is. Returns the
    cell's --controller URL and the controller processes to wait for on the cell's Zenoh."""
    time_scale = ("--time-scale", str(args.time_scale))
    if args.controller == "zenoh":
        for role in ("master", "slave"):
            processes.start(f"controller-{role}", "controller", "serve", "--role", role, *time_scale,
                            role=role)
        return "zenoh", {"controller-master", "controller-slave"}
    port = free_ports()
    own_cell = argparse.Namespace(**{**vars(args), "cell": f"{cell_id}-motoros"})
    processes.start("controller", "controller", "serve", "--role", "both", *time_scale,
                    "--motoros", f"127.0.0.1:{port}", role="controller", wire_args=wire_arguments(own_cell))
    state_port = f"tcp/127.0.0.1:{port + 1}"  # the state port: a probe there takes no motion slot
    if not _wait_listening(state_port, STARTUP_TIMEOUT_S, stop, processes):
        raise StartupFailed(f"the controller did not serve MotoROS on 127.0.0.1:{port}", processes)
    return f"motoros://127.0.0.1:{port}", set()


def say(*parts: object) -> None:
    """Progress for the person watching (stderr; stdout is for --json)."""
    print(*parts, file=sys.stderr, flush=True)


def demo_time_scale(args: argparse.Namespace) -> float:
    """The time scale the demo runs at. Over MotoROS the cell stamps the robot's joint states with the
    wall clock (MotoROS carries no robot time), so the cloth physics, which follows the arms' path in
    stamp time, would see them move K times too fast: there the scale is 1."""
    physics = (args.folding or load_sim_config().folding) == "physics"
    if args.controller != "motoros" or not physics:
        return DEFAULT_TIME_SCALE if args.time_scale is None else float(args.time_scale)
    if args.time_scale not in (None, 1.0):
        raise ValueError(f"--time-scale: must be 1 for the cloth physics over --controller motoros, got "
                         f"{args.time_scale:g} (the joint states from MotoROS are stamped with the wall "
                         "clock, so the cloth would see the arms move that many times too fast); or give "
                         "--folding geometric")
    return 1.0


def fold_one(wire: Wire, observer: Observer, processes: Processes, stop: StopSignal, category: str,
             seed: int, mount: str, folding: str | None = None) -> GarmentRun:
    """One garment: a camera process with its scene, the fold command, the wait, the clean-up."""
    run = GarmentRun(category, seed)
    observer.begin(run)
    started = time.monotonic()
    processes.start("camera", "camera", "serve", "--source", "sim", "--seed", str(seed),
                    "--garment", category, "--mount", mount, *(("--folding", folding) if folding else ()),
                    role="camera")
    if not _wait_alive(wire, {"camera"}, STARTUP_TIMEOUT_S, stop, processes):
        if stop.is_set():
            run.outcome, run.reason = GarmentOutcome.INTERRUPTED, "stopped before its folding began"
        else:
            run.outcome, run.reason = GarmentOutcome.ERROR, "camera did not start"
        run.wall_time_s = time.monotonic() - started
        processes.stop("camera")
        return run
    say(f"[{category}] folding (seed {seed})")
    reply = _cell_command(wire, "fold", category)
    if not reply.accepted:
        run.outcome, run.reason = GarmentOutcome.REJECTED, reply.text
    else:
        run.outcome, run.reason = observer.wait_terminal(GARMENT_TIMEOUT_S, stop, processes)
        truth = observer.fresh_truth(TRUTH_TIMEOUT_S)
        run.final_truth = truth
    run.wall_time_s = time.monotonic() - started
    if run.outcome in (GarmentOutcome.FAILED, GarmentOutcome.FAULT, GarmentOutcome.TIMEOUT,
                       GarmentOutcome.INTERRUPTED):
        _cell_command(wire, "abort", "")
    refusal = _reset_cell(wire, observer, stop)
    if refusal:
        run.notes.append(f"the cell could not be reset for the next garment: {refusal}")
    processes.stop("camera")
    say(f"[{category}] {run.outcome.value}" + (f": {run.reason}" if run.reason else ""))
    return run


def _reset_cell(wire: Wire, observer: Observer, stop: StopSignal) -> str:
    """Reset the cell (a fault's cause cleared on the controller) until it is idle, so the next garment
    starts clean; '' once it is, else the last refusal. A controller alarm that outlasts a lost link
    (the slave coming back) is asked again for up to RESET_TIMEOUT_S."""
    deadline = time.monotonic() + RESET_TIMEOUT_S
    refusal = ""
    while not stop.is_set():
        reply = _cell_command(wire, "reset", "")
        if reply.accepted and observer.wait_state("idle", RESET_POLL_S * 4):
            return ""
        refusal = reply.text if not reply.accepted else \
            f"the cell is {observer.state or 'silent'} after reset"
        if time.monotonic() > deadline:
            break
        stop.wait(RESET_POLL_S)
    return refusal


def write_outputs(summary: dict, session: Path, out: Path) -> None:
    """summary.json, and the report when there is a session to report on (`report` None otherwise)."""
    if not session.exists():
        summary["session_log"] = summary["report"] = None   # stopped before the recorder began one
    else:
        try:
            from drivers.sessions.report import write_report
            write_report(session, summary, out / "report.html")
        except Exception as exc:  # the summary stands without the report
            say(f"report not written: {type(exc).__name__}: {exc}")
            summary["report"] = None
    (out / "summary.json").write_text(json.dumps(summary, indent=2))


def _summary_row(g: dict) -> tuple[str, ...]:
    err = g["landmark_error_cm"]["median"]
    iou = g["final_iou"]
    measure = g["fold_success"]
    return (g["garment"], g["outcome"], str(g["folds_done"]), str(g["folds_imperfect"]),
            "-" if iou is None else f"{iou:.3f}",
            "-" if measure is None else "success" if measure["success"] else measure["cause"],
            "-" if err is None else f"{err:.2f}", f"{sum(g['compute_s'].values()):.2f}",
            f"{g['robot_time_s']:.1f}", f"{g['wall_time_s']:.1f}")


def print_summary(summary: dict) -> None:
    print(f"\nfoldcell demo summary (time scale {summary['time_scale']:g}: robot time runs "
          f"{summary['time_scale']:g}x faster than wall time)")
    columns = ("garment", "outcome", "folds", "imperfect", "IoU", "measure", "lm err cm", "compute s",
               "robot s", "wall s")
    rows = [_summary_row(g) for g in summary["garments"]]
    # each column as wide as its widest cell: an outcome such as `interrupted` keeps the others in line
    widths = [max(len(text) for text in column) for column in zip(columns, *rows, strict=True)]

    def line(cells: tuple[str, ...]) -> str:
        return " ".join(text.ljust(w) if i < 2 else text.rjust(w)
                        for i, (text, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    header = line(columns)
    print(header)
    print("-" * len(header))
    for g, row in zip(summary["garments"], rows, strict=True):
        print(line(row))
        measure = g["fold_success"]
        if g["reason"]:
            print(f"  reason: {g['reason']}")
        if measure is not None and not measure["success"]:
            print(f"  fold success: {measure['detail']} (landmarks {measure['landmark_error_cm_max']:.1f} cm "
                  f"max, area {measure['area_ratio']:.2f} of the ideal)")
        for note in g["notes"]:
            print(f"  note: {note}")
    print(f"\nsession log: {summary['session_log'] or 'none (stopped before one began)'}")
    print(f"report:      {summary['report'] or 'not written'}")
    print(f"total wall time: {summary['wall_time_s']:.1f} s")


def _alive(wire: Wire) -> set[str]:
    return {process_of(k) for k in wire.alive()}


def _wait_alive(wire: Wire, names: set[str], timeout: float, stop: StopSignal, processes: Processes) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not stop.is_set() and not processes.dead():
        if names <= _alive(wire):
            return True
        time.sleep(0.2)
    return names <= _alive(wire)


def _cell_command(wire: Wire, command: str, argument: str) -> Any:
    request = messages.new("foldcell_msgs/msg/CellCommand", header=messages.header(), command=command,
                           argument=argument, client="demo")
    try:
        return wire.request("cell/command", request, timeout=10.0)
    except WireError as err:
        return messages.new("foldcell_msgs/msg/CellReply", accepted=False, text=str(err))
