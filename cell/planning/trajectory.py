"""Joint trajectories: jerk-limited time parameterisation (ruckig), sampling, and the controller's rules.

A `JointTrajectory` holds all 13 joints (project order) sampled at points with exact positions and
velocities, as MotoROS wants them; the controller interpolates between points with cubic Hermite
splines, which `hermite_sample` reproduces for dense checks.

Two parameterisations, both synchronising all axes on one time base:
* `ptp_trajectory`: through a few joint waypoints, stopping at each; ruckig with phase
  synchronisation keeps every piece on the straight joint-space segment that the motion planner
  checked.
* `path_trajectory`: along a dense joint path (Cartesian interpolation); the path is a C1 (PCHIP)
  curve q(s) and ruckig plans the path parameter s(t) with limits derived from |q'(s)|, |q''(s)|.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory
from scipy.interpolate import PchipInterpolator

from cell.planning.errors import InvalidTrajectory, PlanningError
from drivers.robot.config import RobotConfig


@dataclass(frozen=True)
class TrajectoryParams:
    """config/planning.yaml `trajectory`."""

    sample_period: float         # s between emitted points (longer moves use a longer one)
    max_points: int              # controller limit per trajectory
    velocity_scale: float        # fraction of each joint's max velocity used by the planner
    acceleration_scale: float
    jerk_scale: float
    start_tolerance: float       # rad: first point vs current position
    velocity_tolerance: float    # relative slack on implied velocities
    interpolation_period: float  # s, the controller's interpolation tick (dense checks)


@dataclass(frozen=True)
class JointTrajectory:
    """Time-stamped points for all joints. positions/velocities (K, n), times (K,) from 0 s."""

    joint_names: tuple[str, ...]
    positions: np.ndarray
    velocities: np.ndarray
    times: np.ndarray
    label: str = ""
    allow_finger_contact: bool = field(default=False)

    @property
    def duration(self) -> float:
        return float(self.times[-1])

    def to_msg_dict(self) -> dict:
        """Plain data for trajectory_msgs/JointTrajectory (the wire layer encodes it)."""
        return {
            "joint_names": list(self.joint_names),
            "points": [
                {"positions": self.positions[k].tolist(), "velocities": self.velocities[k].tolist(),
                 "time_from_start": float(self.times[k])}
                for k in range(len(self.times))
            ],
        }


class Limits:
    """Scaled joint limits used by the planner (the controller checks the full ones)."""

    def __init__(self, robot: RobotConfig, params: TrajectoryParams):
        self.robot = robot
        self.params = params
        self.lower = robot.lower
        self.upper = robot.upper
        self.velocity = robot.max_velocity * params.velocity_scale
        self.acceleration = robot.max_acceleration * params.acceleration_scale
        self.jerk = robot.max_jerk * params.jerk_scale


def _sample_times(duration: float, params: TrajectoryParams) -> np.ndarray:
    """Sample instants 0..duration with at most max_points points."""
    n = max(2, int(np.ceil(duration / params.sample_period)) + 1)
    n = min(n, params.max_points)
    return np.linspace(0.0, duration, n)


def _ruckig_rest_to_rest(q0: np.ndarray, q1: np.ndarray, limits: Limits) -> Trajectory:
    n = len(q0)
    otg = Ruckig(n)
    inp = InputParameter(n)
    inp.current_position = q0.tolist()
    inp.current_velocity = [0.0] * n
    inp.current_acceleration = [0.0] * n
    inp.target_position = q1.tolist()
    inp.target_velocity = [0.0] * n
    inp.target_acceleration = [0.0] * n
    inp.max_velocity = limits.velocity.tolist()
    inp.max_acceleration = limits.acceleration.tolist()
    inp.max_jerk = limits.jerk.tolist()
    inp.synchronization = Synchronization.Phase
    traj = Trajectory(n)
    res = otg.calculate(inp, traj)
    if res not in (Result.Working, Result.Finished):
        raise PlanningError(f"ruckig could not time-parameterise a move: {res}")
    return traj


def ptp_trajectory(waypoints: np.ndarray, limits: Limits, label: str = "") -> JointTrajectory:
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
        return JointTrajectory(limits.robot.joint_names, np.vstack([wps[0], wps[0]]),
                               np.zeros((2, wps.shape[1])), times, label)
    times = _sample_times(total, limits.params)
    # make sure every waypoint (a rest point) is sampled exactly
    bounds = np.cumsum([0.0] + durations)
    times = np.unique(np.concatenate([times, bounds]))
    if len(times) > limits.params.max_points:
        times = np.unique(np.concatenate([np.linspace(0, total, limits.params.max_points - len(bounds)), bounds]))
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
    return JointTrajectory(limits.robot.joint_names, pos, vel, times, label)


def path_trajectory(path: np.ndarray, limits: Limits, label: str = "",
                    allow_finger_contact: bool = False) -> JointTrajectory:
    """Time-parameterise a dense joint path (N, n) from rest to rest, following it closely."""
    Q = np.asarray(path, dtype=float)
    keep = [0] + [i for i in range(1, len(Q)) if np.linalg.norm(Q[i] - Q[i - 1]) > 1e-7]
    Q = Q[keep]
    if len(Q) < 3:
        return ptp_trajectory(Q, limits, label)
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
    otg = Ruckig(1)
    inp = InputParameter(1)
    inp.current_position, inp.current_velocity, inp.current_acceleration = [0.0], [0.0], [0.0]
    inp.target_position, inp.target_velocity, inp.target_acceleration = [L], [0.0], [0.0]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v_s], [a_s], [j_s]
    traj = Trajectory(1)
    res = otg.calculate(inp, traj)
    if res not in (Result.Working, Result.Finished):
        raise PlanningError(f"ruckig could not time-parameterise path {label!r}: {res}")
    times = _sample_times(traj.duration, limits.params)
    pos = np.empty((len(times), Q.shape[1]))
    vel = np.empty_like(pos)
    for k, t in enumerate(times):
        p, v, _ = traj.at_time(float(t))
        sk = min(max(p[0], 0.0), L)
        pos[k] = curve(sk)
        vel[k] = d1(sk) * v[0]
    pos[0], vel[0] = Q[0], 0.0
    pos[-1], vel[-1] = Q[-1], 0.0
    return JointTrajectory(limits.robot.joint_names, pos, vel, times, label, allow_finger_contact)


def hermite_sample(traj: JointTrajectory, period: float) -> np.ndarray:
    """Positions (M, n) as the controller interpolates them (cubic Hermite), every `period` s."""
    out = [traj.positions[:1]]
    for k in range(len(traj.times) - 1):
        T = traj.times[k + 1] - traj.times[k]
        p0, p1 = traj.positions[k], traj.positions[k + 1]
        v0, v1 = traj.velocities[k], traj.velocities[k + 1]
        m = max(1, int(np.ceil(T / period)))
        tau = (np.arange(1, m + 1) / m * T)[:, None]
        a1 = 6 * (p1 - p0) / T**2 - 2 * (v1 + 2 * v0) / T
        a2 = -12 * (p1 - p0) / T**3 + 6 * (v1 + v0) / T**2
        out.append(p0 + v0 * tau + a1 * tau**2 / 2 + a2 * tau**3 / 6)
    return np.vstack(out)


def check_trajectory(traj: JointTrajectory, robot: RobotConfig, current: np.ndarray | None,
                     params: TrajectoryParams) -> None:
    """Raise InvalidTrajectory if the controller (MotoROS rules) would reject `traj`."""
    names = robot.joint_names
    if tuple(traj.joint_names) != names:
        raise InvalidTrajectory(f"joint_names must be the {len(names)} project joints in order, got {traj.joint_names}")
    P, V, t = np.asarray(traj.positions), np.asarray(traj.velocities), np.asarray(traj.times)
    K = len(t)
    if K < 2:
        raise InvalidTrajectory(f"needs at least 2 points, got {K}")
    if K > params.max_points:
        raise InvalidTrajectory(f"{K} points, the controller takes at most {params.max_points}")
    if P.shape != (K, len(names)) or V.shape != (K, len(names)):
        raise InvalidTrajectory(f"positions and velocities must be ({K}, {len(names)}), got {P.shape}, {V.shape}")
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(V)) and np.all(np.isfinite(t))):
        raise InvalidTrajectory("non-finite value in positions, velocities or times")
    if t[0] != 0.0 or np.any(np.diff(t) <= 0.0):
        raise InvalidTrajectory("time_from_start must start at 0 and increase strictly")
    lo, hi = robot.lower, robot.upper
    bad = np.argwhere((P < lo - 1e-9) | (P > hi + 1e-9))
    if len(bad):
        k, j = bad[0]
        raise InvalidTrajectory(f"point {k}: {names[j]} = {P[k, j]:.4f} outside [{lo[j]:.4f}, {hi[j]:.4f}]")
    vmax = robot.max_velocity * (1.0 + params.velocity_tolerance)
    bad = np.argwhere(np.abs(V) > vmax)
    if len(bad):
        k, j = bad[0]
        raise InvalidTrajectory(f"point {k}: {names[j]} velocity {V[k, j]:.3f} above {robot.max_velocity[j]:.3f}")
    implied = np.abs(np.diff(P, axis=0)) / np.diff(t)[:, None]
    bad = np.argwhere(implied > vmax)
    if len(bad):
        k, j = bad[0]
        raise InvalidTrajectory(f"points {k}-{k + 1}: {names[j]} implied velocity {implied[k, j]:.3f} above limit")
    if np.any(V[-1] != 0.0):
        raise InvalidTrajectory("last point must have zero velocity")
    if current is not None:
        err = np.max(np.abs(P[0] - np.asarray(current)))
        if err > params.start_tolerance:
            raise InvalidTrajectory(f"first point is {err:.4f} rad from the current position")


__all__ = ["JointTrajectory", "Limits", "TrajectoryParams", "check_trajectory", "hermite_sample",
           "path_trajectory", "ptp_trajectory"]
