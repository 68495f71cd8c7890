"""The cell daemon (`foldcell run`): the work loop wired to Zenoh, the session recorder, the log.

Commands arrive on `cell/command`; the cell publishes `cell/state` (on change and periodically),
`cell/log`, `perception/observation`, `perception/annotations`, `plan/trajectory` and
`cell/fold_report`; it watches the liveliness of the processes it needs and the controller status,
and faults (stopping the robot) within a fraction of a second of losing one. With a job file it keeps
the garment it works on there, and on start takes up a job a previous run left unfinished (`paused`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from cell.config import CellConfig
from cell.jobfile import JobFile
from cell.planning.folds import FoldPlan, FoldPlanner
from cell.reports import FoldReport, PerceptionReport
from cell.runner import CellRunner, Perception
from cell.wrist import WristCamera
from drivers.camera.zenoh_client import ZenohCamera
from drivers.common.scheduling import set_thread_nice
from drivers.controller import codec
from drivers.controller.errors import ControllerError
from drivers.controller.interface import ControllerStatus
from drivers.controller.link import controller_link
from drivers.robot.table import TableConfig
from drivers.sessions.annotations import annotations_from_observation, load_annotation_style
from drivers.sessions.mcap.config import SessionLogConfig
from drivers.sessions.recorder import SessionRecorder
from drivers.wire import messages
from drivers.wire.transport import Wire, process_of
from statemachine.machine import WORK_STATES, TransitionRecord

log = logging.getLogger(__name__)

PROCESS_NAME = "cell"
LOG_LEVELS = {logging.DEBUG: 10, logging.INFO: 20, logging.WARNING: 30, logging.ERROR: 40,
              logging.CRITICAL: 50}


class WireLogHandler(logging.Handler):
    """Python logging -> `cell/log` (rcl_interfaces/Log), so the session log holds the cell's story."""

    def __init__(self, wire: Wire):
        super().__init__(logging.INFO)
        self.publisher = wire.publisher("cell/log")
        self.local = threading.local()

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(self.local, "busy", False):
            return  # logging from inside publishing must not recurse
        self.local.busy = True
        try:
            ns = int(record.created * 1e9)
            self.publisher.put(messages.new(
                "rcl_interfaces/msg/Log", stamp=messages.stamp_from_ns(ns),
                level=LOG_LEVELS.get(record.levelno, 20), name=record.name, msg=record.getMessage(),
                file=record.pathname, function=record.funcName, line=record.lineno))
        except Exception:
            pass  # a closed session while shutting down: the record is in stderr anyway
        finally:
            self.local.busy = False


class Pulse:
    """Whether this process itself could not run lately: the state ticker beats it every `period`; a
    beat a period overdue while the process used little CPU means it was stopped (SIGSTOP, a debugger)
    or starved, not busy (a busy interpreter still uses its CPU). A stop is remembered for `memory` s
    after it ends: its consequences (peers' links expired meanwhile) may be heard after the next beat."""

    BUSY_SHARE = 0.5   # of the overdue time spent on the CPU: above it the process was running

    def __init__(self, period: float, memory: float = 2.0):
        self.period = period
        self.memory = memory
        self.last = (time.monotonic(), time.process_time())
        self.stop: tuple[float, float] = (-math.inf, 0.0)   # (ended at, lasted) of the last stop

    def beat(self) -> None:
        stopped = self._stopped_since_last()
        self.last = (time.monotonic(), time.process_time())
        if stopped:
            self.stop = (self.last[0], stopped)

    def _stopped_since_last(self) -> float:
        wall, cpu = self.last
        since = time.monotonic() - wall
        overdue = since - self.period
        if overdue <= self.period or time.process_time() - cpu > overdue * self.BUSY_SHARE:
            return 0.0
        return since

    def stop_began(self) -> float | None:
        """When (monotonic s) the process's stop now, or in the last `memory` s, began; None if none."""
        if self._stopped_since_last():
            return self.last[0]
        ended, lasted = self.stop
        return ended - lasted if time.monotonic() - ended <= self.memory else None

    def stopped_for(self) -> float:
        """How long (s) the process was just stopped (now, or in the last `memory` s); 0 if it was not."""
        ended, lasted = self.stop
        recent = lasted if time.monotonic() - ended <= self.memory else 0.0
        return max(self._stopped_since_last(), recent)


class CellDaemon:
    """Owns the Wire side of the cell; the work itself is `CellRunner`'s."""

    def __init__(self, wire: Wire, config: CellConfig, perception: Perception, planner: FoldPlanner,
                 table: TableConfig, record_path: Path | None, log_config: SessionLogConfig,
                 wrist: WristCamera | None = None, job_file: Path | None = None, work_nice: int = 0):
        self.wire = wire
        self.config = config
        self.work_nice = work_nice   # the worker's (perception, planning): below the links' in priority
        self.stop = threading.Event()
        self.time_scale = 1.0
        self.state_pub = wire.publisher("cell/state")
        self.obs_pub = wire.publisher("perception/observation")
        self.ann_pub = wire.publisher("perception/annotations")
        self.plan_pub = wire.publisher("plan/trajectory")
        self.report_pub = wire.publisher("cell/fold_report")
        self.annotation_style = load_annotation_style()
        self.recorder = SessionRecorder(wire, record_path, log_config) if record_path else None
        self.log_handler = WireLogHandler(wire)
        for name in ("cell", "statemachine", "drivers"):
            logging.getLogger(name).addHandler(self.log_handler)
            logging.getLogger(name).setLevel(logging.INFO)
        self.camera = ZenohCamera(wire, config.camera_timeout_s, config.reply_timeout_s)
        self.link = controller_link(config.controller, wire, PROCESS_NAME)
        self.controller = self.link.controller
        self.required_processes = self.link.required(config.required_processes)
        self.runner = CellRunner(self.camera, self.controller, planner, perception, config, self, table,
                                 lambda: self.time_scale, wrist, JobFile(job_file) if job_file else None)
        self.state_lock = threading.Lock()
        self.lease_lock = threading.Lock()
        self.holding_lease = False
        self.seen_alive: set[str] = set()  # required processes whose token the cell has seen
        self.lost: set[str] = set()        # ... and has seen go since (until they are back)
        self.losses: dict[str, object] = {}  # the latest loss of each, watched until it is back
        self.appeared: dict[str, float] = {}  # when (monotonic s) each token was last seen appear
        self.pulse = Pulse(config.state_period_s)   # beaten by the state ticker
        self.faulted_stop: float | None = None       # when the stop began that last faulted the cell

    # ---------------------------------------------------------------- life cycle
    def start(self) -> None:
        self.camera.connect()
        self.wire.watch_alive(self._on_alive)
        self.controller.add_status_listener(self._on_status)
        self.controller.add_lease_listener(self._on_lease_taken)
        self.link.on_lost(self._on_controller_lost)
        self.link.start()
        self.restored = self.runner.restore_job()  # before commands: a `fold` must not race the old job
        self.wire.serve("cell/command", self._on_command)
        self.worker = threading.Thread(target=self._work, name="cell-worker", daemon=True)
        self.worker.start()
        self.ticker = threading.Thread(target=self._tick, name="cell-state", daemon=True)
        self.ticker.start()
        log.info("cell %s ready", self.wire.cell_id)

    def _work(self) -> None:
        set_thread_nice(self.work_nice, "the cell's worker (perception, planning)")
        self.runner.run(self.stop)

    def close(self) -> None:
        self.stop.set()
        if self.runner.machine.is_active:
            self.runner.stop_robot()
        self.worker.join(5.0)
        self.ticker.join(2.0)
        for name in ("cell", "statemachine", "drivers"):
            logging.getLogger(name).removeHandler(self.log_handler)
        try:
            self.link.close()
        except Exception:
            log.debug("controller disconnect failed", exc_info=True)

    def _connect_controller(self) -> None:
        if not self.controller.is_connected:
            self.controller.connect()
        self.controller.acquire_lease()
        self.holding_lease = True

    def _release_lease_when_idle(self) -> None:
        """An idle cell gives the lease up, so an operator may reset or move the robot by hand."""
        with self.lease_lock:
            if not self.holding_lease or self.runner.machine.is_active:
                return
            self.holding_lease = False
            try:
                self.controller.release_lease()
            except ControllerError as exc:
                log.warning("lease release failed: %s", exc)

    # ---------------------------------------------------------------- inputs
    def _on_alive(self, key: str, alive: bool) -> None:
        process = process_of(key)
        if process not in self.required_processes:
            return
        if alive:
            self._seen(process)
            return
        if process not in self.seen_alive:
            return  # a withdrawal of a token never declared (a stranger) says nothing of the cell
        self.seen_alive.discard(process)
        self.lost.add(process)
        self.publish_state()   # the cell's own view of who is gone, at once (the monitor shows it)
        loss = self.losses[process] = object()
        threading.Thread(target=self._until_back, args=(process, loss), name=f"lost-{process}",
                         daemon=True).start()
        # At rest nothing moves: a token back within the grace was a link that lapsed (a process starved
        # of CPU past the link's lease), not a lost process. A process just started again gets the grace
        # too: Zenoh may withdraw its token once more as the peers' links to it settle (seen 0.4 s after
        # a restarted camera's token, at the cell only).
        if (self.runner.machine.state not in WORK_STATES or process in self.config.graced_while_working
                or time.monotonic() - self.appeared.get(process, -math.inf) < self.config.lost_grace_s):
            if self.runner.machine.is_active:
                log.warning("the token of process %s is gone: a fault unless it is back within %g s", process,
                            self.config.lost_grace_s)
            else:   # idle or ended: nothing needs it until work begins
                log.info("process %s is gone while the cell is %s", process, self.runner.machine.state)
            return
        self._fault_on_loss(f"the link to {process} lapsed" if self.pulse.stopped_for()
                            else f"process {process} is gone")

    def _until_back(self, process: str, loss: object) -> None:
        """Ask the network every grace period whether a lost process is back: a withdrawal of its old
        session's token told after its new one's appearance would otherwise keep it lost. Faults the
        cell when it is not back within the first (a cell folding has faulted at once)."""
        grace = self.config.lost_grace_s
        first = True
        while not self.stop.wait(grace) and process in self.lost and self.losses[process] is loss:
            if self._on_network(process):
                self._seen(process)
                return
            if first and self.runner.machine.is_active:
                self._fault_on_loss(f"process {process} is gone (not back within {grace:g} s)")
            first = False

    def _seen(self, process: str) -> None:
        back = process in self.lost
        if back:
            log.info("process %s is back", process)
        self.seen_alive.add(process)
        self.lost.discard(process)
        if back:
            self.publish_state()
        self.appeared[process] = time.monotonic()

    def _on_network(self, process: str) -> bool:
        """Whether the process's token is alive now, asked of the network."""
        return process in {process_of(key) for key in self.wire.alive(timeout=self.config.reply_timeout_s)}

    def _fault_on_loss(self, seen: str) -> None:
        reason = self.fault_cause(seen)
        log.warning("%s", reason)
        began = self.pulse.stop_began()
        same_stop = (began is not None and self.faulted_stop is not None
                     and abs(began - self.faulted_stop) < self.pulse.period)
        if same_stop:
            # every link lapses in one stop, and Zenoh tells them one by one: the stop faulted the cell
            # once, and a resume accepted since (every process seen again) is not faulted by the rest
            return
        if self.runner.machine.is_active:
            self.faulted_stop = began
            self.runner.fault(reason)

    def _on_lease_taken(self, reason: str) -> None:
        """The controller took the lease away and stopped the robot: a fault with its reason (a retry
        would only be refused again); `resume` takes the lease again and goes on."""
        with self.lease_lock:
            self.holding_lease = False
        if self.runner.machine.is_active:
            self.runner.fault(f"lease lost: {reason}")

    def _on_controller_lost(self, reason: str) -> None:
        """A controller without a liveliness token (MotoROS) is lost with its connection."""
        log.warning("controller lost: %s", reason)
        if self.runner.machine.is_active:
            self.runner.fault(f"controller lost: {reason}")

    def _on_status(self, status: ControllerStatus) -> None:
        self.time_scale = status.time_scale
        self.runner.motion.saw_status(status)
        if not self.runner.machine.is_active or self.runner.machine.state == "paused":
            return
        if status.e_stopped:
            self.runner.interrupt("e-stop")
            self.runner.stop_robot()
        elif status.in_error:
            self.runner.fault(f"controller alarm {status.error_code}: {status.alarm_text}")

    def _on_command(self, request: Any, _info: Any) -> Any:
        command, argument = request.command.strip(), request.argument.strip()
        log.info("command %r %r from %s", command, argument, request.client or "?")
        if command == "resume":
            missing = self._still_lost()
            if missing:
                # after a partition or a stop of this process, Zenoh makes the links again on its own
                # (its retries back off to a few seconds): gone, or not back yet
                return self._reply(False, f"resume: process {', '.join(missing)} is not seen: start it "
                                          "again, or, if its link was lost, try again in a moment")
        with self.lease_lock:  # not released by the idle check between the lease and the command
            if command in ("fold", "resume", "reset"):
                try:
                    self._connect_controller()
                except Exception as exc:
                    if command != "reset":  # a reset goes on to idle without the controller
                        words = exc.text if isinstance(exc, ControllerError) else exc
                        return self._reply(False, f"{command}: controller not ready: {words}")
            accepted, text = self.runner.command(command, argument)
        if accepted:
            self.publish_state()
        return self._reply(accepted, text)

    def _still_lost(self) -> list[str]:
        """The required processes lost and not back, asked of the network now: a token withdrawn late
        by the old session of a restarted process must not keep the new one out."""
        if not self.lost:
            return []
        back = {process_of(key) for key in self.wire.alive(timeout=self.config.reply_timeout_s)}
        self.seen_alive |= back & self.lost
        self.lost -= back
        return sorted(self.lost)

    def _reply(self, accepted: bool, text: str) -> Any:
        return messages.new("foldcell_msgs/msg/CellReply", header=messages.header(), accepted=accepted,
                            text=text, state=self.runner.machine.state)

    # ---------------------------------------------------------------- outputs (CellEvents)
    def _tick(self) -> None:
        while not self.stop.wait(self.config.state_period_s):
            self.pulse.beat()
            self.publish_state()
            self._release_lease_when_idle()

    def publish_state(self) -> None:
        m = self.runner.machine
        with self.state_lock:
            job = m.job
            history = [messages.new("foldcell_msgs/msg/CellTransition",
                                    stamp=messages.stamp_from_ns(r.stamp_ns), trigger=r.trigger,
                                    source=r.source, dest=r.dest, reason=r.reason)
                       for r in list(m.history)]
            self.state_pub.put(messages.new(
                "foldcell_msgs/msg/CellState", header=messages.header(), cell_id=self.wire.cell_id,
                state=m.state,
                garment=job.category if job else "", fold_index=job.fold_index if job else 0,
                fold_count=job.fold_count if job else 0, attempt=job.attempt if job else 0,
                stage=m.state, reason=m.reason, history=history, triggers=m.allowed_triggers(),
                processes_lost=sorted(self.lost)))

    def state_changed(self, record: TransitionRecord | None) -> None:
        self.publish_state()

    def perceived(self, report: PerceptionReport) -> None:
        stamp_ns = int(report.frame.stamp * 1e9)
        landmarks = [messages.new("foldcell_msgs/msg/Landmark", name=n, x_px=px[0], y_px=px[1],
                                  x_table=report.landmarks_table[n][0], y_table=report.landmarks_table[n][1])
                     for n, px in report.landmarks_px.items()]
        polygon = [messages.new("geometry_msgs/msg/Point", x=float(x), y=float(y))
                   for x, y in report.polygon_px]
        timings = [messages.new("foldcell_msgs/msg/StageTiming", stage=k, seconds=float(v))
                   for k, v in report.timings_s.items()]
        observation = messages.new(
            "foldcell_msgs/msg/GarmentObservation",
            header=messages.header(stamp_ns, report.frame.info.frame_id),
            category=report.category, fold_index=report.fold_index, landmarks=landmarks, polygon_px=polygon,
            cost=report.cost if np.isfinite(report.cost) else 0.0, timings=timings)
        self.obs_pub.put(observation)
        self.ann_pub.put(annotations_from_observation(observation, self.annotation_style))

    def planned(self, plan: FoldPlan) -> None:
        for trajectory in plan.trajectories:
            self.plan_pub.put(codec.trajectory_msg(trajectory, time.time_ns()))

    def fault_cause(self, reason: str) -> str:
        stopped = self.pulse.stopped_for()
        if not stopped:
            return reason
        # a stop the pulse notices (two state periods, 1 s) outlasts the links' lease (0.4 s): the peers
        # lost sight of this process, and the controller took the lease that follows its session
        return (f"lease lost: this cell could not run for {stopped:.1f} s (stopped, or starved of CPU), "
                "so its peers lost sight of it and the controller stopped the robot and took the control "
                f"lease; the cell saw then: {reason}")

    def fold_finished(self, report: FoldReport) -> None:
        self.report_pub.put(messages.new(
            "foldcell_msgs/msg/FoldReport", header=messages.header(), garment=report.category,
            fold_index=report.fold_index, attempt=report.attempt, outcome=report.outcome.value,
            cause=report.cause,
            verify_iou=float(report.verify_iou), robot_time=float(report.robot_time_s),
            timings=[messages.new("foldcell_msgs/msg/StageTiming", stage=k, seconds=float(v))
                     for k, v in report.timings_s.items()]))
