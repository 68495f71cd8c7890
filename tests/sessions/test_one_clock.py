"""One clock: a time-scaled session (master and slave emulators at 10x, the recorder, a motion of both
arms and a grip) is stamped on the session's own time base. Every header stamp and every publish time
lies within the log times the recorder gave, and robot time is there as data: the status says which
robot time its stamp is, and that runs 10x the stamps. Read with mcap_ros2, which shares no code with
foldcell."""

from __future__ import annotations

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from drivers.controller.codes import Command
from drivers.controller.interface import MotionStatus
from drivers.controller.zenoh_client import ZenohController
from drivers.sessions.mcap.bag import find_session
from drivers.wire.transport import Wire
from tests.conftest import foldcell_argv, wait_until
from tests.emulator.test_process import traj

SCALE = 10.0
SLACK_NS = 300_000_000   # a sample's stamp precedes its receipt by a loop at most, not hours


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_every_stamp_of_a_time_scaled_session_lies_within_its_log_times(endpoint, spawn, tmp_path):
    path = tmp_path / "session"
    serve = ("controller", "serve", "--time-scale", str(SCALE), *endpoint.args())
    spawn(foldcell_argv(*serve, "--role", "master"))
    spawn(foldcell_argv(*serve, "--role", "slave"))
    recorder = spawn(foldcell_argv("log", "record", "-o", str(path), *endpoint.args()))
    with Wire(endpoint.settings(), "tester") as wire:
        assert wait_until(lambda: any("recorder" in k for k in wire.alive()), 30)
        ctl = ZenohController(wire)
        ctl.connect(timeout=30)
        assert wait_until(lambda: all(g.link_ok for g in ctl.status_message().groups), 30)
        ctl.acquire_lease()
        ctl.command(Command.START_TRAJ_MODE)
        assert ctl.wait_status(lambda s: s.motion_possible, 10)
        q0 = ctl.joint_state().positions.copy()
        end = q0.copy()
        end[0] += 0.2    # r1 (master)
        end[6] -= 0.2    # r2 (slave)
        assert ctl.execute(traj(q0, [end], [0.0, 5.0])).wait(30) == MotionStatus.SUCCEEDED
        ctl.grip("r1", True)
        ctl.grip("r1", False)
        ctl.release_lease()
    assert recorder.stop() == 0, recorder.stderr()

    records = []   # (topic, log time, publish time, decoded)
    for file in find_session(path).files:
        with open(file, "rb") as f:
            for _schema, channel, message, decoded in make_reader(
                    f, decoder_factories=[DecoderFactory()]).iter_decoded_messages():
                records.append((channel.topic, message.log_time, message.publish_time, decoded))
    topics = {topic.split("/", 3)[3] for topic, *_ in records}
    assert {"controller/joint_states", "controller/status", "controller/gripper/r1",
            "controller/slave/joint_states", "controller/slave/status"} <= topics, topics
    first = min(log for _, log, _, _ in records) - SLACK_NS
    last = max(log for _, log, _, _ in records) + SLACK_NS
    stamped = 0
    for topic, log_time, publish_time, decoded in records:
        assert first <= publish_time <= last, (topic, publish_time - log_time)
        header = getattr(decoded, "header", None)
        if header is not None:
            stamp = _stamp_ns(header.stamp)
            assert first <= stamp <= last, (topic, (stamp - log_time) / 1e9)
            stamped += 1
    assert stamped > 100

    # robot time is data: the status's robot time runs SCALE x its stamps, exactly a tick's multiple
    statuses = [d for topic, *_, d in records if topic.endswith("/controller/status")]
    (s0, s1) = statuses[0], statuses[-1]
    wall = _stamp_ns(s1.header.stamp) - _stamp_ns(s0.header.stamp)
    assert wall > 300_000_000
    assert abs((s1.robot_time_ns - s0.robot_time_ns) / wall - SCALE) < 1e-6
    assert all(s.robot_time_ns % 4_000_000 == 0 and s.time_scale == SCALE for s in statuses)
