"""What a SIGKILLed recorder loses, measured against the publisher's own record of what it sent and when.

A publisher in this process sends, at a fixed rate, numbered `cell/log` lines (a reliable key: none is
dropped on the way) beside a 13-joint `controller/joint_states` stream, the load of a running cell. The
recorder (`foldcell log record`, its own process) is killed with SIGKILL while they flow; `foldcell log
recover` turns its file into a valid one, read back with the `mcap` reader (no foldcell code). The loss
is the span from the first line sent before the kill that is missing from the file to the kill, and the
count of lines sent before the kill that are missing. The recorder's CPU share while recording is read
from /proc. Used by tests/sessions/test_recorder.py and the `recorder` bench.
"""

from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from drivers.sessions.mcap.bag import find_session
from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.conftest import REPO, Endpoint, foldcell_argv, wait_until

LINE_KEY = "cell/log"
LOAD_KEY = "controller/joint_states"
JOINTS = 13
RATE_HZ = 250.0             # the controller's feedback rate (config/controller.yaml)
START_TIMEOUT_S = 60.0


@dataclass(frozen=True)
class KillLoss:
    seconds: float          # from the first line missing to the kill (0: nothing sent before it is missing)
    lines: int              # lines sent before the kill that are not in the recovered file
    sent: int               # lines sent before the kill
    cpu_share: float        # the recorder's CPU time per wall second while recording (1.0: one core)


class NumberedPublisher:
    """Sends line n (its text is n) and a joint state every 1/rate s, noting when each line was sent."""

    def __init__(self, wire: Wire, rate_hz: float):
        self.period = 1.0 / rate_hz
        self.lines = wire.publisher(LINE_KEY)
        self.load = wire.publisher(LOAD_KEY)
        self.sent_at: list[float] = []      # when Zenoh had taken line i + 1 (monotonic)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="numbered-publisher", daemon=True)

    def _run(self) -> None:
        names = [f"joint_{i}" for i in range(JOINTS)]
        next_tick = time.monotonic()
        while not self.stop.is_set():
            number = len(self.sent_at) + 1
            joints = messages.new("sensor_msgs/msg/JointState", header=messages.header(), name=names,
                                  position=[0.001 * number] * JOINTS, velocity=[0.0] * JOINTS,
                                  effort=[0.0] * JOINTS)
            line = messages.new("rcl_interfaces/msg/Log", stamp=messages.stamp_now(), level=20,
                                name="numbered", msg=str(number))
            self.lines.put(line)
            self.sent_at.append(time.monotonic())
            self.load.put(joints)
            next_tick += self.period
            delay = next_tick - time.monotonic()
            if delay > 0:
                self.stop.wait(delay)

    def sent_before(self, moment: float) -> list[float]:
        return [t for t in list(self.sent_at) if t < moment]


def cpu_seconds(pid: int) -> float:
    """User and system CPU time of a process so far (/proc/<pid>/stat)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def numbers_in(path: Path) -> list[int]:
    """The line numbers in a (recovered) session file, in file order, read by the `mcap` reader."""
    numbers = []
    for file in find_session(path).files:
        with open(file, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            numbers += [int(m.decoded_message.msg) for m in reader.iter_decoded_messages()
                        if m.channel.topic.endswith("/" + LINE_KEY)]
    return numbers


def kill_recorder_once(endpoint: Endpoint, directory: Path, record_s: float, name: str = "killed",
                       rate_hz: float = RATE_HZ) -> KillLoss:
    """Record for `record_s` seconds of publishing, SIGKILL the recorder, recover and count the loss."""
    path = directory / f"{name}.mcap"
    with open(directory / f"{name}.log", "wb") as err:
        recorder = subprocess.Popen(foldcell_argv("log", "record", "-o", str(path), *endpoint.args()),
                                    cwd=REPO, stdout=subprocess.DEVNULL, stderr=err)
    try:
        with Wire(endpoint.settings(), f"numbered-{name}") as wire:
            if not wait_until(lambda: any("recorder" in k for k in wire.alive()), START_TIMEOUT_S):
                raise RuntimeError("the recorder did not start")
            publisher = NumberedPublisher(wire, rate_hz)
            if not publisher.lines.wait_for_subscribers(START_TIMEOUT_S):
                raise RuntimeError("the recorder does not subscribe to the numbered lines")
            publisher.thread.start()
            started, cpu_before = time.monotonic(), cpu_seconds(recorder.pid)
            time.sleep(record_s)  # the kill lands wherever the recorder's chunk happens to be
            cpu_used, recorded_s = cpu_seconds(recorder.pid) - cpu_before, time.monotonic() - started
            killed_at = time.monotonic()
            recorder.send_signal(signal.SIGKILL)
            recorder.wait()
            publisher.stop.set()
            publisher.thread.join()
            sent = publisher.sent_before(killed_at)
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.wait()
    recovered = directory / f"{name}-recovered.mcap"
    result = subprocess.run(foldcell_argv("log", "recover", str(path), "-o", str(recovered)), cwd=REPO,
                            capture_output=True, text=True)
    if result.returncode not in (0, 3):  # 3: data was lost, which is what is measured
        raise RuntimeError(f"log recover failed: {result.stderr}")
    kept = set(numbers_in(recovered))
    missing = [number for number in range(1, len(sent) + 1) if number not in kept]
    seconds = killed_at - sent[missing[0] - 1] if missing else 0.0
    return KillLoss(seconds, len(missing), len(sent), cpu_used / recorded_s)
