"""`LocalController`: the `Controller` interface over an in-process emulator core, with no Zenoh.

Deterministic: robot time advances only inside `wait()` and `advance()`, one interpolation tick at a
time, so cell and state-machine tests can drive a "robot" without threads, sockets or wall-clock
waits. Timeouts here are robot seconds. The Zenoh client (`foldcell controller serve` + its client)
has the same semantics with wall-clock timeouts.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from drivers.controller.codes import Command
from drivers.controller.config import ControllerConfig, default_controller_config
from drivers.controller.errors import raise_for_reply
from drivers.controller.interface import (
    Controller,
    ControllerStatus,
    JointFeedback,
    MotionStatus,
    PolledMotionHandle,
)
from drivers.controller.trajectory import FloatArray, JointTrajectory
from drivers.emulator.core import ControllerCore
from drivers.robot.config import RobotConfig, default_robot_config


class LocalMotionHandle(PolledMotionHandle):
    """An accepted trajectory on a `LocalController`; `wait` steps the core."""

    def __init__(self, owner: LocalController, trajectory_id: int, goal: FloatArray):
        super().__init__(owner.stop, trajectory_id, goal)
        self._owner = owner

    def _poll(self) -> MotionStatus | None:
        if self._result is not None:
            return self._result
        core = self._owner.core
        if self.trajectory_id in core.queued_ids:
            return None
        at_goal = (np.abs(core.q - self.goal) <= core.config.goal_tolerance).all() and not core.v.any()
        if self._cancelled:
            self._result = MotionStatus.CANCELLED
        else:
            self._result = MotionStatus.SUCCEEDED if at_goal else MotionStatus.ABORTED
        return self._result

    def wait(self, timeout: float | None = None) -> MotionStatus:
        """Step robot time until the motion ends or `timeout` robot seconds pass (None: until it ends;
        a held motion then waits forever, so pass a timeout when holds are possible)."""
        core = self._owner.core
        end = None if timeout is None else core.stamp + timeout
        while (result := self._poll()) is None:
            if end is not None and core.stamp >= end:
                return MotionStatus.RUNNING
            core.step()
        return result


class LocalController(Controller):
    """The emulator core behind the `Controller` interface; one session `session` commands it."""

    def __init__(self, robot_config: RobotConfig | None = None, config: ControllerConfig | None = None,
                 session: str = "local", initial_position: Sequence[float] | None = None):
        super().__init__()
        self.robot_config = robot_config or default_robot_config()
        self.config = config or default_controller_config()
        self.session = session
        self.core = ControllerCore(self.robot_config, self.config, "both", initial_position)

    # life cycle
    def connect(self) -> None:
        self._connected = True

    def disconnect(self) -> None:
        if self._connected:
            self.core.lease_lost(self.session)
            self._connected = False

    # lease
    def acquire_lease(self) -> None:
        self._check()
        raise_for_reply(self.core.command(Command.LEASE_ACQUIRE, self.session))

    def release_lease(self) -> None:
        self._check()
        raise_for_reply(self.core.command(Command.LEASE_RELEASE, self.session))

    # motion
    def execute(self, trajectory: JointTrajectory) -> LocalMotionHandle:
        self._check()
        reply = raise_for_reply(self.core.submit(trajectory, self.session))
        return LocalMotionHandle(self, reply.trajectory_id, np.asarray(trajectory.positions)[-1].copy())

    def move_to(self, q: FloatArray) -> LocalMotionHandle:
        self._check()
        reply = raise_for_reply(self.core.move_to(q, self.session))
        return LocalMotionHandle(self, reply.trajectory_id, np.asarray(q, dtype=float).copy())

    def stop(self) -> None:
        self._check()
        raise_for_reply(self.core.command(Command.STOP_MOTION, self.session))

    def command(self, code: int, arm: str = "", values: Sequence[float] = (), joint: str = "") -> None:
        self._check()
        raise_for_reply(self.core.command(code, self.session, arm, values, joint))

    def grip(self, arm: str, closed: bool) -> None:
        self.command(Command.GRIP_CLOSE if closed else Command.GRIP_OPEN, arm=arm)

    # state
    def gripper_states(self) -> dict[str, bool]:
        self._check()
        return dict(self.core.grippers)

    def status(self) -> ControllerStatus:
        self._check()
        return self.core.status()

    def fresh_status(self, timeout: float) -> ControllerStatus:
        return self.status()   # read from the core at the call: fresh already

    def joint_state(self) -> JointFeedback:
        self._check()
        return self.core.feedback()

    def advance(self, seconds: float) -> None:
        """Let `seconds` of robot time pass."""
        self._check()
        self.core.run_until(self.core.stamp + seconds)
