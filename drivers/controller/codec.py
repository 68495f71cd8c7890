"""The contract's dataclasses <-> wire messages: the one encoder and decoder of each controller message,
shared by the emulator, the Zenoh client and the cell."""

from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from drivers.controller.codes import Reply
from drivers.controller.interface import ControllerStatus, GroupStatus, JointFeedback
from drivers.controller.trajectory import FloatArray, JointTrajectory
from drivers.wire import messages
from drivers.wire.poses import pose_msg
from drivers.wire.timebase import TimeBase, timebase_of

STATUS_TYPE = "foldcell_msgs/msg/ControllerStatus"
GROUP_TYPE = "foldcell_msgs/msg/GroupStatus"
REPLY_TYPE = "foldcell_msgs/msg/MotionReply"
COMMAND_TYPE = "foldcell_msgs/msg/ControllerCommand"
JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
TRAJECTORY_TYPE = "trajectory_msgs/msg/JointTrajectory"
GRIPPER_TYPE = "foldcell_msgs/msg/GripperState"


CDR_LITTLE_ENDIAN = b"\x00\x01"
_UINT32 = struct.Struct("<I")
_INT32 = struct.Struct("<i")
# Where a ControllerCommand's fields start in its CDR: a 4-byte representation header, then the body
# (alignment counts from its start): Header {int32 sec, uint32 nanosec, string frame_id}, int32 command.
_BODY = 4
_FRAME_ID_LENGTH = _BODY + 8


def command_code(payload: bytes) -> int | None:
    """The command code of an encoded `ControllerCommand`, read without decoding the rest; None when
    the bytes are not a little-endian CDR command up to the code."""
    if len(payload) < _FRAME_ID_LENGTH + 4 or payload[:2] != CDR_LITTLE_ENDIAN:
        return None
    (frame_id_bytes,) = _UINT32.unpack_from(payload, _FRAME_ID_LENGTH)  # with its NUL
    body_offset = _FRAME_ID_LENGTH - _BODY + 4 + frame_id_bytes
    body_offset += -body_offset % _INT32.size
    if _BODY + body_offset + _INT32.size > len(payload):
        return None
    return int(_INT32.unpack_from(payload, _BODY + body_offset)[0])


def tristate(value: bool) -> int:
    """A message's tri-state flag (-1 unknown, 0 false, 1 true) of a known value."""
    return 1 if value else 0


def status_msg(status: ControllerStatus, stamp_ns: int, time_scale: float,
               link_ok: Mapping[str, bool] | None = None,
               group_joints: Mapping[str, Sequence[str]] | None = None,
               motion_possible: bool | None = None, robot_ns: int | None = None) -> Any:
    """`foldcell_msgs/ControllerStatus` from the combined status, stamped `stamp_ns` (wall) with robot
    time `robot_ns` (None: robot time is wall time); `link_ok` per group (default True)."""
    link_ok = link_ok or {}
    group_joints = group_joints or {}
    groups = [messages.new(GROUP_TYPE, name=g.name, controller=g.controller,
                           joint_names=list(group_joints.get(g.name, ())),
                           drives_powered=tristate(g.drives_powered), in_motion=tristate(g.in_motion),
                           motion_possible=tristate(g.motion_possible and link_ok.get(g.name, True)),
                           link_ok=tristate(link_ok.get(g.name, True)))
              for g in status.groups]
    possible = status.motion_possible if motion_possible is None else motion_possible
    return messages.new(
        STATUS_TYPE, header=messages.header(stamp_ns), drives_powered=tristate(status.drives_powered),
        e_stopped=tristate(status.e_stopped), in_error=tristate(status.in_error),
        error_code=int(status.error_code), alarm_text=status.alarm_text, in_motion=tristate(status.in_motion),
        mode=int(status.mode), motion_possible=tristate(possible), held=tristate(status.held),
        trajectory_mode=tristate(status.trajectory_mode),
        queue_count=int(status.queue_count), groups=groups, lease_holder=status.lease_holder,
        time_scale=float(time_scale), robot_time_ns=int(stamp_ns if robot_ns is None else robot_ns),
        faults=list(status.faults), lease_note=status.lease_note, loop_stalls=int(status.loop_stalls))


def status_from_msg(msg: Any) -> ControllerStatus:
    """The combined status of a `ControllerStatus` message, stamped in its robot time. Per-group
    e-stop/alarm/hold are not on the wire: every group gets the controller-wide value."""
    groups = tuple(
        GroupStatus(name=g.name, controller=g.controller, drives_powered=g.drives_powered == 1,
                    e_stopped=msg.e_stopped == 1, in_error=msg.in_error == 1, error_code=int(msg.error_code),
                    alarm_text=msg.alarm_text, in_motion=g.in_motion == 1, mode=int(msg.mode),
                    motion_possible=g.motion_possible == 1 and msg.motion_possible == 1, held=msg.held == 1,
                    queue_count=int(msg.queue_count), trajectory_mode=msg.trajectory_mode == 1)
        for g in msg.groups)
    timebase = timebase_of(msg)
    return ControllerStatus(timebase.robot_ns * 1e-9, groups, msg.lease_holder, tuple(msg.faults),
                            timebase.scale, msg.lease_note, int(msg.loop_stalls))


def reply_msg(reply: Reply, stamp_ns: int, command: int = 0) -> Any:
    return messages.new(REPLY_TYPE, header=messages.header(stamp_ns), command=int(command),
                        result=int(reply.result), subcode=int(reply.subcode), text=reply.text,
                        point=int(reply.point), joint=reply.joint, trajectory_id=int(reply.trajectory_id),
                        start_tick=int(reply.start_tick))


def reply_from_msg(msg: Any) -> Reply:
    return Reply(int(msg.result), int(msg.subcode), msg.text, int(msg.point), msg.joint,
                 int(msg.trajectory_id), int(msg.start_tick))


def joint_state_msg(names: Sequence[str]) -> Any:
    """A reusable `JointState` whose arrays the loop overwrites in place."""
    n = len(names)
    return messages.new(JOINT_STATE_TYPE, header=messages.header(0), name=list(names),
                        position=np.zeros(n), velocity=np.zeros(n), effort=np.zeros(n))


def feedback_from_msg(msg: Any, timebase: TimeBase) -> JointFeedback:
    """The joint state of a `JointState` message, stamped in robot time by the sender's `timebase`."""
    pos = np.array(msg.position, dtype=float)  # copies: decoded arrays are read-only views
    vel = np.array(msg.velocity, dtype=float) if len(msg.velocity) else np.zeros_like(pos)
    eff = np.array(msg.effort, dtype=float) if len(msg.effort) else np.zeros_like(pos)
    stamp = timebase.robot(messages.stamp_to_ns(msg.header.stamp)) * 1e-9
    return JointFeedback(stamp, tuple(msg.name), pos, vel, np.full_like(pos, np.nan), eff)


def command_msg(code: int, client: str, arm: str = "", values: Sequence[float] | FloatArray = (),
                joint: str = "", stamp_ns: int | None = None) -> Any:
    """`foldcell_msgs/ControllerCommand` from `client` (its liveliness key, for the lease)."""
    return messages.new(COMMAND_TYPE, header=messages.header(stamp_ns), command=int(code), client=client,
                        arm=arm, joint=joint, values=np.asarray(list(values), dtype=float))


def trajectory_msg(traj: JointTrajectory, stamp_ns: int = 0) -> Any:
    """`trajectory_msgs/JointTrajectory`, the label as header.frame_id, stamped `stamp_ns` (wall; a
    controller queues it after its queue whatever the stamp)."""
    pos = np.ascontiguousarray(traj.positions, dtype=float)  # column slices are not contiguous
    vel = None if traj.velocities is None else np.ascontiguousarray(traj.velocities, dtype=float)
    points = [messages.new("trajectory_msgs/msg/JointTrajectoryPoint", positions=pos[k].copy(),
                           velocities=np.zeros(0) if vel is None else vel[k].copy(),
                           time_from_start=messages.duration_from_s(float(traj.times[k])))
              for k in range(pos.shape[0])]
    return messages.new(TRAJECTORY_TYPE, header=messages.header(stamp_ns, traj.label),
                        joint_names=list(traj.joint_names), points=points)


class MalformedTrajectory(ValueError):
    """The message's arrays do not have one value per joint; `.point` says where."""

    def __init__(self, text: str, point: int):
        super().__init__(text)
        self.point = point


def trajectory_from_msg(msg: Any) -> JointTrajectory:
    """Arrays of a trajectory message; velocities None when no point has any (MotoROS: zero)."""
    names = tuple(msg.joint_names)
    n = len(names)
    k = len(msg.points)
    pos = np.zeros((k, n))
    vel = np.zeros((k, n))
    times = np.zeros(k)
    with_vel = [len(p.velocities) > 0 for p in msg.points]
    for i, p in enumerate(msg.points):
        if len(p.positions) != n:
            raise MalformedTrajectory(f"point {i} has {len(p.positions)} positions for {n} joints", i)
        if any(with_vel) and len(p.velocities) != n:
            raise MalformedTrajectory(f"point {i} has {len(p.velocities)} velocities for {n} joints", i)
        pos[i] = p.positions
        if with_vel[i]:
            vel[i] = p.velocities
        times[i] = messages.duration_to_s(p.time_from_start)
    return JointTrajectory(names, times, pos, vel if any(with_vel) else None, msg.header.frame_id)


def gripper_msg(arm: str, closed: bool, opening: float, pose: np.ndarray, stamp_ns: int) -> Any:
    return messages.new(GRIPPER_TYPE, header=messages.header(stamp_ns, "world"), arm=arm, closed=bool(closed),
                        opening=float(opening), tcp_pose=pose_msg(pose))
