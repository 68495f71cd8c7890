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
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from cell.evaluation.dataset import best_naming
from drivers.camera.model import MOUNTS, default_camera_config
from drivers.common.garments import CATEGORIES, LANDMARKS
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
TERMINAL_STATES = ("done", "failed", "fault")
NOTED_TRIGGERS = ("retry", "interrupt")  # steps redone on the way: notes, not the garment's failure
IOU_RESOLUTION_M = 0.001       # raster cell when comparing the final outline with the ideal fold
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


@dataclass
class GarmentRun:
    category: str
    seed: int
    outcome: str = ""
    reason: str = ""   # why the garment did not end done; empty when it did
    notes: list[str] = field(default_factory=list)  # steps redone on the way, and why
    states: list[str] = field(default_factory=list)
    perceptions: list[dict] = field(default_factory=list)
    fold_reports: list[dict] = field(default_factory=list)
    final_truth: Any = None             # the last ground truth (SimTruth) once the garment ended
    truth_landmarks: dict[str, tuple[float, float]] = field(default_factory=dict)
    wall_time_s: float = 0.0
    naming: dict[str, str] | None = None   # the cell's flat landmark names -> the truth's (symmetry)


class Observer:
    """The demo's view of the cell: states, perceptions with their ground truth, fold reports."""

    def __init__(self, wire: Wire, progress: bool):
        self.wire = wire
        self.progress = progress
        self.lock = threading.Condition()
        self.state = ""
        self.state_msg: Any = None
        self.reason_shown = ""
        self.run: GarmentRun | None = None
        self.truth: Any = None
        self.truths = 0
        self.transitions_seen: set[tuple[int, str]] = set()  # (stamp, trigger) of the cell's history
        wire.subscribe("cell/state", self._on_state)
        wire.subscribe("perception/observation", self._on_observation)
        wire.subscribe("sim/truth", self._on_truth)
        wire.subscribe("cell/fold_report", self._on_report)

    def _on_state(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            changed = msg.state != self.state
            self.state, self.state_msg = msg.state, msg
            self._note_redone_steps(msg)
            if changed and self.run is not None:
                self.run.states.append(msg.state)
                if self.progress:
                    where = f" fold {msg.fold_index}/{msg.fold_count}" if msg.fold_count else ""
                    # a reason once, when it comes: the cell keeps it through the states that follow
                    why = f" ({msg.reason})" if msg.reason and msg.reason != self.reason_shown else ""
                    self.reason_shown = msg.reason
                    print(f"  [{self.run.category}]{where} {msg.state}{why}", file=sys.stderr, flush=True)
            self.lock.notify_all()

    def _note_redone_steps(self, msg: Any) -> None:
        """Each retry or interruption in the cell's history, once, as a note of the garment (those seen
        before it began are marked seen and belong to no garment)."""
        for t in msg.history:
            seen = (messages.stamp_to_ns(t.stamp), t.trigger)
            if t.trigger in NOTED_TRIGGERS and seen not in self.transitions_seen:
                self.transitions_seen.add(seen)
                if self.run is not None:
                    self.run.notes.append(f"{t.trigger} after {t.source}: {t.reason}")

    def outcome_reason(self, outcome: str) -> str:
        """Why the garment ended `outcome`: the cell's reason, except for a garment done (a reason
        left from a retried step is a note, not a failure)."""
        with self.lock:
            if outcome == "done" or self.state_msg is None:
                return ""
            return str(self.state_msg.reason)

    def _on_truth(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            self.truth = msg
            self.truths += 1
            self.lock.notify_all()

    def fresh_truth(self, timeout_s: float) -> Any:
        """The first ground truth published from now on (a physics world publishes once it has
        simulated what it was shown); the last one when none comes within `timeout_s`."""
        with self.lock:
            seen = self.truths
            self.lock.wait_for(lambda: self.truths > seen, timeout_s)
            return self.truth

    def _on_observation(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            if self.run is None or self.truth is None:
                return
            truth = {lm.name: (lm.x_table, lm.y_table) for lm in self.truth.landmarks}
            seen = {lm.name: (lm.x_table, lm.y_table) for lm in msg.landmarks}
            flat = LANDMARKS[self.run.category]
            if self.run.naming is None and all(n in seen and n in truth for n in flat):
                # a towel turned by 180 degrees looks the same: the cell's naming of the flat garment
                # is scored as the symmetry that fits best, and its names keep that meaning after folds
                self.run.naming = best_naming(seen, truth, flat, self.run.category, facing_known=True)
            naming = self.run.naming or {}
            errors = {name: float(np.hypot(x - truth[naming.get(name, name)][0],
                                           y - truth[naming.get(name, name)][1]))
                      for name, (x, y) in seen.items() if naming.get(name, name) in truth}
            self.run.perceptions.append({
                "fold_index": int(msg.fold_index), "cost": float(msg.cost),
                "landmark_error_cm": {k: round(v * 100, 3) for k, v in errors.items()},
                "median_error_cm": (round(float(np.median(list(errors.values()))) * 100, 3)
                                    if errors else None),
                "timings_ms": {t.stage: round(t.seconds * 1e3, 2) for t in msg.timings}})

    def _on_report(self, _k: str, msg: Any, _r: Any) -> None:
        with self.lock:
            if self.run is not None:
                self.run.fold_reports.append({
                    "fold_index": int(msg.fold_index), "attempt": int(msg.attempt), "outcome": msg.outcome,
                    "verify_iou": round(float(msg.verify_iou), 4),
                    "robot_time_s": round(float(msg.robot_time), 2),
                    "timings_s": {t.stage: round(t.seconds, 4) for t in msg.timings}})

    def begin(self, run: GarmentRun) -> None:
        with self.lock:
            self.run, self.truth = run, None

    def wait_state(self, state: str, timeout: float) -> bool:
        """Until the cell reports `state` (True), or `timeout` s pass."""
        with self.lock:
            return self.lock.wait_for(lambda: self.state == state, timeout)

    def wait_terminal(self, timeout: float, stop: StopSignal, processes: Processes) -> str:
        deadline = time.monotonic() + timeout
        with self.lock:
            while self.state not in TERMINAL_STATES:
                if stop.is_set():
                    return "interrupted"
                if processes.dead():
                    return f"process {', '.join(processes.dead())} exited"
                if time.monotonic() > deadline:
                    return "timeout"
                self.lock.wait(0.2)
            return self.state


def _flat_garment(truth: Any) -> tuple[dict[str, tuple[float, float]], np.ndarray]:
    """The flat garment a SimTruth carries: its landmarks and outline, table frame (m)."""
    return ({lm.name: (lm.x_table, lm.y_table) for lm in truth.flat_landmarks},
            np.array([[p.x, p.y] for p in truth.flat_outline_table]))


def final_iou(category: str, truth: Any) -> float:
    """IoU of the garment's outline in the ground truth `truth` (a SimTruth) with its flat garment,
    as laid (and moved by any pull), folded perfectly by the whole recipe."""
    from cell.evaluation.ideal_fold import ideal_fold_iou, ideal_folds

    landmarks, flat_outline = _flat_garment(truth)
    silhouette = np.array([[p.x, p.y] for p in truth.silhouette_table])
    every_fold = len(ideal_folds(category, landmarks))
    return ideal_fold_iou(category, landmarks, flat_outline, every_fold, [silhouette], IOU_RESOLUTION_M)


def fold_success(category: str, truth: Any) -> dict | None:
    """The fold-success measure of the whole recipe (cell/evaluation/fold_success.py) on the ground
    truth `truth` (a SimTruth): where the garment's landmarks lie against the open-loop ideal, and its
    area. None where the world does not follow landmarks through the cloth (the geometric world)."""
    from cell.evaluation.fold_success import load_success_criteria, score_recipe
    from drivers.sim.geometry import signed_area

    if not truth.landmark_vertex_names:
        return None
    flat, flat_outline = _flat_garment(truth)
    after = {name: (p.x, p.y)
             for name, p in zip(truth.landmark_vertex_names, truth.landmark_vertices, strict=True)}
    area = abs(signed_area(np.array([[p.x, p.y] for p in truth.silhouette_table])))
    score = score_recipe(category, flat, flat_outline, after, area, load_success_criteria())
    return {"success": score.success, "cause": score.cause, "detail": score.detail,
            "landmark_error_cm_max": round(score.max_error_m * 100, 2),
            "landmark_error_cm_mean": round(score.mean_error_m * 100, 2),
            "area_ratio": round(score.area_ratio, 3)}


def summarise(run: GarmentRun) -> dict:
    # a fold the cell's own check called imperfect is not counted as done
    folds_done = sum(1 for r in run.fold_reports if r["outcome"] == "done")
    folds_imperfect = sum(1 for r in run.fold_reports if r["outcome"].startswith("done, imperfect"))
    iou = None
    iou_note = ""
    measure = None
    if run.final_truth is not None:
        try:
            iou = round(final_iou(run.category, run.final_truth), 4)
            if run.outcome == "done":
                measure = fold_success(run.category, run.final_truth)
        except ValueError as exc:  # the ideal fold is not defined on this garment
            iou_note = f"no ideal fold to compare with: {exc}"
    stage_totals: dict[str, float] = {}
    for r in run.fold_reports:
        for k, v in r["timings_s"].items():
            stage_totals[k] = stage_totals.get(k, 0.0) + v
    errors = [p["median_error_cm"] for p in run.perceptions if p["median_error_cm"] is not None]
    return {
        "garment": run.category, "seed": run.seed, "outcome": run.outcome, "reason": run.reason,
        "notes": list(run.notes),
        "folds_done": folds_done, "folds_imperfect": folds_imperfect, "final_iou": iou,
        **({"final_iou_note": iou_note} if iou_note else {}),
        "fold_success": measure,
        "landmark_error_cm": {"per_perception_median": errors,
                              "median": round(float(np.median(errors)), 3) if errors else None},
        "compute_s": {k: round(v, 3) for k, v in stage_totals.items() if k != "execute"},
        "robot_time_s": round(sum(r["robot_time_s"] for r in run.fold_reports), 2),
        "wall_time_s": round(run.wall_time_s, 1), "states": run.states,
        "perceptions": run.perceptions, "folds": run.fold_reports,
    }


def cmd_demo(args: argparse.Namespace) -> int:
    args.time_scale = demo_time_scale(args)
    if not 0 < args.time_scale < math.inf:
        raise ValueError(f"--time-scale: must be > 0, got {args.time_scale}")
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
                if run.outcome == "error":
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
    ok = runs and all(r.outcome == "done" for r in runs) and len(runs) == len(garments)
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
            run.outcome, run.reason = "interrupted", "stopped before its folding began"
        else:
            run.outcome, run.reason = "error", "camera did not start"
        run.wall_time_s = time.monotonic() - started
        processes.stop("camera")
        return run
    say(f"[{category}] folding (seed {seed})")
    reply = _cell_command(wire, "fold", category)
    if not reply.accepted:
        run.outcome, run.reason = "rejected", reply.text
    else:
        run.outcome = observer.wait_terminal(GARMENT_TIMEOUT_S, stop, processes)
        run.reason = observer.outcome_reason(run.outcome)
        truth = observer.fresh_truth(TRUTH_TIMEOUT_S)
        run.final_truth = truth
    run.wall_time_s = time.monotonic() - started
    if run.outcome in ("failed", "fault", "timeout", "interrupted"):
        _cell_command(wire, "abort", "")
    refusal = _reset_cell(wire, observer, stop)
    if refusal:
        run.notes.append(f"the cell could not be reset for the next garment: {refusal}")
    processes.stop("camera")
    say(f"[{category}] {run.outcome}" + (f": {run.reason}" if run.reason else ""))
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
