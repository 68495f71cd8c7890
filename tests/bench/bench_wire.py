"""Spine figures: encode/decode per type, recorder throughput, pub/sub round trip between processes."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh
from mcap.reader import make_reader

from drivers.wire import messages
from drivers.wire.transport import Wire
from tests.conftest import Endpoint, foldcell_argv, wait_until
from tests.wire.examples import random_message, registry_types

REPEATS = 5


def _median_us(fn, n: int) -> float:
    runs = []
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        runs.append((time.perf_counter() - t0) / n * 1e6)
    return float(np.median(runs))


def codec() -> None:
    rng = np.random.default_rng(0)
    print(f"{'type':45} {'bytes':>7} {'encode us':>10} {'decode us':>10}")
    for type_name in registry_types():
        msg = random_message(type_name, rng)
        if type_name == "sensor_msgs/msg/JointState":
            msg = messages.new(type_name, header=messages.header(), name=[f"j{i}" for i in range(13)],
                               position=rng.normal(size=13), velocity=rng.normal(size=13))
        data = messages.encode(type_name, msg)
        enc = _median_us(lambda type_name=type_name, msg=msg: messages.encode(type_name, msg), 300)
        dec = _median_us(lambda type_name=type_name, data=data: messages.decode(type_name, data), 300)
        print(f"{type_name:45} {len(data):7d} {enc:10.1f} {dec:10.1f}")


def recorder_throughput() -> None:
    print("\nrecorder throughput (publisher process -> recorder process -> MCAP, loopback Zenoh)")
    for size, count in ((200, 20000), (1 << 20, 300)):
        rates = []
        for _ in range(3):
            ep = Endpoint("bench")
            with tempfile.TemporaryDirectory() as tmp:
                path = Path(tmp) / "b.mcap"
                rec = subprocess.Popen(foldcell_argv("log", "record", "-o", str(path), *ep.args()),
                                       stderr=subprocess.DEVNULL)
                with Wire(ep.settings(), "bench-pub") as wire:
                    assert wait_until(lambda: any("recorder" in k for k in wire.alive()), 10)
                    pub = wire.publisher("camera/image")
                    # reliable publishing: measure what the recorder sustains, not what the network drops
                    raw = wire.session.declare_publisher(
                        wire.key("camera/image"), encoding=pub.publisher.encoding,
                        congestion_control=zenoh.CongestionControl.BLOCK)
                    payload = messages.encode("sensor_msgs/msg/CompressedImage", messages.new(
                        "sensor_msgs/msg/CompressedImage", format="png",
                        data=np.random.default_rng(1).integers(0, 255, size - 60, dtype=np.uint8)))
                    assert pub.wait_for_subscribers(10)
                    for _ in range(count):
                        raw.put(payload)
                    raw.undeclare()
                    time.sleep(0.5)
                rec.send_signal(2)
                rec.wait(60)
                with open(path, "rb") as f:
                    times = [m.log_time for _, _, m in make_reader(f).iter_messages()]
                got = len(times)
                span = (max(times) - min(times)) / 1e9 if got > 1 else float("nan")
                rates.append((got / span, got * len(payload) / span / 1e6, got / count))
        r = np.median(np.array(rates), axis=0)
        print(f"  {size:>8} B messages: {r[0]:10.0f} msg/s  {r[1]:8.1f} MB/s  (received {r[2] * 100:.1f} %, "
              f"median of 3 runs of {count})")


def round_trip() -> None:
    print("\npub/sub round trip between two processes (JointState, 13 joints, via a mirror process)")
    ep = Endpoint("src")
    mirror = subprocess.Popen([sys.executable, "-m", "tests.nodes.mirror", *ep.args("src"), "--dst", "dst"],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
    mirror.stdout.readline()
    lat: list[float] = []
    done = threading.Event()
    sent: dict[int, int] = {}
    try:
        with Wire(ep.settings("dst"), "bench-sink") as sink, Wire(ep.settings("src"), "bench-src") as src:
            def on_msg(_k, msg, _r):
                i = int(msg.header.frame_id)
                lat.append((time.perf_counter_ns() - sent[i]) / 1e3)
                done.set()
            sink.subscribe("controller/joint_states", on_msg)
            pub = src.publisher("controller/joint_states")
            assert pub.wait_for_subscribers(10)
            assert wait_until(lambda: any("mirror-out" in k for k in sink.alive()), 10)
            rng = np.random.default_rng(0)
            for i in range(1000):
                msg = messages.new("sensor_msgs/msg/JointState", header=messages.header(frame_id=str(i)),
                                   name=[f"j{k}" for k in range(13)], position=rng.normal(size=13))
                done.clear()
                sent[i] = time.perf_counter_ns()
                pub.put(msg)
                done.wait(1.0)
    finally:
        mirror.send_signal(2)
        mirror.wait(10)
    a = np.array(lat)
    print(f"  round trip over {len(a)} samples: median {np.median(a):.0f} us, "
          f"p99 {np.percentile(a, 99):.0f} us")


def main() -> None:
    codec()
    recorder_throughput()
    round_trip()


if __name__ == "__main__":
    main()
