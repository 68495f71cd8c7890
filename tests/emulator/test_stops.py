"""Coordinated stops on the split master/slave processes: hold, stop, lease loss and e-stop keep both arms
on the commanded path (within 1 mrad) and stop them on the same tick, within the joint limits; the
synchronous start holds with a busy process on the controllers' CPU."""

from __future__ import annotations

import os
import subprocess
import sys
import threading

import numpy as np
import pytest

from drivers.controller import codec
from drivers.controller.codes import Command, Result
from drivers.controller.credential import Signer
from drivers.controller.interface import MotionStatus
from drivers.controller.trajectory import JointTrajectory
from drivers.emulator.commands import EmulatorCommand
from drivers.emulator.node import load_server_config
from drivers.wire.messages import ErrorReply, WireError
from drivers.wire.transport import Wire
from tests.conftest import request_once_served, wait_until
from tests.emulator.stop_runs import (
    ARMS,
    KINDS,
    PERIOD,
    RC,
    CommandedPath,
    make_ready,
    master_and_slave,
    run_stop,
    two_arm_trajectory,
)
from tests.emulator.test_process import CFG

DEVIATION_LIMIT = 1e-3  # rad from the coordinated path
FD_SLACK = 0.02  # finite differences of the reported velocity vs the acceleration limit


@pytest.fixture(scope="module")
def split_processes(tmp_path_factory):
    with master_and_slave(tmp_path_factory.mktemp("stops")) as running:
        yield running


@pytest.fixture
def split(split_processes):
    """The module's processes, the tester holding the lease and the robot ready, whatever the test before
    left: one failing half-way (the lease given to a holder process, now killed) fails alone."""
    _, ctl, _, _ = split_processes
    assert ctl.wait_status(lambda s: s.lease_holder in ("", ctl.client), 20), ctl.status()
    ctl.acquire_lease()
    make_ready(ctl)
    return split_processes


@pytest.mark.parametrize("kind", KINDS)
def test_a_stop_keeps_both_arms_on_the_path_and_ends_on_one_tick(split, kind):
    ep, ctl, rec, _ = split
    run = run_stop(kind, ep, ctl, rec)
    assert run.deviation() <= DEVIATION_LIMIT, (kind, run.deviation(), run.worst_sample())
    assert run.stop_tick("R1") == run.stop_tick("R2"), (kind, run.stop_tick("R1"), run.stop_tick("R2"))
    final = run.samples[-1][1]
    assert np.abs(final - run.trajectory.positions[-1]).max() > 0.01, "it stopped at the goal, not on the way"
    assert run.worst_velocity() <= 1.0 + CFG.limit_tolerance
    if kind != "e-stop":  # an e-stop is the brakes: the speed drops to zero at once
        assert run.worst_acceleration() <= 1.0 + FD_SLACK, (kind, run.worst_acceleration())
        assert run.stop_tick("R1") - run.brake_tick() > 1, "a smooth stop took a single tick"


BUSY = "import os, sys\nos.sched_setaffinity(0, {int(sys.argv[1])})\nwhile True:\n    pass\n"


SLOW_REPLY = 2 * load_server_config().sync_lead_time  # s: longer than the synchronous start's lead


@pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="needs CPU affinity (Linux)")
def test_synchronous_start_holds_beside_a_busy_process(split):
    """Master, slave and two busy loops share one CPU, and the controllers' replies come late: every
    two-arm motion still starts both halves on its start tick (each published state is on the path at
    its tick's nominal time)."""
    _, ctl, rec, procs = split
    cpu = min(os.sched_getaffinity(0))
    before = {proc.popen.pid: os.sched_getaffinity(proc.popen.pid) for proc in procs}
    busy = [subprocess.Popen([sys.executable, "-c", BUSY, str(cpu)]) for _ in range(2)]
    try:
        ctl.command(EmulatorCommand.FAULT_REPLY_LATENCY_ON, values=(SLOW_REPLY, 0.05))
        for pid in before:
            os.sched_setaffinity(pid, {cpu})
        home = np.asarray(RC.home, dtype=float)
        for leg in range(4):
            start_q = ctl.joint_state().positions.copy()
            trajectory = two_arm_trajectory(start_q, None if leg % 2 == 0 else home)
            rec.clear()
            handle = ctl.execute(trajectory)
            assert handle.wait(120) == MotionStatus.SUCCEEDED
            start = handle.reply.start_tick
            path = CommandedPath(trajectory)
            samples = [s for s in rec.since(start) if (s[0] - start) * PERIOD <= trajectory.duration]
            assert len(samples) > 10, len(samples)
            for tick, q, _ in samples:
                off = np.abs(q - path.at((tick - start) * PERIOD)).max()
                assert off <= CFG.tracking_tolerance, (leg, tick - start, off)
    finally:   # the busy loops go first: left running, they would slow every test after this one
        for proc in busy:
            proc.kill()
            proc.wait()
        for pid, cpus in before.items():
            os.sched_setaffinity(pid, cpus)
        ctl.command(EmulatorCommand.FAULT_REPLY_LATENCY_OFF)



def test_the_slave_obeys_only_its_master(split):
    """A stranger sends the slave motion, once under its own name and once under the master's with a
    made-up credential: every request is refused and R2 stays where it is (read from the master's
    merged joint stream)."""
    ep, ctl, rec, _ = split
    make_ready(ctl)
    r2 = ARMS["R2"]
    q0 = ctl.joint_state().positions.copy()
    r2_joints = RC.group("R2").joints
    stranger = Wire(ep.settings(), "stranger")
    try:
        for name in ("alive/stranger", "alive/controller-master"):
            signer = Signer(name)
            jog = codec.command_msg(Command.JOG, name, joint=r2_joints[0], values=(0.1,))
            reply = request_once_served(stranger, "controller/slave/command", jog, timeout=5,
                                        sign=signer.attachment)
            assert reply.result != Result.SUCCESS, (name, reply.text)
            own = JointTrajectory(r2_joints, np.array([0.0, 1.0]),
                                  np.stack([q0[r2], q0[r2] + 0.1]), None)
            reply = request_once_served(stranger, "controller/slave/trajectory", codec.trajectory_msg(own),
                                        timeout=5, sign=signer.attachment)
            assert reply.result != Result.SUCCESS, (name, reply.text)
        rec.clear()
        assert wait_until(lambda: len(rec.since(0)) > 100, 20)
        for _, q, _ in rec.since(0):
            np.testing.assert_array_equal(q[r2], q0[r2])
        assert ctl.status().motion_possible, ctl.status()  # the master's link to its slave is intact
    finally:
        stranger.close()


def test_a_flood_at_the_slave_does_not_keep_the_master_s_stop_from_it(split):
    """A stranger floods `controller/slave/command` past its rate limit while a two-arm motion is stopped:
    the master's stop still reaches the slave, and both arms stop on one tick on the path."""
    ep, ctl, rec, _ = split
    stranger = Wire(ep.settings(), "flooder")
    flooding = threading.Event()
    refused = []

    def flood() -> None:
        jog = codec.command_msg(Command.JOG, "alive/flooder", joint=RC.group("R2").joints[0], values=(0.1,))
        while flooding.is_set():
            try:
                stranger.request("controller/slave/command", jog, timeout=2)
            except ErrorReply as exc:
                refused.append(str(exc))
            except WireError:
                pass

    flooding.set()
    flooder = threading.Thread(target=flood, daemon=True)
    flooder.start()
    try:
        assert wait_until(lambda: any("rate limit" in text for text in refused), 30), "never over the limit"
        run = run_stop("stop", ep, ctl, rec)
        assert any("rate limit" in text for text in refused[-20:]), "the flood was not on during the stop"
    finally:
        flooding.clear()
        flooder.join(10)
        stranger.close()
    assert run.deviation() <= DEVIATION_LIMIT, run.deviation()
    assert run.stop_tick("R1") == run.stop_tick("R2"), (run.stop_tick("R1"), run.stop_tick("R2"))
