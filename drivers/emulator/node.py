"""`ControllerNode`: one DX100 emulator process (master, slave or both) on Zenoh.

A fixed wall-clock loop (period 1/feedback_rate, slept to absolute deadlines on the monotonic clock)
steps the pure `ControllerCore` up to the robot time of `RobotClock` (several 4 ms ticks per loop when
`--time-scale` > 1), then publishes the joint state (every loop), the status (on change and at
`status_rate`) and, where this process owns arms, the grippers (on change, and while the TCPs move at
the status rate).

Roles:
- `both`: one core with every group; serves `controller/trajectory` and `controller/command`.
- `slave`: a core with the slave's groups; serves `controller/slave/*`, publishes
  `controller/slave/joint_states|status`; obeys the master (no lease of its own); stops hard when the
  master's liveliness token vanishes.
- `master`: a core with the master's groups; the cell's only contact. It validates a whole trajectory,
  forwards the slave's columns with a common start tick (the header stamp of the forwarded trajectory),
  merges the slave's feedback and status into `controller/joint_states|status`, and raises
  SLAVE_LINK_LOST and stops every group when the slave's token vanishes or its feedback stops for
  `link.timeout` (wall s).

The lease: `ControllerCommand.client` (commands) or the query attachment (trajectories) names the
sender, `alive/<process>`; when that liveliness token vanishes the lease lapses and the robot stops.
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
from typing import Any

import numpy as np

from drivers.common.configfile import config_dir, load_yaml
from drivers.controller import codec
from drivers.controller.acceptance import check_ready, check_trajectory
from drivers.controller.codes import MOTION_COMMANDS, Command, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig
from drivers.controller.interface import ControllerStatus, JointTrajectory
from drivers.emulator.clock import RobotClock
from drivers.emulator.core import ControllerCore
from drivers.emulator.motion import PlanError, plan_point_to_point
from drivers.emulator.split import LinkMonitor, common_start_tick, joints_of, split_trajectory
from drivers.robot.config import RobotConfig
from drivers.wire import messages
from drivers.wire.registry import split_key
from drivers.wire.transport import RequestInfo, Wire

log = logging.getLogger(__name__)

ROLES = ("master", "slave", "both")
_HISTORY = 4096  # ticks of the master's own state kept for merging (16 s of robot time)
PROCESS_NAMES = {"both": "controller", "master": "controller-master", "slave": "controller-slave"}


@dataclass(frozen=True)
class ServerConfig:
    """The `server:` section of `config/controller.yaml` (wall seconds, m)."""

    sync_lead_time: float = 0.15
    gripper_open_width: float = 0.08
    max_catch_up: float = 1.0


def load_server_config(path: str | Path | None = None) -> ServerConfig:
    f = load_yaml(Path(path) if path else config_dir() / "controller.yaml")
    s = f.sub("server")
    s.reject_unknown({"sync_lead_time", "gripper_open_width", "max_catch_up"})
    return ServerConfig(sync_lead_time=s.float("sync_lead_time", positive=True),
                        gripper_open_width=s.float("gripper_open_width", min=0.0),
                        max_catch_up=s.float("max_catch_up", positive=True))


# Commands the master runs itself only (the rest are also forwarded to the slave).
_MASTER_ONLY = frozenset({
    Command.CHECK_MOTION_READY, Command.CHECK_QUEUE_CNT, Command.DISCONNECT, Command.LEASE_ACQUIRE,
    Command.LEASE_RELEASE, Command.FAULT_DROP_SLAVE_LINK_ON, Command.FAULT_DROP_SLAVE_LINK_OFF,
    Command.FAULT_FREEZE_FEEDBACK_ON, Command.FAULT_FREEZE_FEEDBACK_OFF, Command.FAULT_ALARM_ON,
    Command.FAULT_REPLY_LATENCY_ON, Command.FAULT_REPLY_LATENCY_OFF, Command.FAULT_SLOW_LOOP_ON,
    Command.FAULT_SLOW_LOOP_OFF,
})
# Commands after which the slave's queue is known to be empty (or being dropped).
_DROPS_QUEUE = frozenset({Command.STOP_MOTION, Command.STOP_SERVOS, Command.ESTOP, Command.STOP_TRAJ_MODE,
                          Command.PENDANT_TEACH, Command.PENDANT_REMOTE_OFF})


class ControllerNode:
    """One emulator process. `run(stop)` blocks in the loop until `stop` is set; `close()` after."""

    def __init__(self, wire: Wire, role: str, robot_config: RobotConfig, config: ControllerConfig,
                 server_config: ServerConfig | None = None, time_scale: float | None = None,
                 kinematics: Any = None):
        if role not in ROLES:
            raise ValueError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
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
        self.submit_lock = threading.Lock()  # one trajectory forward at a time (master)
        self.kin = kinematics
        self.owners = config.group_owners
        self.slave_joints = joints_of(robot_config, self.owners, "slave") if role == "master" else ()
        self.slave_idx = np.array([robot_config.index(j) for j in self.slave_joints], dtype=int)
        self.own_idx = self.core.indices
        self.group_joints = {g.name: g.joints for g in robot_config.groups}

        # slave state seen by the master
        home = np.asarray(robot_config.home, dtype=float)
        self.slave_q = home[self.slave_idx].copy()
        self.slave_v = np.zeros(len(self.slave_joints))
        self.slave_status: ControllerStatus | None = None
        self.slave_heard = False
        self.slave_link_ok = False
        self.link = LinkMonitor(config.link_timeout, time.monotonic())
        self.slave_end_tick = 0
        self.slave_end_q = self.slave_q.copy()
        self.slave_grippers = {a.name: False for a in robot_config.arms if a.name not in self.core.grippers} \
            if role == "master" else {}
        self._was_in_error = False
        # the master's own recent ticks, to merge with the slave's (older) samples at one stamp
        self.hist_tick = np.full(_HISTORY, -1, dtype=np.int64)
        self.hist_q = np.zeros((_HISTORY, len(self.core.joint_names)))
        self.hist_v = np.zeros((_HISTORY, len(self.core.joint_names)))
        self.slave_tick = -1
        self._slave_was_in_error = False

        prefix = "controller/slave/" if role == "slave" else "controller/"
        all_names = self.core.joint_names if role != "master" else robot_config.joint_names
        self.js_names = all_names
        self.js_msg = codec.joint_state_msg(all_names)
        self.js_pub = wire.publisher(prefix + "joint_states")
        self.status_pub = wire.publisher(prefix + "status")
        self.gripper_pubs = {} if role == "slave" else {
            a.name: wire.publisher(f"controller/gripper/{a.name}") for a in robot_config.arms}
        self._last_js: tuple[bytes, int] | None = None
        self._last_status_key: tuple | None = None
        self._last_status_wall = 0.0
        self._last_gripper: dict[str, tuple[bool, np.ndarray]] = {}
        self._last_gripper_wall = 0.0
        self.loop_overruns = 0

        wire.serve(prefix + "trajectory", self._on_trajectory)
        wire.serve(prefix + "command", self._on_command)
        if role == "master":
            wire.subscribe("controller/slave/joint_states", self._on_slave_joint_states)
            wire.subscribe("controller/slave/status", self._on_slave_status)
        wire.watch_alive(self._on_alive, "alive/*")
        log.info("controller %s up: joints %s, time scale %g", role, ", ".join(self.core.joint_names),
                 self.time_scale)

    # ------------------------------------------------------------------ loop
    def run(self, stop: threading.Event | Any) -> None:
        """The fixed-period loop, until `stop.is_set()`."""
        base = 1.0 / self.config.feedback_rate
        deadline = time.monotonic()
        while not stop.is_set():
            try:
                self.iterate(time.monotonic())
            except Exception:  # a bug in one loop must not take the stream down; it is logged
                log.exception("controller loop failed")
            deadline += base * self.core.faults.slow_loop_factor
            delay = deadline - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -base * 50:  # stalled (debugger, overload): start afresh instead of bursting
                self.loop_overruns += 1
                deadline = time.monotonic()

    def iterate(self, now: float) -> None:
        """One loop: step the core to robot time, check links, publish."""
        actions: list[Callable[[], None]] = []
        with self.lock:
            core = self.core
            target = self.clock.tick(now)
            limit = int(self.server.max_catch_up / core.period)
            steps = min(target - core.tick, limit)
            if target - core.tick > limit:
                log.warning("loop fell behind by %d ticks", target - core.tick)
            for _ in range(max(steps, 0)):
                fb = core.step()
                if self.role == "master":
                    slot = core.tick % _HISTORY
                    self.hist_tick[slot] = core.tick
                    self.hist_q[slot] = fb.positions
                    self.hist_v[slot] = fb.velocities
            if self.role == "master":
                self._check_slave_link(now, actions)
            elif self.role == "both" and core.faults.drop_slave_link and not core.alarm_code:
                core.link_lost("slave")  # one process: the fault stands for a lost link to the slave's groups
            js_payload = self._joint_state_payload(core)
            status, status_key = self._status_locked()
            grippers = self._gripper_states_locked() if self.gripper_pubs else {}
        for act in actions:
            threading.Thread(target=act, daemon=True, name="controller-forward").start()
        self.js_pub.put_encoded(*js_payload)
        due = now - self._last_status_wall >= 1.0 / self.config.status_rate
        if status_key != self._last_status_key or due:
            self.status_pub.put(status)
            self._last_status_key = status_key
            self._last_status_wall = now
        if grippers:
            self._publish_grippers(grippers, now)

    def _joint_state_payload(self, core: ControllerCore) -> tuple[bytes, int]:
        if core.faults.freeze_feedback and self._last_js is not None:
            return self._last_js
        fb = core.feedback()
        msg = self.js_msg
        tick = core.tick
        if self.role == "master":
            q, v = fb.positions, fb.velocities
            slot = self.slave_tick % _HISTORY
            if self.slave_link_ok and self.slave_tick <= tick and self.hist_tick[slot] == self.slave_tick:
                # one consistent sample: our state at the tick of the slave's latest sample
                tick, q, v = self.slave_tick, self.hist_q[slot], self.hist_v[slot]
            msg.position[self.own_idx] = q
            msg.velocity[self.own_idx] = v
            msg.position[self.slave_idx] = self.slave_q
            msg.velocity[self.slave_idx] = self.slave_v
        else:
            msg.position[:] = fb.positions
            msg.velocity[:] = fb.velocities
        stamp_ns = self.clock.tick_ns(tick)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        self._last_js = (messages.encode(codec.JOINT_STATE_TYPE, msg), stamp_ns)
        return self._last_js

    def _check_slave_link(self, now: float, actions: list[Callable[[], None]]) -> None:
        core = self.core
        if self.slave_heard and self.link.check(now):
            self._lose_slave("no feedback from the slave for "
                             f"{self.config.link_timeout:g} s", actions)
        in_error = bool(core.alarm_code)
        if in_error and not self._was_in_error and self.slave_link_ok:
            # an alarm on the master aborts the slave's half too (smooth stop)
            actions.append(lambda: self._forward_command(Command.STOP_MOTION))
            self.slave_end_tick = 0
        self._was_in_error = in_error
        st = self.slave_status
        slave_err = st is not None and (st.in_error or st.e_stopped)
        if slave_err and not self._slave_was_in_error and core.in_motion:
            core.stop_motion()
        self._slave_was_in_error = slave_err

    def _lose_slave(self, why: str, actions: list[Callable[[], None]] | None) -> None:
        """Alarm and hard stop here; and a hard stop of the slave if it can still hear us."""
        if not self.slave_link_ok and self.core.alarm_code:
            return
        log.error("slave link lost: %s", why)
        self.slave_link_ok = False
        self.slave_v = np.zeros(len(self.slave_joints))
        self.core.link_lost("slave")
        self.slave_end_tick = 0
        if actions is not None:
            actions.append(lambda: self._forward_command(Command.STOP_SERVOS, timeout=0.2))

    # ------------------------------------------------------------------ status and grippers
    def _status_locked(self) -> tuple[Any, tuple]:
        own = self.core.status()
        if self.role == "master":
            groups = list(own.groups)
            faults = list(own.faults)
            if self.slave_status is not None:
                groups += [g for g in self.slave_status.groups if g.controller == "slave"]
            else:  # never heard: report the slave's groups as unpowered and unreachable
                for g in self.rc.groups:
                    if self.owners.get(g.name, g.controller) == "slave":
                        groups.append(replace(own.groups[0], name=g.name, controller="slave",
                                              drives_powered=False,
                                              in_motion=False, motion_possible=False, queue_count=0))
            order = [g.name for g in self.rc.groups]
            groups.sort(key=lambda g: order.index(g.name) if g.name in order else len(order))
            merged = ControllerStatus(own.stamp, tuple(groups), own.lease_holder, tuple(faults))
            link = {g.name: (g.controller != "slave" or self.slave_link_ok) for g in groups}
            possible = merged.motion_possible and self.slave_link_ok
        else:
            merged, link, possible = own, None, None
        stamp_ns = self.clock.tick_ns(self.core.tick)
        msg = codec.status_msg(merged, stamp_ns, self.time_scale, link, self.group_joints, possible)
        key = (merged.groups, merged.lease_holder, merged.faults, possible,
               tuple(sorted((link or {}).items())))
        return msg, key

    def _gripper_states_locked(self) -> dict[str, bool]:
        states = dict(self.core.grippers)
        states.update(self.slave_grippers)
        return states

    def full_position(self) -> np.ndarray:
        """All 13 joints (project order): this core's and, on the master, the slave's last sample."""
        with self.lock:
            q = np.asarray(self.rc.home, dtype=float).copy()
            q[self.own_idx] = self.core.q
            if self.role == "master":
                q[self.slave_idx] = self.slave_q
            return q

    def _publish_grippers(self, states: dict[str, bool], now: float) -> None:
        changed = any(self._last_gripper.get(arm, (None,))[0] != closed for arm, closed in states.items())
        if not changed and now - self._last_gripper_wall < 1.0 / self.config.status_rate:
            return
        q = self.full_position()
        poses = self._tcp_poses(q)
        if not changed and all(np.allclose(poses[a], self._last_gripper[a][1], atol=1e-6) for a in states):
            self._last_gripper_wall = now
            return
        stamp_ns = self.clock.tick_ns(self.core.tick)
        for arm, closed in states.items():
            opening = 0.0 if closed else self.server.gripper_open_width
            self.gripper_pubs[arm].put(codec.gripper_msg(arm, closed, opening, poses[arm], stamp_ns))
            self._last_gripper[arm] = (closed, poses[arm])
        self._last_gripper_wall = now

    def _tcp_poses(self, q: np.ndarray) -> dict[str, np.ndarray]:
        if self.kin is None:
            from drivers.robot.kinematics import CellKinematics

            self.kin = CellKinematics(self.rc)
        return self.kin.tcp_poses(q)

    # ------------------------------------------------------------------ peers
    def _on_slave_joint_states(self, key: str, msg: Any, raw: Any) -> None:
        with self.lock:
            if self.core.faults.drop_slave_link:
                return
            fb = codec.feedback_from_msg(msg)
            if fb.joint_names != self.slave_joints:
                log.warning("slave joint states name %s, expected %s", fb.joint_names, self.slave_joints)
                return
            self.slave_q = fb.positions
            self.slave_v = fb.velocities
            self.slave_tick = self.clock.ns_tick(messages.stamp_to_ns(msg.header.stamp))
            self.slave_heard = True
            if not self.slave_link_ok and not self.core.alarm_code:
                self.slave_link_ok = True
            self.link.heard(time.monotonic())

    def _on_slave_status(self, key: str, msg: Any, raw: Any) -> None:
        with self.lock:
            if not self.core.faults.drop_slave_link:
                self.slave_status = codec.status_from_msg(msg)

    def _on_alive(self, full_key: str, alive: bool) -> None:
        rel = split_key(full_key)[1]
        if alive:
            return
        actions: list[Callable[[], None]] = []
        with self.lock:
            if rel == f"alive/{PROCESS_NAMES['slave']}" and self.role == "master":
                self._lose_slave("its liveliness token vanished", None)
            elif rel == f"alive/{PROCESS_NAMES['master']}" and self.role == "slave":
                self.core.link_lost("master")
            if self.core.lease_holder and self.core.lease_holder == rel:
                log.warning("lease holder %s vanished: stopping", rel)
                self.core.lease_lost(rel)
                if self.role == "master" and self.slave_link_ok:
                    actions.append(lambda: self._forward_command(Command.STOP_MOTION))
                    self.slave_end_tick = 0
        for act in actions:
            act()

    def _forward_command(self, code: int, arm: str = "", values: tuple[float, ...] = (),
                         timeout: float | None = None) -> Reply:
        msg = messages.new(codec.COMMAND_TYPE, header=messages.header(self.clock.tick_ns(self.core.tick)),
                           command=int(code), client=f"alive/{self.wire.process}", arm=arm,
                           values=list(values))
        try:
            reply = self.wire.request("controller/slave/command", msg,
                                      timeout=timeout or self.config.reply_timeout)
        except Exception as exc:  # noqa: BLE001 - WireError or a closing session: the link is the problem
            return Reply(Result.NOT_READY, Subcode.NOT_READY_ERROR, f"slave: {exc}")
        return codec.reply_from_msg(reply)

    # ------------------------------------------------------------------ queryables
    def _delay_reply(self) -> None:
        f = self.core.faults
        if f.reply_latency or f.reply_jitter:
            time.sleep(f.reply_latency + random.uniform(0.0, f.reply_jitter))

    def _reply(self, reply: Reply, command: int = 0) -> Any:
        self._delay_reply()
        return codec.reply_msg(reply, self.clock.tick_ns(self.core.tick), command)

    def _on_trajectory(self, request: Any, info: RequestInfo) -> Any:
        session = info.attachment.decode("utf-8", "replace")
        try:
            traj = codec.trajectory_from_msg(request)
        except codec.MalformedTrajectory as exc:
            return self._reply(Reply(Result.INVALID, Subcode.INVALID_DATA_INSUFFICIENT, f"arrays: {exc}",
                                     exc.point))
        if self.role == "master":
            reply = self.submit_full(traj, session)
        else:
            start = self.clock.ns_tick(messages.stamp_to_ns(request.header.stamp))
            with self.lock:
                if self.role == "slave" and start > 0:
                    at = start
                else:  # after the queue, so the reply's start tick is when the motion really starts
                    at = self.core.projected_end_tick() if self.core.queue_count else None
                reply = self.core.submit(traj.joint_names, traj.positions, traj.velocities, traj.times,
                                         session, at)
        log.info("trajectory from %s: %s", session or "?", reply.describe())
        return self._reply(reply)

    def _lease_reply(self, session: str) -> Reply | None:
        holder = self.core.lease_holder
        if not self.config.lease_required or (session and session == holder):
            return None
        if holder:
            return Reply(Result.FAILURE, Subcode.LEASE_HELD,
                         f"lease: session {holder!r} holds the control lease")
        return Reply(Result.FAILURE, Subcode.NO_LEASE, "lease: acquire the control lease first")

    def submit_full(self, traj: JointTrajectory, session: str) -> Reply:
        """Master: validate all joints, forward the slave's part with a common start tick, queue ours."""
        with self.submit_lock:
            with self.lock:
                core = self.core
                reply = self._lease_reply(session) or check_ready(core.readiness())
                if not reply.ok:
                    return reply
                if not self.slave_link_ok:
                    return Reply(Result.NOT_READY, Subcode.NOT_READY_ERROR,
                                 "readiness: no link to the slave controller")
                current = self._queue_end_full()
                reply = check_trajectory(traj.joint_names, traj.positions, traj.velocities, traj.times,
                                         current, self.rc, self.config)
                if not reply.ok:
                    return reply
                parts = split_trajectory(self.rc, self.owners, traj.joint_names, traj.positions,
                                         traj.velocities, traj.times)
                mine = parts["master"]
                reply = core.check(mine.joint_names, mine.positions, mine.velocities, mine.times, session)
                if not reply.ok:
                    return reply
                lead = int(math.ceil(self.server.sync_lead_time * self.time_scale / core.period))
                start = common_start_tick(core.tick, core.projected_end_tick(), self.slave_end_tick, lead)
            slave = parts.get("slave")
            if slave is not None:
                fwd = JointTrajectory(slave.joint_names, slave.times, slave.positions, slave.velocities)
                try:
                    answer = self.wire.request("controller/slave/trajectory",
                                               codec.trajectory_msg(fwd, self.clock.tick_ns(start)),
                                               timeout=self.config.reply_timeout)
                except Exception as exc:  # noqa: BLE001 - no reply: treat as a link failure
                    return Reply(Result.NOT_READY, Subcode.NOT_READY_ERROR, f"slave did not accept: {exc}")
                sreply = codec.reply_from_msg(answer)
                if not sreply.ok:
                    return replace(sreply, text=f"slave: {sreply.text}")
            with self.lock:
                if core.tick >= start:
                    reply = Reply(Result.FAILURE, Subcode.NONE,
                                  "synchronous start missed: the slave answered too late; retry")
                else:
                    reply = core.submit(mine.joint_names, mine.positions, mine.velocities, mine.times,
                                        session, start)
                if reply.ok and slave is not None:
                    self.slave_end_tick = start + int(math.ceil(float(slave.times[-1]) / core.period)) + 1
                    self.slave_end_q = slave.positions[-1].copy()
            if not reply.ok and slave is not None:
                self._forward_command(Command.STOP_MOTION)
            elif reply.ok:
                reply = replace(reply, text=reply.text + " (master and slave)")
            return reply

    def _queue_end_full(self) -> np.ndarray:
        q = np.asarray(self.rc.home, dtype=float).copy()
        q[self.own_idx] = self.core.queue_end_position()
        busy = self.slave_end_tick > self.core.tick
        q[self.slave_idx] = self.slave_end_q if busy else self.slave_q
        return q

    def _on_command(self, request: Any, info: RequestInfo) -> Any:
        code, session = int(request.command), request.client
        values = tuple(float(v) for v in request.values)
        if self.role != "master":
            with self.lock:
                n = len(self.core.joint_names)
                if code == Command.MOVE_TO and self.role == "both" and len(values) != n:
                    reply = Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                                  f"move_to: values must be {len(self.core.joint_names)} joint positions")
                elif code == Command.MOVE_TO and np.allclose(values, self.core.queue_end_position(), rtol=0.0,
                                                             atol=1e-9) and self.core.motion_possible \
                        and self._lease_reply(session) is None:
                    reply = Reply(Result.SUCCESS, Subcode.NONE, "move_to: already at the target")
                else:
                    reply = self.core.command(code, session, request.arm, values, request.joint)
            return self._reply(reply, code)
        return self._reply(self._master_command(code, session, request.arm, values, request.joint), code)

    def _master_command(self, code: int, session: str, arm: str, values: tuple[float, ...],
                        joint: str) -> Reply:
        try:
            cmd = Command(code)
        except ValueError:
            return Reply(Result.INVALID, Subcode.INVALID_COMMAND, f"command: unknown command code {code}")
        if cmd in (Command.MOVE_TO, Command.JOG):
            return self._master_move(cmd, session, values, joint)
        if cmd in (Command.GRIP_OPEN, Command.GRIP_CLOSE) and arm in self.slave_grippers:
            with self.lock:
                reply = self._lease_reply(session)
            if reply is not None:
                return reply
            reply = self._forward_command(cmd, arm)
            if reply.ok:
                with self.lock:
                    self.slave_grippers[arm] = cmd == Command.GRIP_CLOSE
            return reply
        with self.lock:
            reply = self.core.command(cmd, session, arm, values, joint)
            if cmd in _DROPS_QUEUE and (reply.ok or cmd == Command.ESTOP):
                self.slave_end_tick = 0
            if cmd in (Command.RESET_ALARM, Command.FAULT_ALARM_OFF) and reply.ok and self.slave_heard:
                self.link.heard(time.monotonic())
                self.slave_link_ok = not self.link.lost
        if cmd in _MASTER_ONLY or (not reply.ok and cmd != Command.ESTOP):
            return reply
        if cmd in (Command.GRIP_OPEN, Command.GRIP_CLOSE):
            return reply  # one of the master's own grippers: nothing for the slave to do
        if cmd in MOTION_COMMANDS or cmd in (Command.ESTOP, Command.ESTOP_RESET, Command.FAULT_ALARM_OFF) \
                or cmd.name.startswith("PENDANT"):
            sreply = self._forward_command(cmd)
            if not sreply.ok:
                return replace(sreply, text=f"slave: {sreply.text}")
        return reply

    def _master_move(self, cmd: Command, session: str, values: tuple[float, ...], joint: str) -> Reply:
        """Move-to / jog over all joints: one ruckig plan, submitted like a cell trajectory."""
        names = self.rc.joint_names
        with self.lock:
            start = self._queue_end_full()
        if cmd == Command.JOG:
            if joint not in names:
                return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                             f"jog: joint must be one of {', '.join(names)}, got {joint!r}", -1, joint)
            if len(values) != 1 or not math.isfinite(values[0]):
                return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                             f"jog: values must be (delta rad), got {list(values)}",
                             -1, joint)
            target = start.copy()
            target[names.index(joint)] += values[0]
        else:
            target = np.asarray(values, dtype=float)
            if target.shape != (len(names),) or not np.isfinite(target).all():
                return Reply(Result.INVALID, Subcode.BAD_ARGUMENT,
                             f"move_to: values must be {len(names)} finite joint positions, "
                             f"got {list(values)}")
        lower, upper = self.rc.lower, self.rc.upper
        out = (target < lower) | (target > upper)
        if out.any():
            j = int(np.argmax(out))
            return Reply(Result.INVALID, Subcode.INVALID_DATA_POSITION,
                         f"{cmd.name.lower()}: {names[j]} target {target[j]:.6f} rad is outside "
                         f"[{lower[j]:.6f}, {upper[j]:.6f}]", -1, names[j])
        with self.lock:
            reply = self._lease_reply(session) or check_ready(self.core.readiness())
        if not reply.ok:
            return reply
        if np.allclose(target, start, rtol=0.0, atol=1e-9):
            return Reply(Result.SUCCESS, Subcode.NONE, f"{cmd.name.lower()}: already at the target")
        f = self.config.move_to_limit_fraction
        try:
            times, pos, vel = plan_point_to_point(start, target, self.rc.max_velocity * f,
                                                  self.rc.max_acceleration * f, self.rc.max_jerk * f,
                                                  self.config.max_points)
        except PlanError as exc:
            return Reply(Result.FAILURE, Subcode.PLAN_FAILED, f"{cmd.name.lower()}: {exc}")
        return self.submit_full(JointTrajectory(names, times, pos, vel), session)

    # ------------------------------------------------------------------ status for callers
    def status(self) -> ControllerStatus:
        with self.lock:
            return self.core.status()

    def close(self) -> None:
        """Stop the motion (the process is going away) and close the session."""
        with self.lock:
            self.core.stop_motion()
        self.wire.close()

