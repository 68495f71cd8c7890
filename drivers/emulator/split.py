"""Master/slave as pure logic: split a cell trajectory by controller, merge feedback, watch the link.

The Zenoh wrapper of the master does, for a 13-joint trajectory:
1. `master.check(...)`-like validation of the whole trajectory (`check_trajectory` over all joints with
   the merged current position), so a bad trajectory is refused before anything is forwarded;
2. `split_trajectory` -> the master's part and the slave's part;
3. forward the whole trajectory: the slave pre-loads its columns (no start tick yet, so its reply may
   come as late as it likes); then pick a common start tick `common_start_tick(...)` `sync_lead_time`
   ahead, queue the master's part on it and RELEASE the slave's on it: both groups start on the same
   interpolation tick of the shared robot time, whenever the replies arrive;
4. `merge_feedback` / `merge_status` the two cores' outputs into one `controller/joint_states`;
5. feed `LinkMonitor` with every slave sample; when it reports loss, `master.link_lost("slave")`.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np

from drivers.controller.interface import ControllerStatus, JointFeedback
from drivers.controller.trajectory import JointTrajectory
from drivers.robot.config import RobotConfig


def joints_of(robot_config: RobotConfig, owners: dict[str, str], role: str) -> tuple[str, ...]:
    """The joints (project order) of the groups `role` owns; `owners` maps group -> master/slave."""
    owned = {j for g in robot_config.groups if owners.get(g.name, g.controller) == role for j in g.joints}
    return tuple(j for j in robot_config.joint_names if j in owned)


def split_trajectory(robot_config: RobotConfig, owners: dict[str, str],
                     trajectory: JointTrajectory) -> dict[str, JointTrajectory]:
    """Split a trajectory over all joints into {'master': its columns, 'slave': its columns} (a role
    without joints is left out). Raises ValueError naming a joint that is not the cell's."""
    names = list(trajectory.joint_names)
    pos = np.asarray(trajectory.positions, dtype=float)
    vel = None if trajectory.velocities is None else np.asarray(trajectory.velocities, dtype=float)
    parts = {}
    for role in ("master", "slave"):
        mine = joints_of(robot_config, owners, role)
        if not mine:
            continue
        try:
            cols = [names.index(j) for j in mine]
        except ValueError as exc:
            raise ValueError(f"joint_names: {exc.args[0].split()[0]} of the {role} is missing") from exc
        parts[role] = JointTrajectory(mine, np.asarray(trajectory.times, dtype=float), pos[:, cols],
                                      None if vel is None else vel[:, cols], trajectory.label)
    unknown = [j for j in names if j not in robot_config.joint_names]
    if unknown:
        raise ValueError(f"joint_names: unknown joint {unknown[0]!r}")
    return parts


def common_start_tick(now_tick: int, master_end_tick: int, slave_end_tick: int, lead_ticks: int) -> int:
    """The first tick both controllers can start on: after both queues and `lead_ticks` ahead of now
    (the time the forward and the slave's acceptance take)."""
    return max(now_tick + lead_ticks, master_end_tick, slave_end_tick)


def merge_feedback(robot_config: RobotConfig, parts: Sequence[JointFeedback]) -> JointFeedback:
    """One joint state over all joints (project order) from the controllers' samples.

    The stamp is the oldest part's (the merged sample is only as new as its oldest part). Raises
    ValueError if a joint is missing or given twice.
    """
    names = robot_config.joint_names
    n = len(names)
    arrays = {k: np.full(n, np.nan) for k in ("p", "v", "a", "e")}
    seen = np.zeros(n, dtype=bool)
    for fb in parts:
        idx = _indices(robot_config, fb.joint_names)
        if seen[idx].any():
            raise ValueError(f"merge_feedback: joint {names[int(idx[seen[idx]][0])]} given twice")
        seen[idx] = True
        arrays["p"][idx] = fb.positions
        arrays["v"][idx] = fb.velocities
        arrays["a"][idx] = fb.accelerations
        arrays["e"][idx] = fb.efforts
    if not seen.all():
        raise ValueError(f"merge_feedback: joint {names[int(np.argmin(seen))]} is missing")
    stamp = min(fb.stamp for fb in parts)
    return JointFeedback(stamp, names, arrays["p"], arrays["v"], arrays["a"], arrays["e"])


@lru_cache(maxsize=16)
def _indices(robot_config: RobotConfig, joint_names: tuple[str, ...]) -> np.ndarray:
    """Where `joint_names` sit in the project order (a merge at 250 Hz looks them up once)."""
    idx = np.array([robot_config.index(j) for j in joint_names], dtype=int)
    idx.setflags(write=False)
    return idx


def merge_status(robot_config: RobotConfig, parts: Sequence[ControllerStatus]) -> ControllerStatus:
    """One status with every group (in `robot/joints.yaml` order), every active fault, the stalls of
    every loop; lease holder and note from the master (first)."""
    groups = {g.name: g for st in parts for g in st.groups}
    ordered = tuple(groups[g.name] for g in robot_config.groups if g.name in groups)
    holder = next((st.lease_holder for st in parts if st.lease_holder), "")
    faults = tuple(dict.fromkeys(fault for st in parts for fault in st.faults))
    return ControllerStatus(min(st.stamp for st in parts), ordered, holder, faults,
                            lease_note=parts[0].lease_note if parts else "",
                            loop_stalls=sum(st.loop_stalls for st in parts))


class LinkMonitor:
    """Declares a peer lost when no sample arrived for `timeout` s of robot time (once per loss)."""

    def __init__(self, timeout: float, now: float = 0.0):
        if timeout <= 0:
            raise ValueError(f"timeout must be > 0, got {timeout}")
        self.timeout = timeout
        self.last_heard = now
        self.lost = False

    def heard(self, now: float) -> None:
        """A sample from the peer arrived at robot time `now`."""
        self.last_heard = now
        self.lost = False

    def check(self, now: float) -> bool:
        """True exactly once when the link has just been declared lost."""
        if not self.lost and now - self.last_heard > self.timeout:
            self.lost = True
            return True
        return False
