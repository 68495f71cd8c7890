"""`ControllerNode`: one DX100 emulator process on Zenoh (`foldcell controller serve`).

A fixed wall-clock loop (period 1/feedback_rate, slept to absolute deadlines on the monotonic clock)
steps the pure `ControllerCore` up to the robot time of `RobotClock` (several 4 ms ticks per loop when
`--time-scale` > 1), then publishes the joint state (every loop), the status (on change and at
`status_rate`) and, where this process owns arms, the grippers (on change, and while the TCPs move at
the status rate). Every stamp is the wall time of its tick (`RobotClock.stamp_ns`); the status carries
the robot time of its tick and the time scale, so a reader recovers robot time as data.

Roles:
- `both`: one core with every group; serves `controller/trajectory` and `controller/command`.
- `slave`: a core with the slave's groups; serves `controller/slave/*`, publishes
  `controller/slave/joint_states|status`; obeys the master (no lease of its own): pre-loads the paths it
  sends, starts them on its RELEASE, applies its commands on the tick of their header stamp; stops hard
  when the master's liveliness token vanishes.
- `master`: `drivers.emulator.master.MasterNode`, the cell's only contact when the groups are split.

The lease: `ControllerCommand.client` (commands) or the query attachment (trajectories) names the
sender, `alive/<process>`; the attachment carries its `Credential`, a signature over the request by the
sender's session key. The lease is granted to the name with the key that signed the acquire, which is
pinned: a request naming the holder that this key did not sign, or that repeats a signed one, is judged a
stranger's. Every command that moves the robot or changes what it may do (`codes.MOTION_COMMANDS`: also
fault injection and the pendant's modes) needs the lease, as trajectories do; with no holder the sender
takes the lease first. An e-stop is obeyed from anyone. The lease lapses (and the robot stops) when the
holder's liveliness token vanishes or it falls silent for `lease.silence_timeout`, measured as it is (an
injected reply latency does not stretch it). The slave obeys only its master, whose key it pins on first
contact (an e-stop from anyone is still obeyed).
"""

from __future__ import annotations

import logging
import math
import random
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from drivers.common.configfile import config_dir, load_fields, load_yaml, rule
from drivers.common.scheduling import histogram
from drivers.controller import codec
from drivers.controller.codes import Command, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig
from drivers.controller.credential import Credential, PinnedKey
from drivers.controller.interface import PROCESS_NAMES, ControllerStatus, JointFeedback
from drivers.controller.publisher import GripperPublisher
from drivers.controller.trajectory import FloatArray, JointTrajectory
from drivers.emulator.clock import RobotClock
from drivers.emulator.commands import EmulatorCommand
from drivers.emulator.core import ControllerCore
from drivers.emulator.split import split_trajectory
from drivers.robot.config import RobotConfig
from drivers.robot.kinematics import CellKinematics
from drivers.wire import messages
from drivers.wire.registry import split_key
from drivers.wire.transport import RequestInfo, Wire

log = logging.getLogger(__name__)

SECURITY_ROLES = {"both": "controller", "master": "master", "slave": "slave"}   # config/security.yaml
# Work a loop hands to a thread of its own, after releasing the lock (a forward to the slave).
Actions = list[Callable[[], object]]
KEPT_KEYS = 64   # commander keys remembered with the sequence numbers they used (an old acquire replayed)


@dataclass(frozen=True)
class ServerConfig:
    """The `server:` section of `config/controller.yaml` (wall seconds, m)."""

    sync_lead_time: float = rule(positive=True)
    stop_lead_time: float = rule(positive=True)
    max_catch_up: float = rule(positive=True)
    stall: float = rule(positive=True)
    min_sleep: float = rule(positive=True)
    gil_switch: float = rule(positive=True)
    slave_rest_period: float = rule(positive=True)


def load_server_config(path: str | Path | None = None) -> ServerConfig:
    f = load_yaml(Path(path) if path else config_dir() / "controller.yaml")
    return load_fields(ServerConfig, f.sub("server"))


class TickListener(Protocol):
    """Runs beside the core on the loop's thread, holding the lock (a MotoROS server's increments)."""

    def on_tick(self) -> None:
        """After every tick stepped, and once after ticks skipped."""

    def needs_ticks(self) -> bool:
        """True while it must see every tick (ticks are then stepped one by one, never skipped)."""


URGENT_COMMANDS = frozenset({Command.ESTOP, Command.LEASE_RENEW})


# the slave's: also the master's coordinated stops and its synchronous start, which a stranger's flood
# must neither delay nor use up the rate limit for (the slave refuses the stranger's own at once)
SLAVE_URGENT_COMMANDS = URGENT_COMMANDS | {Command.STOP_MOTION, Command.HOLD, EmulatorCommand.RELEASE}


def is_urgent(payload: bytes) -> bool:
    """An e-stop or a lease renewal (by its code, read as it arrives): answered on a lane of their own,
    never behind other commands (a renewal stuck behind slow ones would starve the watchdog) and never
    rate-limited."""
    return codec.command_code(payload) in URGENT_COMMANDS


def is_urgent_on_slave(payload: bytes) -> bool:
    return codec.command_code(payload) in SLAVE_URGENT_COMMANDS


class ControllerNode:
    """One emulator process of role `both` or `slave` (`MasterNode` is the master). `run(stop)` blocks
    in the loop until `stop` is set; `close()` after."""

    ROLES: tuple[str, ...] = ("both", "slave")

    def __init__(self, wire: Wire, role: str, robot_config: RobotConfig, config: ControllerConfig,
                 server_config: ServerConfig | None = None, time_scale: float | None = None,
                 kinematics: CellKinematics | None = None):
        if role not in self.ROLES:
            raise ValueError(f"role must be one of {', '.join(self.ROLES)}, got {role!r}")
        self.wire = wire
        self.role = role
        self.rc = robot_config
        self.config = config
        self.server = server_config or load_server_config()
        self.time_scale = float(time_scale if time_scale is not None else config.time_scale)
        self.clock = RobotClock(self.time_scale, config.interpolation_period)
        # the slave obeys the master, which holds the lease check for the cell
        core_config = replace(config, lease_required=False) if role == "slave" else config
        self.core = ControllerCore(robot_config, core_config, role, tick=self.clock.tick())
        self.lock = threading.RLock()  # the core and the node's state
        self.group_joints = {g.name: g.joints for g in robot_config.groups}
        self.own_idx = self.core.indices
        prefix = "controller/slave/" if role == "slave" else "controller/"
        published = self.core.joint_names if role == "slave" else robot_config.joint_names
        self.js_msg = codec.joint_state_msg(published)
        self.js_pub = wire.publisher(prefix + "joint_states")
        self.status_pub = wire.publisher(prefix + "status")
        # the slave's grippers are its master's to publish
        self.grippers = None if role == "slave" else GripperPublisher(wire, robot_config, config, kinematics)
        self._last_js: tuple[bytes, int] | None = None
        self._js_content: tuple[bytes, bytes] | None = None   # positions, velocities of `_last_js`
        self._js_changed = True      # `_last_js` holds new positions or velocities
        self._js_sent = -math.inf    # monotonic s the joint state was last sent
        self._last_status_key: tuple | None = None
        self._last_status_wall = 0.0
        self._holder_heard: float | None = None   # monotonic s of the lease holder's last request
        self._holder: PinnedKey | None = None   # the lease holder's key, pinned at its acquire
        self._keys: dict[bytes, PinnedKey] = {}   # the keys that asked for the lease, the latest last
        self._master: PinnedKey | None = None   # the slave's: its master's, pinned on first contact
        self.alive: set[str] = set()   # the liveliness tokens present (`alive/<process>`)
        self._alive_changed = threading.Condition(self.lock)
        self._loop_at: float | None = None   # monotonic s the loop last ran
        self.tick_delay = histogram(f"{PROCESS_NAMES[role]} tick", "how late the 250 Hz loop woke")
        self.holder_silence = histogram("lease holder silence", "gap between the holder's requests")
        # run beside every core step, holding the lock: a server beside the Zenoh side (MotoROS)
        self.tick_listeners: list[TickListener] = []
        self._declare(prefix)
        log.info("controller %s up: joints %s, time scale %g", role, ", ".join(self.core.joint_names),
                 self.time_scale)

    def _declare(self, prefix: str) -> None:
        """Serve the keys and watch the peers; the last step of construction (callbacks start at once)."""
        self.wire.serve(prefix + "trajectory", self._on_trajectory, unlimited=self._from_commander)
        self.wire.serve(prefix + "command", self._on_command,
                        urgent=is_urgent_on_slave if self.role == "slave" else is_urgent,
                        unlimited=self._from_commander)
        self.wire.watch_alive(self._on_alive, "alive/*")

    # ------------------------------------------------------------------ loop
    def run(self, stop: threading.Event | Any) -> None:
        """The fixed-period loop, until `stop.is_set()`."""
        base = 1.0 / self.config.feedback_rate
        deadline = time.monotonic()
        while not stop.is_set():
            now = time.monotonic()
            self.tick_delay.record(now - deadline)
            try:
                self.iterate(now)
            except Exception:  # a bug in one loop must not take the stream down; it is logged
                log.exception("controller loop failed")
            deadline += base * self.core.faults.slow_loop_factor
            delay = deadline - time.monotonic()
            if delay < -base * 50:  # stalled (debugger, overload): start afresh instead of bursting
                deadline = time.monotonic()
            # a sleep every period, late or not: a loop at a real-time priority never holds a CPU
            time.sleep(max(delay, self.server.min_sleep))

    def iterate(self, now: float) -> None:
        """One loop: step the core to robot time, check links, publish."""
        actions: Actions = []
        with self.lock:
            stalled = self._loop_stall(now)
            # a gripper that changed since the last loop changed where the arms stand now, before the
            # core steps on: a late loop must not report it where the next motion has taken the arms
            changes = self.grippers.changes(self._gripper_states(), self.full_position, self._stamp_ns(),
                                            now) if self.grippers else []
            self._step_core(now)
            self._check_commander(now, stalled, actions)
            self._check_links(now, stalled, actions)
            js_payload = self._joint_state_payload()
            status = self._status_due(now)
            grippers = self._gripper_states() if self.grippers else {}
        for act in actions:
            threading.Thread(target=act, daemon=True, name="controller-forward").start()
        # the cell's stream every period; the slave's to its master on each change and, still, at
        # `slave_rest_period` (the master takes a still slave's sample as current)
        if self.role != "slave" or self._js_changed or now - self._js_sent >= self.server.slave_rest_period:
            self.js_pub.put_encoded(*js_payload)
            self._js_sent = now
        if status is not None:
            self.status_pub.put(status)
        if self.grippers:
            self.grippers.push(changes)
            self.grippers.periodic(grippers, self.full_position, self._stamp_ns(), now)

    def _loop_stall(self, now: float) -> float:
        """How long (s) the loop could not run before this iteration beyond its period, when that is
        longer than `server.stall`: counted, logged and reported in the status; 0 otherwise."""
        last, self._loop_at = self._loop_at, now
        if last is None:
            return 0.0
        gap = now - last - 1.0 / self.config.feedback_rate
        if gap <= self.server.stall:
            return 0.0
        self.core.loop_stalls += 1
        log.warning("the loop could not run for %.3f s (stall %d): a loaded machine; the links and the "
                    "lease do not count it against their peers", gap, self.core.loop_stalls)
        return gap

    def _step_core(self, now: float) -> None:
        """Step the core to the clock's tick, at most `max_catch_up` robot seconds after a stall; ticks
        in which nothing happens are skipped at once."""
        core = self.core
        target = self.clock.tick(now)
        limit = int(self.server.max_catch_up / core.period)
        steps = max(min(target - core.tick, limit), 0)
        skipped = False
        while steps > 0:
            idle = 0 if any(listener.needs_ticks() for listener in self.tick_listeners) else \
                core.idle_ticks(steps)
            if idle:
                core.skip(idle)
                self._skipped(core.tick - idle + 1, core.tick)
                steps -= idle
                skipped = True
                continue
            feedback = core.step()
            self._stepped(core.tick, feedback)
            for listener in self.tick_listeners:
                listener.on_tick()
            steps -= 1
            skipped = False
        if skipped:
            for listener in self.tick_listeners:
                listener.on_tick()

    def _stepped(self, tick: int, feedback: JointFeedback) -> None:
        """The core has just stepped to `tick`, where its joint state is `feedback`."""

    def _skipped(self, first: int, last: int) -> None:
        """The core skipped ticks `first`..`last`, in which it stood still."""

    def _check_links(self, now: float, stalled: float, actions: Actions) -> None:
        core = self.core
        if self.role == "both" and core.faults.drop_slave_link and not core.alarm_code:
            core.link_lost("slave")  # one process: the fault stands for a lost link to the slave's groups

    # ------------------------------------------------------------------ joint states, status, grippers
    def _joint_state_payload(self) -> tuple[bytes, int]:
        """The encoded joint state of this loop and its stamp (ns); the last one while frozen. Unchanged
        positions and velocities are sent again with the new stamp, not encoded again."""
        if self.core.faults.freeze_feedback and self._last_js is not None:
            self._js_changed = False
            return self._last_js
        tick, feedback = self._joint_state(self.core.feedback())
        stamp_ns = self.clock.stamp_ns(tick)
        content = (feedback.positions.tobytes(), feedback.velocities.tobytes())
        self._js_changed = content != self._js_content
        if self._last_js is not None and not self._js_changed:
            self._last_js = (messages.restamp(self._last_js[0], stamp_ns), stamp_ns)
            return self._last_js
        msg = self.js_msg
        msg.position[:] = feedback.positions
        msg.velocity[:] = feedback.velocities
        msg.header.stamp = messages.stamp_from_ns(stamp_ns)
        self._last_js = (messages.encode(codec.JOINT_STATE_TYPE, msg), stamp_ns)
        self._js_content = content
        return self._last_js

    def _joint_state(self, own: JointFeedback) -> tuple[int, JointFeedback]:
        """The joint state this process publishes (from its core's `own`) and the tick it belongs to."""
        return self.core.tick, own

    def _status_due(self, now: float) -> Any:
        """The status message when it changed or `status_rate` is due, else None (built only then)."""
        key = self._status_key()
        due = now - self._last_status_wall >= 1.0 / self.config.status_rate
        if key == self._last_status_key and not due:
            return None
        self._last_status_key, self._last_status_wall = key, now
        status, link, possible = self._merged_status()
        tick = self.core.tick
        return codec.status_msg(status, self.clock.stamp_ns(tick), self.time_scale, link, self.group_joints,
                                possible, robot_ns=self.clock.tick_ns(tick))

    def _status_key(self) -> tuple:
        """What the status depends on besides its stamp."""
        return self.core.status_key()

    def _merged_status(self) -> tuple[ControllerStatus, dict[str, bool] | None, bool | None]:
        """(status, link_ok per group, motion possible): None = as the status says."""
        return self.core.status(), None, None

    def _gripper_states(self) -> dict[str, bool]:
        """Arm -> closed, for every arm this process reports."""
        return dict(self.core.grippers)

    def full_position(self) -> FloatArray:
        """All joints (project order): this core's, the rest at home."""
        with self.lock:
            q = np.asarray(self.rc.home, dtype=float).copy()
            q[self.own_idx] = self.core.q
            return q

    def _stamp_ns(self) -> int:
        """The wall stamp (ns) of the core's current tick."""
        return self.clock.stamp_ns(self.core.tick)

    # ------------------------------------------------------------------ peers
    def _on_alive(self, full_key: str, alive: bool) -> None:
        rel = split_key(full_key)[1]
        actions: Actions = []
        with self.lock:
            if alive:
                self.alive.add(rel)
                self._alive_changed.notify_all()
                return
            self.alive.discard(rel)
            self._peer_vanished(rel)
            if self.core.lease_holder and self.core.lease_holder == rel:
                self._drop_lease(f"{rel} was no longer seen: its process ended or stopped, or the link to "
                                 "it was lost", actions)
        for act in actions:
            act()

    def _drop_lease(self, why: str, actions: Actions) -> None:
        """The lease holder is gone or silent: stop (on the shared tick), say why, tell the subclass."""
        holder = self.core.lease_holder
        log.warning("lease dropped, stopping: %s", why)
        self.core.lease_lost(holder, self.shared_tick(), why)
        self._holder_heard = None
        self._lease_lapsed(actions)

    def heard_from(self, session: str) -> None:
        """A request from `session` (or a sign of life from a MotoROS connection): the watchdog's clock
        restarts when it is the lease holder's."""
        if session and session == self.core.lease_holder:
            now = time.monotonic()
            if self._holder_heard is not None:
                self.holder_silence.record(now - self._holder_heard)
            self._holder_heard = now

    def _check_commander(self, now: float, stalled: float, actions: Actions) -> None:
        """The controller's own watchdog on its commander's interpreter: a lease holder whose requests
        stop for `lease.silence_timeout` (its token still there: a hung process) loses the lease. The
        time this loop itself could not run is not counted against the holder."""
        holder = self.core.lease_holder
        if not holder or not self.config.lease_required:
            self._holder_heard = None   # the next holder's silence counts from its first request
            return
        if self._holder_heard is None:
            self._holder_heard = now
            return
        self._holder_heard += stalled
        silent = now - self._holder_heard
        if silent > self.config.lease_silence_timeout:
            self._drop_lease(f"{holder} sent nothing for {silent:.1f} s while its session stayed: a hung "
                             "process", actions)

    def _peer_vanished(self, alive_key: str) -> None:
        """A liveliness token went (`alive/<process>`): the slave stops when its master does."""
        if self.role == "slave" and alive_key == f"alive/{PROCESS_NAMES['master']}":
            self.core.link_lost("master")
            self._master = None

    def _lease_lapsed(self, actions: Actions) -> None:
        """The lease holder vanished and the core stopped."""

    def _token_alive(self, session: str, timeout: float) -> bool:
        """Whether `session` (`alive/<process>`) has a liveliness token here, waiting up to `timeout` for
        one declared just before its request."""
        with self.lock:
            return self._alive_changed.wait_for(lambda: session in self.alive, timeout)

    def lead_ticks(self, wall_s: float) -> int:
        """Interpolation ticks in `wall_s` wall seconds."""
        return math.ceil(wall_s * self.time_scale / self.core.period)

    def shared_tick(self) -> int | None:
        """The tick a stop, hold, resume or e-stop asked for now takes effect on (None: the next).
        The master's is `stop_lead_time` ahead, so its slave, told at once, acts on the same tick."""
        return None

    # ------------------------------------------------------------------ queryables
    def _reply(self, reply: Reply, command: int = 0) -> Any:
        faults = self.core.faults
        if faults.reply_latency or faults.reply_jitter:
            time.sleep(faults.reply_latency + random.uniform(0.0, faults.reply_jitter))
        return codec.reply_msg(reply, self.clock.stamp_ns(self.core.tick), command)

    def _sender(self, name: str, credential: Credential, info: RequestInfo,
                code: int | None = None) -> tuple[str, Reply | None]:
        """The session id the core judges a request by, or the refusal of a sender this process does not
        obey. `code` is the command's (None for a trajectory)."""
        with self.lock:
            if self.role == "slave":
                master = f"alive/{PROCESS_NAMES['master']}"
                if code == Command.ESTOP:  # stopping is never refused
                    return name, None
                if name != master or credential.client != master:
                    return name, Reply(Result.FAILURE, Subcode.NO_LEASE,
                                       f"slave: obeys only its master {master} (with its credential)")
                pin = self._master or PinnedKey(master, credential.public_key)   # first contact
                if not pin.admits(credential, info.key, info.payload):
                    return name, Reply(Result.FAILURE, Subcode.NO_LEASE,
                                       f"slave: the request names {master} without its signature, or repeats "
                                       "one")
                self._master = pin
                return name, None
            if name and name == self.core.lease_holder:
                if self._holder is None or not self._holder.admits(credential, info.key, info.payload):
                    log.warning("a request names the lease holder %s without its signature, or repeats a "
                                "signed one: judged a stranger's", name)
                    return f"{name} (without its credential)", None
                return name, None
            if code == Command.LEASE_ACQUIRE and not self._admit_acquire(name, credential, info) \
                    and self.config.lease_required:
                return name, Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                                   "lease: the request carries no credential signed by the sender's key, or "
                                   "repeats a signed one (attachment: name, sequence, public key, signature)")
            return name, None

    def _admit_acquire(self, name: str, credential: Credential, info: RequestInfo) -> bool:
        """A lease acquire from `name` is signed by the key it names, and new (a key that asked before
        keeps the sequence numbers it used): the key is kept, to be pinned when the lease is granted.
        Holding the lock."""
        key = credential.public_key
        pin = self._keys.pop(key, None)
        if pin is None or pin.client != name:
            pin = PinnedKey(name, key)
        if credential.client != name or not pin.admits(credential, info.key, info.payload):
            return False
        self._keys[key] = pin
        if len(self._keys) > KEPT_KEYS:
            self._keys.pop(next(iter(self._keys)))
        return True

    def _from_commander(self, info: RequestInfo) -> bool:
        """The request is signed by the one this process obeys (the lease holder; the slave's master): it
        is never rate-limited. Read as each request arrives, without the lock (nothing is taken)."""
        credential = Credential.from_attachment(info.attachment)
        pin = self._master if self.role == "slave" else self._holder
        if pin is None or (self.role != "slave" and credential.client != self.core.lease_holder):
            return False
        return pin.vouches(credential, info.key, info.payload)

    def _on_trajectory(self, request: Any, info: RequestInfo) -> Any:
        credential = Credential.from_attachment(info.attachment)
        session, refusal = self._sender(credential.client, credential, info)
        if refusal is not None:
            return self._reply(refusal)
        self.heard_from(session)
        try:
            trajectory = codec.trajectory_from_msg(request)
        except codec.MalformedTrajectory as exc:
            return self._reply(Reply(Result.INVALID, Subcode.INVALID_DATA_INSUFFICIENT, f"arrays: {exc}",
                                     exc.point))
        reply = self._submit(trajectory, session, messages.stamp_to_ns(request.header.stamp))
        log.info("trajectory from %s: %s", session or "?", reply.describe())
        return self._reply(reply)

    def _submit(self, trajectory: JointTrajectory, session: str, stamp_ns: int) -> Reply:
        """Queue a trajectory after the queue, so the reply's start tick is when the motion really
        starts. The slave pre-loads it (the master's whole path, or its own columns) until the master's
        RELEASE names the start tick."""
        with self.lock:
            if self.role == "slave":
                own, path = self._own_columns(trajectory)
                return self.core.submit(own, session, path=path, preload=True)
            at = self.core.projected_end_tick() if self.core.queue_count else None
            return self.core.submit(trajectory, session, at)

    def _own_columns(self, path: JointTrajectory) -> tuple[JointTrajectory, JointTrajectory | None]:
        """This core's columns of a path over more cell joints, and the path (None when the trajectory
        is not such a path: the core's checks then name what is wrong with it)."""
        if tuple(path.joint_names) == self.core.joint_names:
            return path, None
        try:
            own = split_trajectory(self.rc, self.config.group_owners, path)[self.role]
        except (IndexError, KeyError, ValueError):
            return path, None
        return own, path

    def _on_command(self, request: Any, info: RequestInfo) -> Any:
        code = int(request.command)
        credential = Credential.from_attachment(info.attachment)
        session, refusal = self._sender(request.client, credential, info, code)
        if refusal is not None:
            return self._reply(refusal, code)
        self.heard_from(session)
        values = tuple(float(v) for v in request.values)
        at_tick = None
        if self.role == "slave":  # the master stamps the tick its command takes effect on
            stamp_ns = messages.stamp_to_ns(request.header.stamp)
            at_tick = self.clock.stamp_tick(stamp_ns) if stamp_ns > 0 else None
            if at_tick is not None and code != EmulatorCommand.RELEASE:  # a stop is never put off for long
                at_tick = min(at_tick, self.clock.tick() + 2 * self.lead_ticks(self.server.stop_lead_time))
        if code == Command.LEASE_ACQUIRE and self.config.lease_required \
                and not self._token_alive(session, self.config.reply_timeout / 4):
            # the token is the lease's heartbeat: a name without one could never be seen to go
            return self._reply(Reply(Result.FAILURE, Subcode.NO_LEASE,
                                     f"lease: {session or 'the sender'} has no liveliness token here: the "
                                     "lease goes to a live session (its process's token alive/<process>)"),
                               code)
        reply = self._command(code, session, request.arm, values, request.joint, at_tick)
        if code == Command.LEASE_ACQUIRE and reply.ok:
            with self.lock:
                self._holder = self._keys.get(credential.public_key, self._holder)
        self.heard_from(session)   # again: an acquire makes the sender the holder
        return self._reply(reply, code)

    def _command(self, code: int, session: str, arm: str, values: tuple[float, ...], joint: str,
                 at_tick: int | None = None) -> Reply:
        with self.lock:
            return self.core.command(code, session, arm, values, joint, at_tick)

    def close(self) -> None:
        """Stop the motion (the process is going away) and close the session."""
        with self.lock:
            self.core.stop_motion()
        if self.grippers:
            self.grippers.close()
        self.wire.close()
