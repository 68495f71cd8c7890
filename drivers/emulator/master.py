"""`MasterNode`: the DX100 master process, the cell's only contact when the groups are split.

It validates a whole trajectory, has the slave pre-load it, then queues its own part on a common start
tick and releases the slave's on the same tick (RELEASE, the tick as the header stamp); merges the slave's
feedback and status into `controller/joint_states|status`, and raises SLAVE_LINK_LOST and stops every
group when the slave's token vanishes or its feedback stops for `link.timeout` (wall s). Commands that
concern the slave's groups are forwarded to it. Stops, holds, resumes and e-stops (also a lost lease and
the master's alarms) act on a shared tick `server.stop_lead_time` ahead, stamped on the forwarded
command, so both controllers follow one stop profile of the whole path and stop on the same tick
(`drivers.emulator.core`).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from drivers.controller import codec
from drivers.controller.acceptance import check_trajectory
from drivers.controller.codes import OK, Alarm, Command, Reply, Result, Subcode
from drivers.controller.config import ControllerConfig
from drivers.controller.credential import Signer
from drivers.controller.interface import PROCESS_NAMES, ControllerStatus, JointFeedback
from drivers.controller.motion import Axes, move_trajectory
from drivers.controller.trajectory import FloatArray, JointTrajectory
from drivers.emulator.commands import LEASED_COMMANDS, AnyCommand, EmulatorCommand, command_of
from drivers.emulator.node import Actions, ControllerNode, ServerConfig
from drivers.emulator.split import (
    LinkMonitor,
    common_start_tick,
    joints_of,
    merge_feedback,
    merge_status,
    split_trajectory,
)
from drivers.robot.config import RobotConfig
from drivers.robot.kinematics import CellKinematics
from drivers.wire import messages
from drivers.wire.messages import WireError
from drivers.wire.transport import Wire, decode_sample

log = logging.getLogger(__name__)

_HISTORY = 4096  # ticks of the master's own joint states kept for merging (16 s of robot time)
_GRIP = frozenset({Command.GRIP_OPEN, Command.GRIP_CLOSE})
_SILENCE_POLL_S = 0.01  # how often a reset of the slave-link alarm looks for the slave's feedback
# Commands the master runs itself only (the rest are also forwarded to the slave).
_MASTER_ONLY = frozenset({
    Command.CHECK_MOTION_READY, Command.CHECK_QUEUE_CNT, Command.DISCONNECT, Command.LEASE_ACQUIRE,
    Command.LEASE_RELEASE, Command.LEASE_RENEW, EmulatorCommand.FAULT_DROP_SLAVE_LINK_ON,
    EmulatorCommand.FAULT_DROP_SLAVE_LINK_OFF, EmulatorCommand.FAULT_FREEZE_FEEDBACK_ON,
    EmulatorCommand.FAULT_FREEZE_FEEDBACK_OFF, EmulatorCommand.FAULT_ALARM_ON,
    EmulatorCommand.FAULT_SLOW_LOOP_ON, EmulatorCommand.FAULT_SLOW_LOOP_OFF, EmulatorCommand.RELEASE,
})
# Commands after which the slave's queue is known to be empty (or being dropped).
_DROPS_QUEUE = frozenset({Command.STOP_MOTION, Command.STOP_SERVOS, Command.ESTOP, Command.STOP_TRAJ_MODE,
                          EmulatorCommand.PENDANT_TEACH, EmulatorCommand.PENDANT_REMOTE_OFF})


@dataclass
class SlaveView:
    """What the master knows of the slave: its latest sample and status, the link, where its queue ends."""

    feedback: JointFeedback  # the latest sample (home, at rest, until one arrives)
    link: LinkMonitor
    grippers: dict[str, bool]  # arm -> closed, for the slave's arms
    end_q: FloatArray  # where its queue ends, while `end_tick` is ahead
    status: ControllerStatus | None = None
    status_key: ControllerStatus | None = None  # `status` without its stamp (what a change is)
    status_version: int = 0  # counts the changes of `status_key`
    tick: int = -1  # the tick of `feedback`
    heard: bool = False  # a sample arrived at least once
    link_ok: bool = False
    end_tick: int = 0  # the tick its queue ends on; 0 when empty or dropped
    start_tick: int = 0  # the tick its last released motion starts on
    in_error: bool = False  # e-stop or alarm in its latest status


class MasterNode(ControllerNode):
    """The master: its own core (the master's groups) plus the view of the slave it commands."""

    ROLES = ("master",)

    def __init__(self, wire: Wire, robot_config: RobotConfig, config: ControllerConfig,
                 server_config: ServerConfig | None = None, time_scale: float | None = None,
                 kinematics: CellKinematics | None = None):
        slave_joints = joints_of(robot_config, config.group_owners, "slave")
        self.slave_idx = np.array([robot_config.index(j) for j in slave_joints], dtype=int)
        home = np.asarray(robot_config.home, dtype=float)[self.slave_idx]
        rest = np.zeros(len(slave_joints))
        self.slave = SlaveView(
            feedback=JointFeedback(0.0, slave_joints, home, rest, rest, rest),
            link=LinkMonitor(config.link_stall_timeout, time.monotonic()),
            grippers={a.name: False for a in robot_config.arms
                      if set(robot_config.group(a.group).joints) <= set(slave_joints)},
            end_q=home.copy())
        self.axes = Axes.of(robot_config, robot_config.joint_names)
        self.submit_lock = threading.Lock()  # one trajectory forward at a time
        self._history: list[tuple[int, JointFeedback] | None] = [None] * _HISTORY
        self._rest: tuple[int, int, JointFeedback] | None = None  # ticks skipped at rest, and the state
        self._slave_content = b""   # the slave's last decoded sample after its stamp
        self._was_in_error = False
        self._slave_lost_at = -math.inf   # monotonic time the slave link was last declared lost
        self.signer = Signer(f"alive/{wire.process}")  # the slave pins its key on first contact
        super().__init__(wire, "master", robot_config, config, server_config, time_scale, kinematics)

    def _declare(self, prefix: str) -> None:
        # the loop reads the slave's newest sample itself: no thread wakes for each of 250 a second
        self.slave_samples = self.wire.buffer("controller/slave/joint_states")
        self.wire.subscribe("controller/slave/status", self._on_slave_status)
        super()._declare(prefix)

    # ------------------------------------------------------------------ loop
    def _stepped(self, tick: int, feedback: JointFeedback) -> None:
        self._history[tick % _HISTORY] = (tick, feedback)

    def _skipped(self, first: int, last: int) -> None:
        rest = self._rest
        if rest is not None and rest[1] == first - 1:
            self._rest = (rest[0], last, rest[2])   # still at rest where it was
        else:
            self._rest = (first, last, self.core.feedback())

    def _own_at(self, tick: int) -> JointFeedback | None:
        """This core's joint state at `tick`, while still kept."""
        kept = self._history[tick % _HISTORY]
        if kept is not None and kept[0] == tick:
            return kept[1]
        rest = self._rest
        return rest[2] if rest is not None and rest[0] <= tick <= rest[1] else None

    def _check_links(self, now: float, stalled: float, actions: Actions) -> None:
        """The slave is lost when its token vanishes (`_peer_vanished`: Zenoh's link lease, kept by its
        own threads) or, its token still there, when it sends nothing for `link.stall_timeout` (a hung
        process). A shorter silence is the slave's loop stalling: it catches up and nothing is lost."""
        core, slave = self.core, self.slave
        slave.link.last_heard += stalled   # our own stall is not the slave's silence
        self._take_slave_sample(now)
        if slave.heard and slave.link.check(now):
            self._lose_slave(f"the slave sent nothing for {self.config.link_stall_timeout:g} s while its "
                             "session stayed (a hung process)", actions)
        in_error = bool(core.alarm_code)
        if in_error and not self._was_in_error and slave.link_ok:
            # an alarm on the master aborts the slave's half too, with the same stop from the same tick
            tick = core.pending_stop_tick
            actions.append(lambda: self._forward_command(Command.STOP_MOTION, at_tick=tick))
            slave.end_tick = 0
        self._was_in_error = in_error
        slave_error = slave.status is not None and (slave.status.in_error or slave.status.e_stopped)
        if slave_error and not slave.in_error and core.in_motion and not core.stopping:
            core.stop_motion()  # the slave's own alarm (a stop the master asked for is under way already)
        slave.in_error = slave_error

    def _lose_slave(self, why: str, actions: Actions | None) -> None:
        """Alarm and hard stop here; and a hard stop of the slave if it can still hear us."""
        slave = self.slave
        if not slave.link_ok and self.core.alarm_code:
            return
        log.error("slave link lost: %s", why)
        self._slave_lost_at = time.monotonic()
        slave.link_ok = False
        slave.feedback = replace(slave.feedback, velocities=np.zeros(len(slave.feedback.joint_names)))
        self.core.link_lost("slave")
        slave.end_tick = 0
        if actions is not None:
            actions.append(lambda: self._forward_command(Command.STOP_SERVOS, timeout=0.2))

    # ------------------------------------------------------------------ joint states, status, grippers
    def _joint_state(self, own: JointFeedback) -> tuple[int, JointFeedback]:
        """One consistent sample: ours now if the slave's arm is still (its last sample at rest and no
        motion of its started since), else ours at the tick of the slave's latest sample."""
        slave, tick = self.slave, self.core.tick
        started_unheard = slave.tick < slave.start_tick <= tick
        still = not slave.feedback.velocities.any() and not started_unheard
        kept = self._own_at(slave.tick) if slave.link_ok and slave.tick <= tick and not still else None
        if kept is not None:
            tick, own = slave.tick, kept
        return tick, merge_feedback(self.rc, [own, slave.feedback])

    def _status_key(self) -> tuple:
        return (super()._status_key(), self.slave.status_version, self.slave.link_ok)

    def _merged_status(self) -> tuple[ControllerStatus, dict[str, bool] | None, bool | None]:
        own = self.core.status()
        merged = merge_status(self.rc, [own, self.slave.status or self._unheard_slave(own)])
        link = {g.name: g.controller != "slave" or self.slave.link_ok for g in merged.groups}
        return merged, link, merged.motion_possible and self.slave.link_ok

    def _unheard_slave(self, own: ControllerStatus) -> ControllerStatus:
        """The slave's groups before it was ever heard: unpowered and unreachable."""
        owners = self.config.group_owners
        groups = tuple(replace(own.groups[0], name=g.name, controller="slave", drives_powered=False,
                               in_motion=False, motion_possible=False, queue_count=0)
                       for g in self.rc.groups if owners.get(g.name, g.controller) == "slave")
        return ControllerStatus(own.stamp, groups)

    def _gripper_states(self) -> dict[str, bool]:
        return {**self.core.grippers, **self.slave.grippers}

    def full_position(self) -> FloatArray:
        """All joints (project order): this core's and the slave's last sample."""
        with self.lock:
            q = super().full_position()
            q[self.slave_idx] = self.slave.feedback.positions
            return q

    # ------------------------------------------------------------------ the slave
    def _take_slave_sample(self, now: float) -> None:
        """The slave's newest joint state, if one came since the last loop (holding the lock)."""
        raw = self.slave_samples.latest()
        if raw is None or raw.is_delete or self.core.faults.drop_slave_link:
            return
        slave = self.slave
        stamp_ns = messages.leading_stamp_ns(raw.payload)
        content = raw.payload[messages.HEADER_STAMP_END:]
        if stamp_ns is not None and content == self._slave_content:
            # the slave at rest repeats its sample but for the stamp: nothing to decode
            feedback = replace(slave.feedback, stamp=self.clock.timebase.robot(stamp_ns) * 1e-9)
        else:
            try:
                msg = decode_sample(raw)
            except WireError as err:
                log.warning("dropped a bad slave sample: %s", err)
                return
            feedback = codec.feedback_from_msg(msg, self.clock.timebase)
            if feedback.joint_names != slave.feedback.joint_names:
                log.warning("slave joint states name %s, expected %s", feedback.joint_names,
                            slave.feedback.joint_names)
                return
            stamp_ns = messages.stamp_to_ns(msg.header.stamp)
            self._slave_content = content
        slave.feedback = feedback
        slave.tick = self.clock.stamp_tick(stamp_ns)
        slave.heard = True
        if not slave.link_ok and not self.core.alarm_code:
            slave.link_ok = True
        slave.link.heard(now)

    def _on_slave_status(self, _key: str, msg: Any, _raw: Any) -> None:
        with self.lock:
            if not self.core.faults.drop_slave_link:
                status = codec.status_from_msg(msg)
                content = replace(status, stamp=0.0)
                if content != self.slave.status_key:
                    self.slave.status_key = content
                    self.slave.status_version += 1
                self.slave.status = status

    def _peer_vanished(self, alive_key: str) -> None:
        if alive_key == f"alive/{PROCESS_NAMES['slave']}":
            self._lose_slave("its liveliness token vanished", None)

    def _lease_lapsed(self, actions: Actions) -> None:
        if self.slave.link_ok:
            tick = self.core.pending_stop_tick
            actions.append(lambda: self._forward_command(Command.STOP_MOTION, at_tick=tick))
            self.slave.end_tick = 0

    def shared_tick(self) -> int:
        return max(self.core.tick, self.clock.tick()) + self.lead_ticks(self.server.stop_lead_time)

    def _forward_command(self, code: int, arm: str = "", timeout: float | None = None,
                         values: tuple[float, ...] = (), at_tick: int | None = None) -> Reply:
        """Run a command on the slave, from tick `at_tick` (stamped; None: its next tick)."""
        msg = codec.command_msg(code, self.signer.client, arm, values,
                                stamp_ns=0 if at_tick is None else self.clock.stamp_ns(at_tick))
        try:
            answer = self.wire.request("controller/slave/command", msg,
                                       timeout=timeout or self.config.reply_timeout,
                                       sign=self.signer.attachment)
        except Exception as exc:  # a wire error or a closing session: the link is the problem
            return Reply(Result.NOT_READY, Subcode.NOT_READY_ERROR, f"slave: {exc}")
        return codec.reply_from_msg(answer)

    def _forward_trajectory(self, path: JointTrajectory) -> Reply:
        """The whole path, for the slave to pre-load its columns; its reply (text prefixed `slave:`)."""
        try:
            answer = self.wire.request("controller/slave/trajectory", codec.trajectory_msg(path),
                                       timeout=self.config.reply_timeout, sign=self.signer.attachment)
        except Exception as exc:  # no reply or a closing session: treat as a link failure
            return Reply(Result.NOT_READY, Subcode.NOT_READY_ERROR, f"slave did not accept: {exc}")
        reply = codec.reply_from_msg(answer)
        return reply if reply.ok else replace(reply, text=f"slave: {reply.text}")

    # ------------------------------------------------------------------ trajectories
    def _submit(self, trajectory: JointTrajectory, session: str, stamp_ns: int) -> Reply:
        return self.submit_full(trajectory, session)

    def submit_full(self, trajectory: JointTrajectory, session: str) -> Reply:
        """Validate all joints; the slave pre-loads the whole path (no deadline: it may answer late);
        then queue ours on a common start tick and release the slave's on the same tick."""
        with self.submit_lock:
            with self.lock:
                reply, parts = self._check_full(trajectory, session)
            if not reply.ok:
                return reply
            slave_part = parts.get("slave")
            if slave_part is not None:
                loaded = self._forward_trajectory(trajectory)
                if not loaded.ok:
                    return loaded
            with self.lock:
                reply = self._queue_own(trajectory, parts["master"], slave_part, session)
            if slave_part is None:
                return reply
            ident = (float(loaded.trajectory_id),)
            if not reply.ok:
                self._forward_command(EmulatorCommand.RELEASE, values=ident)  # no start tick: it is dropped
                return reply
            released = self._forward_command(EmulatorCommand.RELEASE, values=ident, at_tick=reply.start_tick)
            if not released.ok:
                # both queues were done by the start tick: only our half can be moving, alone
                with self.lock:
                    self.core.stop_motion()
                    self.slave.end_tick = 0
                return replace(released, text=f"synchronous start missed: slave: {released.text}; retry")
            return replace(reply, text=reply.text + " (master and slave)")

    def _check_full(self, trajectory: JointTrajectory,
                    session: str) -> tuple[Reply, dict[str, JointTrajectory]]:
        """Every rule over all joints, then this core's own checks: OK with the parts by role, or the
        refusal."""
        core = self.core
        reply = core.move_permission(session)
        if not reply.ok:
            return reply, {}
        if not self.slave.link_ok:
            return Reply(Result.NOT_READY, Subcode.NOT_READY_ERROR,
                         "readiness: no link to the slave controller"), {}
        reply = check_trajectory(trajectory, self._queue_end_full(), self.rc, self.config)
        if not reply.ok:
            return reply, {}
        parts = split_trajectory(self.rc, self.config.group_owners, trajectory)
        reply = core.check(parts["master"], session)
        if not reply.ok:
            return reply, {}
        return OK, parts

    def _queue_own(self, path: JointTrajectory, own: JointTrajectory, slave_part: JointTrajectory | None,
                   session: str) -> Reply:
        """Queue the master's part on the common start tick: after both queues, `sync_lead_time` ahead
        (the release's way to the slave)."""
        core = self.core
        lead = self.lead_ticks(self.server.sync_lead_time)
        now = max(core.tick, self.clock.tick())
        start = common_start_tick(now, core.projected_end_tick(), self.slave.end_tick, lead)
        reply = core.submit(own, session, start, path=path)
        if reply.ok and slave_part is not None:
            self.slave.end_tick = start + math.ceil(slave_part.duration / core.period) + 1
            self.slave.start_tick = start
            self.slave.end_q = slave_part.positions[-1].copy()
        return reply

    def _queue_end_full(self) -> FloatArray:
        """All joints where the queues end: ours, and the slave's while its queue runs."""
        q = np.asarray(self.rc.home, dtype=float).copy()
        q[self.own_idx] = self.core.queue_end_position()
        slave = self.slave
        q[self.slave_idx] = slave.end_q if slave.end_tick > self.core.tick else slave.feedback.positions
        return q

    # ------------------------------------------------------------------ commands
    def _command(self, code: int, session: str, arm: str, values: tuple[float, ...], joint: str,
                 at_tick: int | None = None) -> Reply:
        try:
            cmd = command_of(code)
        except ValueError:
            return super()._command(code, session, arm, values, joint)  # the core answers unknown codes
        if cmd is Command.MOVE_TO or cmd is Command.JOG:
            return self._move(cmd, session, values, joint)
        if cmd in _GRIP and arm in self.slave.grippers:
            return self._grip_slave(cmd, session, arm)
        if cmd == Command.RESET_ALARM and (refusal := self._slave_still_silent()) is not None:
            return refusal
        with self.lock:
            at_tick = self.shared_tick()
            reply = self.core.command(cmd, session, arm, values, joint, at_tick)
            self._follow_own_command(cmd, reply)
            # a lease given up or an injected alarm stops our half: the slave's stops with it
            stops_slave = (cmd in _MASTER_ONLY and self.core.pending_stop_tick == at_tick
                           and self.slave.link_ok)
        if stops_slave:
            self._forward_command(Command.STOP_MOTION, at_tick=at_tick)
        if not _forwarded(cmd, reply):
            return reply
        forwarded = self._forward_command(cmd, values=values, at_tick=at_tick)
        return reply if forwarded.ok else replace(forwarded, text=f"slave: {forwarded.text}")

    def _slave_still_silent(self) -> Reply | None:
        """A reset of the slave-link alarm while the slave is silent would leave the arms apart (a
        partition not yet healed, a slave not yet back): it waits up to `link.reset_wait`
        wait for the slave's feedback, then is refused, naming the silence."""
        deadline = time.monotonic() + self.config.link_reset_wait
        while True:
            with self.lock:
                if self.core.alarm_code != Alarm.SLAVE_LINK_LOST or not self.slave.heard:
                    return None
                if self.slave.link.last_heard > self._slave_lost_at:
                    return None                      # the slave spoke since the link was lost: it is back
                silent = time.monotonic() - self.slave.link.last_heard
            if time.monotonic() >= deadline:
                return Reply(Result.NOT_READY, Subcode.NOT_READY_ALARM,
                             f"alarm {Alarm.SLAVE_LINK_LOST.value} stays: no feedback from the slave for "
                             f"{silent:.1f} s (is `foldcell controller serve --role slave` running and "
                             "reachable?); reset it once the slave is back")
            time.sleep(_SILENCE_POLL_S)

    def _follow_own_command(self, cmd: AnyCommand, reply: Reply) -> None:
        """Keep the view of the slave in step with a command the master ran."""
        slave = self.slave
        if cmd in _DROPS_QUEUE and (reply.ok or cmd == Command.ESTOP):
            slave.end_tick = 0
        if cmd in (Command.RESET_ALARM, EmulatorCommand.FAULT_ALARM_OFF) and reply.ok and slave.heard:
            slave.link.heard(time.monotonic())
            slave.link_ok = not slave.link.lost

    def _grip_slave(self, cmd: AnyCommand, session: str, arm: str) -> Reply:
        with self.lock:
            refusal = self.core.lease_reply(session)
        if refusal is not None:
            return refusal
        reply = self._forward_command(cmd, arm)
        if reply.ok:
            with self.lock:
                self.slave.grippers[arm] = cmd == Command.GRIP_CLOSE
        return reply

    def _move(self, cmd: Command, session: str, values: tuple[float, ...], joint: str) -> Reply:
        """MOVE_TO / JOG over all joints: one ruckig plan, submitted like a cell trajectory."""
        with self.lock:
            start = self._queue_end_full()
            permission = self.core.move_permission(session)
        planned = move_trajectory(cmd, self.axes, start, values, joint, permission, self.config)
        if isinstance(planned, Reply):
            return planned
        return self.submit_full(planned, session)


def _forwarded(cmd: AnyCommand, reply: Reply) -> bool:
    """Whether the slave runs `cmd` too, after the master ran it with `reply`."""
    if cmd in _MASTER_ONLY or cmd in _GRIP or (not reply.ok and cmd != Command.ESTOP):
        return False
    # an injected reply latency too: the slave's replies reach the master late (the synchronous start
    # must not care)
    return cmd in LEASED_COMMANDS or cmd == Command.ESTOP
