"""MotoROS result codes, subcodes and command codes, plus foldcell's own commands and alarms.

MotoROS values come from `shared/facts/dx100.md` (`MOTO_MOTION_REPLY`, `MOTO_MOTION_CTRL`); the
foldcell additions live in ranges MotoROS does not use (commands 3000xx, subcodes 9xxx, alarms 4xxx).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum


class Readable(IntEnum):
    @property
    def text(self) -> str:
        """Readable name, e.g. `DATA_START_POS` -> `data start pos`."""
        return self.name.lower().replace("_", " ")


class Result(Readable):
    """`MOTO_MOTION_REPLY.result`."""

    SUCCESS = 0
    BUSY = 1  # queue full: retry later
    FAILURE = 2
    INVALID = 3
    ALARM = 4
    NOT_READY = 5
    MP_FAILURE = 6


class Subcode(Readable):
    """`MOTO_MOTION_REPLY.subcode`: INVALID 3xxx and NOT_READY 5xxx from MotoROS, 9xxx foldcell's."""

    NONE = 0
    INVALID_UNSPECIFIED = 3000
    INVALID_MSGSIZE = 3001
    INVALID_MSGHEADER = 3002
    INVALID_MSGTYPE = 3003
    INVALID_GROUPNO = 3004
    INVALID_SEQUENCE = 3005
    INVALID_COMMAND = 3006
    INVALID_DATA = 3010
    INVALID_DATA_START_POS = 3011
    INVALID_DATA_POSITION = 3012
    INVALID_DATA_SPEED = 3013
    INVALID_DATA_ACCEL = 3014
    INVALID_DATA_INSUFFICIENT = 3015
    INVALID_DATA_TIME = 3016
    INVALID_DATA_TOOLNO = 3017
    NOT_READY_UNSPECIFIED = 5000
    NOT_READY_ALARM = 5001
    NOT_READY_ERROR = 5002
    NOT_READY_ESTOP = 5003
    NOT_READY_NOT_PLAY = 5004
    NOT_READY_NOT_REMOTE = 5005
    NOT_READY_SERVO_OFF = 5006
    NOT_READY_HOLD = 5007
    NOT_READY_NOT_STARTED = 5008
    NOT_READY_WAITING_ROS = 5009
    NOT_READY_SKILLSEND = 5010
    NOT_READY_PFL_ACTIVE = 5011
    # foldcell: control lease (FAILURE replies)
    LEASE_HELD = 9001  # another session holds the lease
    NO_LEASE = 9002  # the sender does not hold the lease (lease required)
    # foldcell: a command argument is wrong (INVALID replies)
    BAD_ARGUMENT = 9010
    # foldcell: the planner of move-to failed (FAILURE replies)
    PLAN_FAILED = 9020


class Command(Readable):
    """Commands on `controller/command`: MotoROS `MOTO_MOTION_CTRL` codes and foldcell's own."""

    CHECK_MOTION_READY = 200101
    CHECK_QUEUE_CNT = 200102
    STOP_MOTION = 200111  # decelerate along the path within limits, drop the queue
    START_SERVOS = 200112
    STOP_SERVOS = 200113
    RESET_ALARM = 200114
    START_TRAJ_MODE = 200121  # servo on + trajectory mode, as MotoROS does
    STOP_TRAJ_MODE = 200122
    DISCONNECT = 200130
    # foldcell
    ESTOP = 300001
    ESTOP_RESET = 300002
    HOLD = 300003
    RESUME = 300004
    GRIP_OPEN = 300010  # arg: arm
    GRIP_CLOSE = 300011  # arg: arm
    MOVE_TO = 300020  # values: target joint positions (rad) of the joints this controller owns
    JOG = 300021  # joint: name, values: (delta rad): a move_to that changes one joint
    LEASE_ACQUIRE = 300030
    LEASE_RELEASE = 300031
    LEASE_RENEW = 300032  # the holder is still there (sent every lease.silence_timeout / 4)


# Commands that move the robot or change what it may do: they need the control lease; an e-stop does
# not (anyone may stop the robot). A controller may guard more of its own (the emulator's fault
# injection and pendant: drivers/emulator/commands.py).
MOTION_COMMANDS = frozenset({
    Command.STOP_MOTION, Command.START_SERVOS, Command.STOP_SERVOS, Command.RESET_ALARM,
    Command.START_TRAJ_MODE, Command.STOP_TRAJ_MODE, Command.HOLD, Command.RESUME,
    Command.GRIP_OPEN, Command.GRIP_CLOSE, Command.MOVE_TO, Command.JOG, Command.ESTOP_RESET,
})


class Alarm(Readable):
    """Alarm codes raised by the emulator (the DX100 shows 4-digit alarm numbers)."""

    NONE = 0
    LIMIT_EXCEEDED = 4100  # a commanded value would leave a limit: clamped
    SLAVE_LINK_LOST = 4200
    MASTER_LINK_LOST = 4201
    LEASE_LOST = 4300  # the commanding client disappeared
    INJECTED = 4900


class Mode(Readable):
    """`ROBOT_STATUS.mode`."""

    UNKNOWN = -1
    MANUAL = 1  # TEACH
    AUTO = 2  # PLAY


@dataclass(frozen=True)
class Reply:
    """A controller's answer (`foldcell_msgs/MotionReply`): which rule failed, at which point and joint."""

    result: int
    subcode: int = 0
    text: str = ""
    point: int = -1  # trajectory point index, -1 if none
    joint: str = ""  # joint name, '' if none
    trajectory_id: int = 0  # id given to an accepted trajectory, 0 otherwise
    start_tick: int = 0  # interpolation tick an accepted trajectory starts on, 0 otherwise

    @property
    def ok(self) -> bool:
        return self.result == Result.SUCCESS

    def describe(self) -> str:
        """`INVALID/INVALID_DATA_SPEED (3/3013): <text>` for logs and the CLI."""
        try:
            r = Result(self.result).name
        except ValueError:
            r = str(self.result)
        try:
            s = Subcode(self.subcode).name
        except ValueError:
            s = str(self.subcode)
        return f"{r}/{s} ({self.result}/{self.subcode}): {self.text}"


OK = Reply(Result.SUCCESS, Subcode.NONE, "ok")
