"""Joint trajectories played into the simulated world as a controller moves the arms and the camera
process hears them, with no processes and no wire (how `cell.evaluation.sim_fold` folds in the
physics world).

Between a trajectory's points the joints move as the controller moves them: MotoROS' cubic Hermite
interpolation (`drivers.controller.trajectory.sample`), as the emulator streams its joint states.
What the world is told of a joint state is what the camera process tells it (`drivers.sim.node`):
where the grippers' TCPs are, by forward kinematics (`tcp_positions`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np

from drivers.controller.trajectory import JointTrajectory, sample
from drivers.robot.kinematics import CellKinematics
from drivers.sim.world import GarmentWorld


def tcp_positions(kinematics: CellKinematics, q: np.ndarray) -> dict[str, np.ndarray]:
    """Every arm's TCP position (m, world) at joints `q`."""
    return {arm: pose[:3, 3] for arm, pose in kinematics.tcp_poses(q).items()}


class TrajectoryPlayer:
    """Plays trajectories and gripper actions into `world` as the controller and the camera process
    would: the grippers' events at their times, the joint states (every `joint_state_period` s of
    robot time, interpolated as the controller does, or at the trajectory's points) as TCP positions,
    the grippers' stream (events, and every gripper's state heard at each joint state)
    `gripper_delay` s behind the joint states, the world simulating what it heard every
    `catch_up_period` s (or when asked). `speed` scales the trajectories' timing (2: twice as fast);
    `clock` is the robot time played so far."""

    def __init__(self, world: GarmentWorld, kinematics: CellKinematics, speed: float = 1.0,
                 joint_state_period: float | None = None, catch_up_period: float | None = None,
                 gripper_delay: float = 0.0):
        self.world, self.kinematics = world, kinematics
        self.speed, self.joint_state_period, self.catch_up_period = speed, joint_state_period, catch_up_period
        self.gripper_delay = gripper_delay
        self.gripper_stream: list[tuple[float, Callable[[], object]]] = []   # (robot time, delivery)
        self.clock = self.looked_at = 0.0

    def gripper(self, arm: str, close: bool, q: np.ndarray) -> None:
        """Gripper `arm` closes (or opens) now, the arms at joints `q`."""
        tcp = self.kinematics.tcp_pose(q, arm)[:3, 3]
        self._send_gripper(self.clock, functools.partial(
            self.world.gripper_event, arm, close, tcp, robot_time=self.clock))

    def trajectory(self, trajectory: JointTrajectory) -> np.ndarray:
        """Play `trajectory` from now; the joints at its end."""
        times = np.asarray(trajectory.times, dtype=float) / self.speed
        positions_at = np.asarray(trajectory.positions, dtype=float)
        if self.joint_state_period is not None:
            heard = np.append(np.arange(0.0, times[-1], self.joint_state_period), times[-1])
            # played `speed` times as fast: the same path, its velocities `speed` times as high
            positions_at, _, _ = sample(times, positions_at, trajectory.point_velocities * self.speed, heard)
            times = heard
        q = positions_at[-1]
        for at, positions in zip(times, positions_at, strict=True):
            now = self.clock + float(at)
            tcps = tcp_positions(self.kinematics, positions)
            self.world.gripper_motion(now, tcps)
            for arm in tcps:
                self._send_gripper(now, functools.partial(self.world.gripper_heard, arm, now))
            self._deliver(now - self.gripper_delay)
            if self.catch_up_period is not None and now >= self.looked_at + self.catch_up_period:
                self.world.catch_up()
                self.looked_at = now
        self.clock += float(times[-1])
        return q

    def flush(self) -> None:
        """Deliver what is left of the grippers' stream (the end of a motion)."""
        self._deliver(math.inf)

    def _send_gripper(self, when: float, delivery: Callable[[], object]) -> None:
        self.gripper_stream.append((when, delivery))
        self._deliver(self.clock - self.gripper_delay if self.gripper_delay else math.inf)

    def _deliver(self, until: float) -> None:
        """Deliver the grippers' stream, in order, up to robot time `until`."""
        while self.gripper_stream and self.gripper_stream[0][0] <= until:
            self.gripper_stream.pop(0)[1]()
