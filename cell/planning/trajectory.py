"""Joint trajectories for the controller: jerk-limited time parameterisation (ruckig).

A `PlannedTrajectory` is the controller contract's `JointTrajectory` (all 13 joints in project order,
exact positions and velocities at each point, as MotoROS wants them) plus what the planner's collision
check allowed; the controller interpolates between points with cubic Hermite splines, which the
contract's `JointTrajectory.dense_positions` reproduces for dense checks. Its point count keeps within
the controller's `max_points`.

Two parameterisations, both synchronising all axes on one time base:
* `ptp_trajectory`: through a few joint waypoints, stopping at each; ruckig with phase
  synchronisation keeps every piece on the straight joint-space segment that the motion planner
  checked.
* `path_trajectory`: along a dense joint path (Cartesian interpolation); the path is a C1 (PCHIP)
  curve q(s) and ruckig plans the path parameter s(t) with limits derived from |q'(s)|, |q''(s)|.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from ruckig import Trajectory
from scipy.interpolate import PchipInterpolator

from cell.planning.errors import PlanningError
from drivers.common.configfile import rule
from drivers.controller.config import ControllerConfig
from drivers.controller.motion import PlanError, rest_to_rest
from drivers.controller.trajectory import JointTrajectory
from drivers.robot.config import RobotConfig


@dataclass(frozen=True)
class TrajectoryParams:
    """config/planning.yaml `trajectory`: how fast the planner moves (the controller's rules are in
    config/controller.yaml)."""

    # s between emitted points (longer moves use a longer one)
    sample_period: float = rule(positive=True)
    velocity_scale: float = rule(positive=True, max=1.0)   # fraction of each joint's max velocity used
    acceleration_scale: float = rule(positive=True, max=1.0)
    jerk_scale: float = rule(positive=True, max=1.0)


@dataclass(frozen=True)
class PlannedTrajectory(JointTrajectory):
    """A trajectory the planner made; `allow_finger_contact`: its collision check let the fingers
    touch the table (grasp, fold and release moves)."""

    allow_finger_contact: bool = False


class Limits:
    """Scaled joint limits used by the planner (the controller checks the full ones), and the
    controller's point limit."""

    def __init__(self, robot: RobotConfig, params: TrajectoryParams, controller: ControllerConfig):
        self.robot = robot
        self.params = params
        self.max_points = controller.max_points
        self.velocity = robot.max_velocity * params.velocity_scale
        self.acceleration = robot.max_acceleration * params.acceleration_scale
        self.jerk = robot.max_jerk * params.jerk_scale


def _sample_times(duration: float, limits: Limits) -> np.ndarray:
    """Sample instants 0..duration with at most max_points points."""
    n = max(2, int(np.ceil(duration / limits.params.sample_period)) + 1)
    n = min(n, limits.max_points)
    return np.linspace(0.0, duration, n)


def _ruckig_rest_to_rest(q0: np.ndarray, q1: np.ndarray, limits: Limits) -> Trajectory:
    try:
        return rest_to_rest(q0, q1, limits.velocity, limits.acceleration, limits.jerk)
    except PlanError as exc:
        raise PlanningError(f"ruckig could not time-parameterise a move: {exc}") from exc


def ptp_trajectory(waypoints: np.ndarray, limits: Limits, label: str = "") -> PlannedTrajectory:
    """Rest-to-rest through each waypoint (M, n), straight in joint space between them."""
    wps = np.asarray(waypoints, dtype=float)
    keep = [0] + [i for i in range(1, len(wps)) if np.max(np.abs(wps[i] - wps[i - 1])) > 1e-9]
    wps = wps[keep]
    if len(wps) < 2:
        wps = np.vstack([wps[0], wps[0]])
        trajs = []
    else:
        trajs = [_ruckig_rest_to_rest(wps[i], wps[i + 1], limits) for i in range(len(wps) - 1)]
    durations = [t.duration for t in trajs]
    total = float(sum(durations))
    if total <= 0.0:
        # a move to where we are: two points, a short hold (the controller needs >= 2 points)
        total = limits.params.sample_period
        times = np.array([0.0, total])
        return PlannedTrajectory(limits.robot.joint_names, times, np.vstack([wps[0], wps[0]]),
                                 np.zeros((2, wps.shape[1])), label)
    times = _sample_times(total, limits)
    # make sure every waypoint (a rest point) is sampled exactly
    bounds = np.cumsum([0.0, *durations])
    times = np.unique(np.concatenate([times, bounds]))
    if len(times) > limits.max_points:
        times = np.unique(np.concatenate([np.linspace(0, total, limits.max_points - len(bounds)), bounds]))
    pos = np.empty((len(times), wps.shape[1]))
    vel = np.empty_like(pos)
    seg = 0
    for k, t in enumerate(times):
        while seg < len(trajs) - 1 and t > bounds[seg + 1]:
            seg += 1
        p, v, _ = trajs[seg].at_time(min(max(t - bounds[seg], 0.0), durations[seg]))
        pos[k], vel[k] = p, v
    pos[-1], vel[-1] = wps[-1], 0.0
    pos[0], vel[0] = wps[0], 0.0
    return PlannedTrajectory(limits.robot.joint_names, times, pos, vel, label)


def path_trajectory(path: np.ndarray, limits: Limits, label: str = "",
                    allow_finger_contact: bool = False) -> PlannedTrajectory:
    """Time-parameterise a dense joint path (N, n) from rest to rest, following it closely."""
    Q = np.asarray(path, dtype=float)
    keep = [0] + [i for i in range(1, len(Q)) if np.linalg.norm(Q[i] - Q[i - 1]) > 1e-7]
    Q = Q[keep]
    if len(Q) < 3:
        return replace(ptp_trajectory(Q, limits, label), allow_finger_contact=allow_finger_contact)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(Q, axis=0), axis=1))])
    L = float(s[-1])
    curve = PchipInterpolator(s, Q, axis=0)
    d1 = curve.derivative(1)
    d2 = curve.derivative(2)
    ss = np.linspace(0.0, L, 4 * len(Q))
    q1 = np.max(np.abs(d1(ss)), axis=0) + 1e-9
    q2 = np.max(np.abs(d2(ss)), axis=0) + 1e-9
    v_s = float(np.min(limits.velocity / q1))
    v_s = min(v_s, float(np.min(np.sqrt(0.5 * limits.acceleration / q2))))
    a_s = float(np.min(0.5 * limits.acceleration / q1))
    j_s = float(np.min(0.3 * limits.jerk / q1))
    try:   # the path parameter s, from rest at 0 to rest at L
        traj = rest_to_rest(np.zeros(1), np.array([L]), np.array([v_s]), np.array([a_s]), np.array([j_s]))
    except PlanError as exc:
        raise PlanningError(f"ruckig could not time-parameterise path {label!r}: {exc}") from exc
    times = _sample_times(traj.duration, limits)
    pos = np.empty((len(times), Q.shape[1]))
    vel = np.empty_like(pos)
    for k, t in enumerate(times):
        p, v, _ = traj.at_time(float(t))
        sk = min(max(p[0], 0.0), L)
        pos[k] = curve(sk)
        vel[k] = d1(sk) * v[0]
    pos[0], vel[0] = Q[0], 0.0
    pos[-1], vel[-1] = Q[-1], 0.0
    return PlannedTrajectory(limits.robot.joint_names, times, pos, vel, label, allow_finger_contact)


__all__ = ["Limits", "PlannedTrajectory", "TrajectoryParams", "path_trajectory", "ptp_trajectory"]
