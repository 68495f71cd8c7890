"""One DX100 with MotoROS, as a pure state machine driven by explicit robot time (no threads, no I/O).

`step()` advances one interpolation tick (4 ms of robot time). Trajectories are interpolated with
MotoROS' cubic Hermite. Smooth stops (stop, hold, alarm, lost lease) slow the motion down along its path
by time scaling: the trajectory time t advances by s per tick of robot time, and the speed s = dt/d(robot
time) goes to 0 at a bounded rate, so positions stay on the accepted (limit-checked) path and the velocity
only shrinks; the rate is chosen per tick so every axis stays inside its acceleration limit. An e-stop
(and servo off) freezes the position, like the brakes; a lost link freezes it at once.

Coordinated stops (master and slave, `split.py`): each core holds the whole path of a two-controller
motion (`PreparedTrajectory`, all joints, its own columns picked out) and computes the speed profile over
every joint of it, from (path, t, s) only, so both cores compute the same profile bit for bit. Stops,
holds, resumes and freezes take effect on a tick (`command(at_tick=...)`; default the next): the master
picks one `stop_lead_time` ahead and stamps it on the command it forwards, so both cores start the same
profile on the same tick and come to rest on the same tick at the same path parameter. The state a
command reports (held, e-stopped, servos) changes at once; only the motion waits for the tick.
Trajectories can be pre-loaded (`submit(preload=True)`) and started by `release` on a given tick.
"""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from drivers.controller.acceptance import Readiness, check_ready, check_trajectory
from drivers.controller.codes import OK, Alarm, Command, Mode, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig
from drivers.controller.interface import ControllerStatus, GroupStatus, JointFeedback
from drivers.controller.motion import Axes, move_trajectory
from drivers.controller.trajectory import FloatArray, JointTrajectory
from drivers.emulator.commands import LEASED_COMMANDS, command_of
from drivers.emulator.motion import PreparedTrajectory
from drivers.robot.config import ArmSpec, ControlGroup, RobotConfig

log = logging.getLogger(__name__)

ROLES = ("master", "slave", "both")
_HALVINGS = 8  # attempts at a smaller speed change when a tick's acceleration would exceed a limit


@dataclass(frozen=True)
class Faults:
    """Injected faults, all off by default. The wrapper applies the timing ones."""

    drop_slave_link: bool = False  # the master stops hearing the slave
    freeze_feedback: bool = False  # joint states repeat the last sample
    alarm: bool = False  # an injected alarm is active
    reply_latency: float = 0.0  # s added to every reply
    reply_jitter: float = 0.0  # s, uniform extra delay in [0, jitter]
    slow_loop_factor: float = 1.0  # the interpolation loop's period is multiplied by this

    def active(self) -> tuple[str, ...]:
        """Names of the faults that are on (for `ControllerStatus.faults`)."""
        out = [name for name in ("drop_slave_link", "freeze_feedback", "alarm") if getattr(self, name)]
        if self.reply_latency or self.reply_jitter:
            out.append("reply_latency")
        if self.slow_loop_factor != 1.0:
            out.append("slow_loop")
        return tuple(out)


@dataclass
class _Active:
    traj: PreparedTrajectory
    limits: Axes  # of every joint of the path: a stop keeps them all inside, on either controller
    t: float = 0.0  # time along the trajectory, s
    speed: float = 1.0  # d(t)/d(robot time)
    braking: str = ""  # '' run, 'hold' pause, 'stop' stop and drop


class ControllerCore:
    """One DX100 owning some control groups (`role` master / slave / both = all groups).

    Joint arrays of this core are in project order restricted to its groups (`joint_names`).
    Every method that changes state takes the sender's `session` id for the control lease.
    """

    def __init__(self, robot_config: RobotConfig, config: ControllerConfig, role: str = "both",
                 initial_position: Sequence[float] | None = None, tick: int = 0):
        if role not in ROLES:
            raise ValueError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
        self.robot_config = robot_config
        self.config = config
        self.role = role
        owners = config.group_owners
        self.groups: tuple[ControlGroup, ...] = tuple(
            g for g in robot_config.groups if role == "both" or owners.get(g.name, g.controller) == role)
        owned = {j for g in self.groups for j in g.joints}
        self.joint_names: tuple[str, ...] = tuple(j for j in robot_config.joint_names if j in owned)
        self.indices = np.array([robot_config.index(j) for j in self.joint_names], dtype=int)
        group_names = {g.name for g in self.groups}
        self.arms: tuple[ArmSpec, ...] = tuple(a for a in robot_config.arms if a.group in group_names)
        self.axes = Axes.of(robot_config, self.joint_names)
        self.period = config.interpolation_period
        self.tick = tick
        home = np.asarray(robot_config.home, dtype=float)[self.indices]
        self.q = home.copy() if initial_position is None else np.asarray(initial_position, dtype=float).copy()
        if self.q.shape != (len(self.joint_names),):
            raise ValueError(f"initial_position must have {len(self.joint_names)} values, got {self.q.shape}")
        self.v = np.zeros_like(self.q)
        self.a = np.zeros_like(self.q)
        self.servo_on = False
        self.traj_mode = False
        self.e_stopped = False
        self.estop_count = 0
        self.alarm_code = 0
        self.alarm_text = ""
        self.held = False
        self.mode = Mode.AUTO
        self.remote = True
        self.lease_holder = ""
        self.lease_note = ""  # why the lease was last taken from its holder
        self.loop_stalls = 0  # counted by the loop that steps this core (drivers/emulator/node.py)
        self.grippers: dict[str, bool] = {a.name: False for a in self.arms}  # True = closed
        self.faults = Faults()
        self._active: _Active | None = None
        self._queue: deque[PreparedTrajectory] = deque()
        # (tick, kind) of stops, holds, resumes and freezes asked for, in the order they take effect
        self._events: list[tuple[int, str]] = []
        self._holding = False  # a hold in effect (`held` is set when asked, the hold on its tick)
        self._command_tick: int | None = None  # the tick the command being run asks to act on
        self._limits: dict[tuple[str, ...], Axes] = {}
        self._frozen: JointFeedback | None = None
        self._next_id = 1
        # True while an outside interpolator that `follow`s the core has motion queued (the MotoROS
        # increment queue): the status then shows it as one trajectory in motion
        self.outside_motion: Callable[[], bool] = lambda: False

    # ------------------------------------------------------------------ state
    @property
    def stamp(self) -> float:
        """Robot time of the current tick, s."""
        return self.tick * self.period

    @property
    def in_motion(self) -> bool:
        act = self._active
        return act is not None and not (act.braking == "hold" and act.speed == 0.0)

    @property
    def queue_count(self) -> int:
        return len(self._queue) + (self._active is not None)

    def readiness(self) -> Readiness:
        return Readiness(self.e_stopped, self.alarm_code, self.servo_on, self.held, self.mode == Mode.AUTO,
                         self.remote, self.traj_mode, self.queue_count, self.config.queue_size)

    @property
    def motion_possible(self) -> bool:
        r = replace(self.readiness(), queue_count=0)
        return check_ready(r).ok

    def queue_end_position(self) -> FloatArray:
        """Where the robot will be when the queue is done (the start a new trajectory must match)."""
        if self._queue:
            return self._queue[-1].end_position
        if self._active is not None:
            return self._active.traj.end_position
        return self.q.copy()

    def projected_end_tick(self) -> int:
        """The first tick at which all queued motion will be done, if nothing holds it."""
        end = self.tick
        if self._active is not None:
            act = self._active
            end += int(np.ceil((act.traj.duration - act.t) / self.period)) + 1
        for traj in self._queue:
            start = end if traj.start_tick is None else traj.start_tick
            end = max(end, start) + int(np.ceil(traj.duration / self.period)) + 1
        return end

    def feedback(self) -> JointFeedback:
        """The joint state of the current tick (the last one before a freeze, while frozen)."""
        if self.faults.freeze_feedback and self._frozen is not None:
            return self._frozen
        fb = JointFeedback(self.stamp, self.joint_names, self.q.copy(), self.v.copy(), self.a.copy(),
                           np.zeros_like(self.q))
        self._frozen = fb
        return fb

    def status(self) -> ControllerStatus:
        possible = self.motion_possible
        outside = self.outside_motion()
        in_motion = self.in_motion or outside
        queue_count = self.queue_count + int(outside)
        groups = tuple(
            GroupStatus(name=g.name, controller=self.config.group_owners.get(g.name, g.controller),
                        drives_powered=self.servo_on, e_stopped=self.e_stopped, in_error=self.alarm_code != 0,
                        error_code=self.alarm_code, alarm_text=self.alarm_text, in_motion=in_motion,
                        mode=int(self.mode), motion_possible=possible, held=self.held,
                        queue_count=queue_count, trajectory_mode=self.traj_mode)
            for g in self.groups)
        return ControllerStatus(self.stamp, groups, self.lease_holder, self.faults.active(),
                                lease_note=self.lease_note, loop_stalls=self.loop_stalls)

    def status_key(self) -> tuple:
        """What `status()` depends on besides its stamp: equal keys, equal statuses (a loop compares
        keys at 250 Hz and builds the status only when it changed or is due)."""
        return (self.servo_on, self.e_stopped, self.alarm_code, self.alarm_text, self.held, self.mode,
                self.remote, self.traj_mode, self.in_motion, self.queue_count, self.outside_motion(),
                self.lease_holder, self.lease_note, self.loop_stalls, self.faults)

    # ------------------------------------------------------------------ trajectories
    def lease_reply(self, session: str) -> Reply | None:
        """None when `session` may command motion (it holds the lease, or none is needed); else the
        refusal."""
        if not self.config.lease_required or (session == self.lease_holder and session):
            return None
        if self.lease_holder:
            return self._lease_held()
        return Reply(Result.FAILURE, Subcode.NO_LEASE, "lease: acquire the control lease first")

    def _lease_held(self) -> Reply:
        return Reply(Result.FAILURE, Subcode.LEASE_HELD,
                     f"lease: session {self.lease_holder!r} holds the control lease")

    def move_permission(self, session: str) -> Reply:
        """`OK` when `session` may start a motion now; else the lease or readiness refusal."""
        return self.lease_reply(session) or check_ready(self.readiness())

    def check(self, trajectory: JointTrajectory, session: str = "") -> Reply:
        """Every check `submit` makes, without queuing (the master validates before forwarding)."""
        reply = self.move_permission(session)
        if not reply.ok:
            return reply
        if self.stopping:
            # where it will come to rest is not known yet, so no start position can be checked
            return Reply(Result.BUSY, Subcode.NONE, "readiness: a stop is in progress: retry when stopped")
        return check_trajectory(trajectory, self.queue_end_position(), self.robot_config, self.config,
                                self.joint_names)

    def submit(self, trajectory: JointTrajectory, session: str = "", start_tick: int | None = None,
               path: JointTrajectory | None = None, preload: bool = False) -> Reply:
        """Accept (and queue) or reject a trajectory over this core's joints; a rejection changes nothing.

        `start_tick`: the motion starts no earlier than this tick (master/slave synchronous start);
        default: the next tick. `preload`: it waits in the queue until `release` names its start tick.
        `path`: the coordinated motion over every joint it moves (master's and slave's) of which
        `trajectory` is this core's columns; stops slow down along it (default: `trajectory`).
        """
        reply = self.check(trajectory, session)
        if reply.ok and path is not None:
            reply = self._check_path(trajectory, path)
        if not reply.ok:
            log.info("trajectory rejected: %s", reply.describe())
            return reply
        whole = trajectory if path is None else path
        start = None
        if not preload:
            start = self.tick + 1 if start_tick is None else max(int(start_tick), self.tick + 1)
        ident = self._next_id
        self._next_id += 1
        self._queue.append(PreparedTrajectory.build(whole, start, ident, self.joint_names))
        when = "pre-loaded: starts when released" if start is None else f"start tick {start}"
        return Reply(Result.SUCCESS, Subcode.NONE,
                     f"accepted {len(trajectory.times)} points, {trajectory.duration:.3f} s, {when}",
                     trajectory_id=ident, start_tick=start or 0)

    def _check_path(self, trajectory: JointTrajectory, path: JointTrajectory) -> Reply:
        """`path`: cell joints in project order including this core's, every acceptance rule but the
        start position (the other controller's joints are not here), `trajectory` exactly its columns."""
        names = tuple(path.joint_names)
        if names != tuple(j for j in self.robot_config.joint_names if j in names) \
                or not set(self.joint_names) <= set(names):
            return Reply(Result.INVALID, Subcode.INVALID_DATA,
                         f"path: joint names must be cell joints in project order, with "
                         f"{', '.join(self.joint_names)}; got {', '.join(names)}")
        positions = np.asarray(path.positions, dtype=float)
        if positions.ndim != 2 or positions.shape[1] != len(names):
            return Reply(Result.INVALID, Subcode.INVALID_MSGSIZE,
                         f"path: positions must have shape (points, {len(names)}), got {positions.shape}")
        reply = check_trajectory(path, positions[0], self.robot_config, self.config, names)
        if not reply.ok:
            return replace(reply, text=f"path: {reply.text}")
        cols = [names.index(j) for j in self.joint_names]
        if not (np.array_equal(np.asarray(path.times, dtype=float), np.asarray(trajectory.times, dtype=float))
                and np.array_equal(positions[:, cols], np.asarray(trajectory.positions, dtype=float))
                and np.array_equal(path.point_velocities[:, cols], trajectory.point_velocities)):
            return Reply(Result.INVALID, Subcode.INVALID_DATA, "path: the trajectory is not its columns")
        return OK

    def release(self, ident: int, start_tick: int | None) -> Reply:
        """Start the pre-loaded trajectory `ident` on `start_tick`; None drops it (with any queued after
        it). A tick already stepped is too late: it is dropped too, and the reply says so."""
        k = next((k for k, traj in enumerate(self._queue) if traj.ident == ident and traj.start_tick is None),
                 -1)
        if k < 0:
            return Reply(Result.FAILURE, Subcode.NONE, f"release: no pre-loaded trajectory {ident}")
        traj = self._queue[k]
        if start_tick is None or start_tick <= self.tick:
            while len(self._queue) > k:
                self._queue.pop()
            if start_tick is None:
                return Reply(Result.SUCCESS, Subcode.NONE, f"release: trajectory {ident} dropped")
            return Reply(Result.FAILURE, Subcode.NONE,
                         f"release: start tick {start_tick} arrived at tick {self.tick}: start missed")
        self._queue[k] = replace(traj, start_tick=int(start_tick))
        return Reply(Result.SUCCESS, Subcode.NONE, f"released: start tick {start_tick}",
                     trajectory_id=ident, start_tick=int(start_tick))

    @property
    def trajectory_id(self) -> int:
        """Id of the trajectory being executed, 0 when idle."""
        return self._active.traj.ident if self._active is not None else 0

    @property
    def queued_ids(self) -> tuple[int, ...]:
        """Ids of the running and the waiting trajectories, in order."""
        return tuple(([self._active.traj.ident] if self._active else []) + [t.ident for t in self._queue])

    def move(self, command: Command, values: Sequence[float] | FloatArray, joint: str = "",
             session: str = "") -> Reply:
        """MOVE_TO (`values`: every joint's target) or JOG (`joint` by `values[0]` rad) from where the
        queue ends: a jerk-limited, synchronised motion queued like any trajectory."""
        planned = move_trajectory(command, self.axes, self.queue_end_position(), values, joint,
                                  self.move_permission(session), self.config)
        if isinstance(planned, Reply):
            return planned
        return self.submit(planned, session)

    def move_to(self, target: Sequence[float] | FloatArray, session: str = "") -> Reply:
        return self.move(Command.MOVE_TO, target, "", session)

    # ------------------------------------------------------------------ commands
    def command(self, code: int, session: str = "", arm: str = "", values: Sequence[float] = (),
                joint: str = "", at_tick: int | None = None) -> Reply:
        """Run a `Command` (`foldcell_msgs/ControllerCommand` fields); the reply says what happened.

        `at_tick`: the tick its stop, hold, resume or freeze takes effect on (the master's shared tick;
        default the next one); the state it reports (held, e-stopped, ...) changes at once.
        """
        try:
            cmd = command_of(code)
        except ValueError:
            return Reply(Result.INVALID, Subcode.INVALID_COMMAND, f"command: unknown command code {code}")
        if cmd in LEASED_COMMANDS:
            reply = self.lease_reply(session)
            if reply is not None:
                return reply
        self._command_tick = at_tick
        try:
            if cmd is Command.JOG:
                reply = self.move(cmd, values, joint, session)
            else:
                handler = getattr(self, f"_cmd_{cmd.name.lower()}")
                reply = handler(session, arm, tuple(values))
        finally:
            self._command_tick = None
        log.debug("command %s -> %s", cmd.name, reply.describe())
        return reply

    def _cmd_check_motion_ready(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        return check_ready(replace(self.readiness(), queue_count=0))

    def _cmd_check_queue_cnt(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        return Reply(Result.SUCCESS, self.queue_count, f"queue count {self.queue_count}")

    def _cmd_stop_motion(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.stop_motion()
        return Reply(Result.SUCCESS, Subcode.NONE, "stopping")

    def _cmd_start_servos(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if self.e_stopped:
            return Reply(Result.NOT_READY, Subcode.NOT_READY_ESTOP, "servo on: reset the e-stop first")
        if self.alarm_code:
            return Reply(Result.NOT_READY, Subcode.NOT_READY_ALARM,
                         f"servo on: reset alarm {self.alarm_code} first")
        self.servo_on = True
        return OK

    def _cmd_stop_servos(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self._schedule("freeze")
        self.servo_on = False
        self.traj_mode = False
        return OK

    def _cmd_reset_alarm(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.alarm_code, self.alarm_text = 0, ""
        self.faults = replace(self.faults, alarm=False)
        return OK

    def _cmd_start_traj_mode(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        reply = self._cmd_start_servos(session, arm, values)
        if reply.ok:
            self.traj_mode = True
        return reply

    def _cmd_stop_traj_mode(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.stop_motion()
        self.traj_mode = False
        return OK

    def _cmd_disconnect(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if session and session == self.lease_holder:
            self.lease_lost(session)
        return OK

    def _cmd_estop(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.estop()
        return OK

    def _cmd_estop_reset(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.e_stopped = False  # servos stay off: an explicit servo on is needed (MotoROS2)
        return OK

    def _cmd_hold(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.held = True
        self._schedule("hold")
        return OK

    def _cmd_resume(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if self.e_stopped or self.alarm_code or not self.servo_on:
            return Reply(Result.NOT_READY, Subcode.NOT_READY_UNSPECIFIED,
                         "resume: clear e-stop and alarm and switch servos on first")
        self.held = False
        self._schedule("resume")
        return OK

    def _cmd_release(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if len(values) != 1 or not float(values[0]).is_integer():
            return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                         f"release: values must be (trajectory id), got {list(values)}")
        return self.release(int(values[0]), self._command_tick)

    def _grip(self, arm: str, closed: bool) -> Reply:
        if arm not in self.grippers:
            return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                         f"grip: arm must be one of {', '.join(self.grippers) or '(none here)'}, got {arm!r}")
        if self.e_stopped:
            return Reply(Result.NOT_READY, Subcode.NOT_READY_ESTOP, "grip: e-stop is engaged")
        self.grippers[arm] = closed
        return OK

    def _cmd_grip_open(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        return self._grip(arm, False)

    def _cmd_grip_close(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        return self._grip(arm, True)

    def _cmd_move_to(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        return self.move(Command.MOVE_TO, values, "", session)

    def _cmd_lease_acquire(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if not session:
            return Reply(Result.INVALID, Subcode.BAD_ARGUMENT, "lease: a session id is needed")
        if self.lease_holder and self.lease_holder != session:
            return self._lease_held()
        self.lease_holder = session
        self.lease_note = ""
        return OK

    def _cmd_lease_renew(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if session != self.lease_holder or not session:
            return Reply(Result.FAILURE, Subcode.NO_LEASE, "lease: this session does not hold the lease")
        return OK

    def _cmd_lease_release(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if session != self.lease_holder or not session:
            return Reply(Result.FAILURE, Subcode.NO_LEASE, "lease: this session does not hold the lease")
        self.lease_lost(session)
        return OK

    def _cmd_pendant_teach(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.mode = Mode.MANUAL
        self.stop_motion()
        return OK

    def _cmd_pendant_play(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.mode = Mode.AUTO
        return OK

    def _cmd_pendant_remote_on(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.remote = True
        return OK

    def _cmd_pendant_remote_off(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.remote = False
        self.stop_motion()
        return OK

    def _cmd_fault_drop_slave_link_on(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.faults = replace(self.faults, drop_slave_link=True)
        return OK

    def _cmd_fault_drop_slave_link_off(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.faults = replace(self.faults, drop_slave_link=False)
        return OK

    def _cmd_fault_freeze_feedback_on(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.feedback()  # the sample to repeat
        self.faults = replace(self.faults, freeze_feedback=True)
        return OK

    def _cmd_fault_freeze_feedback_off(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.faults = replace(self.faults, freeze_feedback=False)
        return OK

    def _cmd_fault_alarm_on(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.faults = replace(self.faults, alarm=True)
        self.raise_alarm(Alarm.INJECTED, "injected alarm (fault injection)")
        return OK

    def _cmd_fault_alarm_off(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        return self._cmd_reset_alarm(session, arm, values)

    def _cmd_fault_reply_latency_on(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if len(values) != 2 or not all(np.isfinite(values)) or min(values) < 0:
            return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                         f"reply latency: values must be (latency s >= 0, jitter s >= 0), got {list(values)}")
        self.faults = replace(self.faults, reply_latency=float(values[0]), reply_jitter=float(values[1]))
        return OK

    def _cmd_fault_reply_latency_off(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.faults = replace(self.faults, reply_latency=0.0, reply_jitter=0.0)
        return OK

    def _cmd_fault_slow_loop_on(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        if len(values) != 1 or not np.isfinite(values[0]) or values[0] < 1.0:
            return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                         f"slow loop: values must be (factor >= 1), got {list(values)}")
        self.faults = replace(self.faults, slow_loop_factor=float(values[0]))
        return OK

    def _cmd_fault_slow_loop_off(self, session: str, arm: str, values: tuple[float, ...]) -> Reply:
        self.faults = replace(self.faults, slow_loop_factor=1.0)
        return OK

    # ------------------------------------------------------------------ events
    def estop(self, at_tick: int | None = None) -> None:
        """Freeze every axis on `at_tick` (default the next), drop the queue, servos off (at once);
        needs reset + servo on."""
        self._schedule("freeze", at_tick)
        self.e_stopped = True
        self.estop_count += 1  # tells a watcher an e-stop happened even if it was released since
        self.servo_on = False
        self.traj_mode = False

    def stop_motion(self, at_tick: int | None = None) -> int:
        """From `at_tick` (default the next) slow down along the path within the limits, then drop the
        queue. Returns the tick the stop starts on."""
        return self._schedule("stop", at_tick)

    def raise_alarm(self, code: int, text: str, at_tick: int | None = None) -> None:
        """Raise an alarm: the motion stops smoothly (from `at_tick`) and nothing moves until the alarm
        is reset."""
        if not self.alarm_code:
            self.alarm_code, self.alarm_text = int(code), text
            log.warning("alarm %d: %s", code, text)
        self.stop_motion(at_tick)

    def link_lost(self, peer: str) -> None:
        """The master lost the slave (or the slave the master): alarm, and every axis stops on the
        next tick (a smooth stop could outlast the status period, and the other half is uncontrolled)."""
        code = Alarm.SLAVE_LINK_LOST if peer == "slave" else Alarm.MASTER_LINK_LOST
        self.raise_alarm(code, f"link to the {peer} controller lost")
        self._hard_stop()

    def lease_lost(self, session: str, at_tick: int | None = None, why: str = "") -> None:
        """The lease holder released the lease or disappeared: the robot stops (from `at_tick`); `why`
        (when the controller took it) is kept for the status."""
        if session == self.lease_holder:
            self.lease_holder = ""
            self.lease_note = why
            self.stop_motion(at_tick)

    @property
    def pending_stop_tick(self) -> int | None:
        """The tick the last stop or freeze asked for takes effect on, while it is ahead."""
        ticks = [tick for tick, kind in self._events if kind in ("stop", "freeze")]
        return ticks[-1] if ticks else None

    @property
    def stopping(self) -> bool:
        """A stop or freeze is running or asked for: where the robot comes to rest is not known yet."""
        return (self._active is not None and self._active.braking == "stop") or any(
            kind in ("stop", "freeze") for _, kind in self._events)

    def _schedule(self, kind: str, at_tick: int | None = None) -> int:
        """Ask for a stop, hold, resume or freeze on `at_tick` (default: the running command's tick,
        else the next); a tick already stepped means the next. Returns the tick it takes effect on."""
        at = self._command_tick if at_tick is None else at_tick
        tick = self.tick + 1 if at is None else max(int(at), self.tick + 1)
        if at is not None and at <= self.tick:
            log.warning("%s for tick %d arrived at tick %d: applied on the next", kind, at, self.tick)
        if kind in ("stop", "freeze") and self._active is None and not self._queue:
            return tick  # nothing to stop
        self._events.append((tick, kind))
        self._events.sort(key=lambda event: event[0])  # stable: same-tick events keep their order
        return tick

    def _apply_events(self) -> None:
        """Apply the stops, holds, resumes and freezes due on the current tick."""
        while self._events and self._events[0][0] <= self.tick:
            _, kind = self._events.pop(0)
            act = self._active
            if kind == "freeze":
                self._hard_stop()
            elif kind == "stop":
                self._queue.clear()
                if act is not None:
                    act.braking = "stop"
            elif kind == "hold":
                self._holding = True
                if act is not None and act.braking != "stop":
                    act.braking = "hold"
            else:  # resume
                self._holding = False
                if act is not None and act.braking == "hold":
                    act.braking = ""

    def _hard_stop(self) -> None:
        self._queue.clear()
        self._active = None
        self.v = np.zeros_like(self.q)
        self.a = np.zeros_like(self.q)

    # ------------------------------------------------------------------ interpolation
    def idle_ticks(self, limit: int) -> int:
        """How many of the next `limit` ticks would change nothing: no motion runs, and no event or
        queued start falls on them (a loop skips them at once instead of stepping each)."""
        if self._active is not None or self.outside_motion() or limit <= 0:
            return 0
        horizon = self.tick + limit
        if self._events:
            horizon = min(horizon, self._events[0][0] - 1)
        starts = [t.start_tick for t in self._queue if t.start_tick is not None]
        if starts:
            horizon = min(horizon, min(starts) - 1)
        return max(horizon - self.tick, 0)

    def skip(self, ticks: int) -> None:
        """Advance `ticks` ticks that `idle_ticks` found change nothing."""
        if ticks > self.idle_ticks(ticks):
            raise RuntimeError(f"skip: {ticks} ticks are not all idle")
        self.tick += ticks
        if ticks and (self.v.any() or self.a.any()):
            self.v = np.zeros_like(self.q)
            self.a = np.zeros_like(self.q)

    def run_until(self, stamp: float) -> list[JointFeedback]:
        """Step until robot time reaches `stamp` (s); the wrapper catches up after a late loop."""
        out = []
        while (self.tick + 1) * self.period <= stamp + 1e-12:
            out.append(self.step())
        return out

    def step(self, dt: float | None = None) -> JointFeedback:
        """Advance one interpolation tick of robot time; returns the new joint state.

        `dt`, if given, must be the interpolation period: the DX100 has one fixed tick.
        """
        if dt is not None and abs(dt - self.period) > 1e-12:
            raise ValueError(f"dt must be the interpolation period {self.period} s, got {dt}")
        self.tick += 1
        self._apply_events()
        start = self._queue[0].start_tick if self._queue else None
        if self._active is None and start is not None and start <= self.tick:
            # the start tick shows the first point: the time advances to 0 below
            traj = self._queue.popleft()
            self._active = _Active(traj, self._path_limits(traj.joint_names), t=-self.period)
            if self._holding:
                self._active.t = 0.0
                self._active.braking = "hold"
                self._active.speed = 0.0
        act = self._active
        if act is None:
            self.v = np.zeros_like(self.q)
            self.a = np.zeros_like(self.q)
            return self.feedback()
        if act.braking == "" and act.speed >= 1.0:
            act.t += self.period
            p, v, a = act.traj.evaluate(act.t)
        else:
            p, v, a = self._scaled_step(act)
        cols = act.traj.columns
        self._apply(p[cols], v[cols], a[cols])
        if act.t >= act.traj.duration or (act.braking == "stop" and act.speed == 0.0):
            self._active = None
            if act.braking == "stop":
                self._queue.clear()
            self.v = np.zeros_like(self.q)
            self.a = np.zeros_like(self.q)
        return self.feedback()

    def follow(self, position: FloatArray, velocity: FloatArray, acceleration: FloatArray) -> None:
        """Take this tick's commanded state from an outside interpolator (the MotoROS increment queue,
        `drivers/motoros`), after `step()`; only while the core runs no trajectory of its own."""
        if self._active is not None or self._queue:
            raise RuntimeError("follow: the core is running a trajectory of its own")
        self._apply(np.asarray(position, dtype=float), np.asarray(velocity, dtype=float),
                    np.asarray(acceleration, dtype=float))

    def _path_limits(self, names: tuple[str, ...]) -> Axes:
        if names not in self._limits:
            self._limits[names] = Axes.of(self.robot_config, names)
        return self._limits[names]

    def _scaled_step(self, act: _Active) -> tuple[FloatArray, FloatArray, FloatArray]:
        """One tick with a changing speed factor s: v = p' s, a = p'' s^2 + p' ds/dt, over every joint
        of the path (a function of the path, t and s only: master and slave compute the same)."""
        dt = self.period
        _, dp, ddp = act.traj.evaluate(act.t)
        s = act.speed
        amax = act.limits.max_acceleration * self.config.stop_acceleration_fraction
        lo, hi = -np.inf, np.inf
        moving = np.abs(dp) > 1e-12
        if moving.any():
            b1 = (-amax[moving] - ddp[moving] * s * s) / dp[moving]
            b2 = (amax[moving] - ddp[moving] * s * s) / dp[moving]
            lo = float(np.max(np.minimum(b1, b2)))
            hi = float(np.min(np.maximum(b1, b2)))
        # braking: slow down as fast as the limits allow; else speed back up
        sdot = max(min(lo, 0.0), -s / dt) if act.braking else min(max(hi, 0.0), (1.0 - s) / dt)
        limit = act.limits.max_acceleration * (1.0 + self.config.limit_tolerance)
        for _ in range(_HALVINGS):
            s_new = min(max(s + sdot * dt, 0.0), 1.0)
            t_new = act.t + 0.5 * (s + s_new) * dt
            p, dp1, ddp1 = act.traj.evaluate(t_new)
            a = ddp1 * s_new * s_new + dp1 * sdot
            if (np.abs(a) <= limit).all():
                break
            sdot *= 0.5
        else:
            sdot = 0.0
            s_new = s
            t_new = act.t + s * dt
            p, dp1, ddp1 = act.traj.evaluate(t_new)
            a = ddp1 * s * s
        act.t, act.speed = t_new, s_new
        return p, dp1 * s_new, a

    def _apply(self, p: FloatArray, v: FloatArray, a: FloatArray) -> None:
        """Take the new command; clamp anything outside a limit and raise an alarm (never expected)."""
        tol = 1.0 + self.config.limit_tolerance
        axes = self.axes
        vmax, amax = axes.max_velocity * tol, axes.max_acceleration * tol
        bad = (p < axes.lower) | (p > axes.upper) | (np.abs(v) > vmax) | (np.abs(a) > amax)
        if bad.any():
            j = int(np.argmax(bad))
            p = np.clip(p, axes.lower, axes.upper)
            v = np.clip(v, -vmax, vmax)
            a = np.clip(a, -amax, amax)
            self.raise_alarm(Alarm.LIMIT_EXCEEDED, f"{self.joint_names[j]} would leave its limits: clamped")
        self.q, self.v, self.a = p, v, a

