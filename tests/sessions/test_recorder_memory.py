"""A long-running recorder keeps no memory of the processes that came and went.

Zenoh's shared memory (on by default in 1.x) left every departed sender's pool mapped in each
receiver: ~20 MB per camera restart. The shipped config turns it off; this test churns real senders
against a real `foldcell log record` and reads the recorder's resident memory from /proc.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from mcap.reader import make_reader

from tests.conftest import REPO, Endpoint, foldcell_argv, wait_until

SENDERS = 6
IMAGES_PER_SENDER = 3
IMAGE_BYTES = 300_000           # fragmented on the wire (over Zenoh's 64 kB batch)
# One departed sender's pool was ~20 MB; the six together would keep ~120 MB.
ALLOWED_GROWTH_MB = 40

SENDER = """
import sys, time
import numpy as np
from drivers.wire import messages
from drivers.wire.transport import Wire
from mcap.reader import make_reader

from tests.conftest import Endpoint
ep = Endpoint(sys.argv[1]); ep.port = int(sys.argv[2])
wire = Wire(ep.settings(), "memory-sender")
pub = wire.publisher("camera/image")
assert pub.wait_for_subscribers(30), "the recorder never matched"
for i in range(int(sys.argv[3])):
    data = np.random.default_rng(i).integers(0, 255, int(sys.argv[4]), dtype=np.uint8).tobytes()
    pub.put(messages.new("sensor_msgs/msg/CompressedImage", header=messages.header(),
                         format="png", data=np.frombuffer(data, np.uint8)))
    time.sleep(0.05)
time.sleep(0.3)
wire.close()
"""


def resident_mb(pid: int) -> float:
    return int(Path(f"/proc/{pid}/statm").read_text().split()[1]) * 4096 / 2**20


def test_a_recorder_keeps_no_memory_of_senders_that_left(tmp_path: Path) -> None:
    ep = Endpoint()
    recorder = subprocess.Popen(foldcell_argv("log", "record", "-o", str(tmp_path / "session"), *ep.args()),
                                cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        sender = [sys.executable, "-c", SENDER, ep.cell, str(ep.port), str(IMAGES_PER_SENDER),
                  str(IMAGE_BYTES)]
        # the first sender brings every lazily made buffer into being; growth counts from after it
        subprocess.run(sender, cwd=REPO, check=True, timeout=60)
        assert wait_until(lambda: recorder.poll() is None, 1.0)
        before = resident_mb(recorder.pid)
        for _ in range(SENDERS):
            subprocess.run(sender, cwd=REPO, check=True, timeout=60)
        grown = resident_mb(recorder.pid) - before
        assert recorder.poll() is None, recorder.stderr.read() if recorder.stderr else ""
        assert grown <= ALLOWED_GROWTH_MB, f"the recorder grew {grown:.0f} MB over {SENDERS} senders"
    finally:
        recorder.terminate()
        recorder.wait(timeout=30)
    # the memory stayed because the recorder was hearing the senders: it recorded every image
    with open(tmp_path / "session" / "session_0.mcap", "rb") as f:
        images = sum(channel.topic.endswith("/camera/image")
                     for _s, channel, _m in make_reader(f).iter_messages())
    assert images == (SENDERS + 1) * IMAGES_PER_SENDER
