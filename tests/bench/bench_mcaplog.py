"""Session writer throughput: messages/s and MB/s for 200-byte and 1-MiB messages.

Run: .venv/bin/python -m tests.bench.bench_mcaplog
Each figure is the median of several runs; a run writes the messages through `SessionWriter.write`
and includes `close()` (summary, footer). Payloads are random bytes (CDR of images and point clouds
compresses little), so compression costs time without shrinking much. Files go to /dev/shm when it
exists (RAM, like the published rosbag2 figures), else to the temp directory.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
from pathlib import Path

from rosbags.typesys import Stores, get_typestore

from drivers.sessions.mcap import SessionWriter, read_info, recover

RUNS = 7
RECOVER_RUNS = 3
CASES = (  # (label, payload bytes, messages per run)
    ("200 B", 200, 50_000),
    ("1 MiB", 1024 * 1024, 48),
)
COMPRESSIONS = ("zstd", "lz4", "none")
TOPIC = "/foldcell/cell1/camera/image"
TYPE_NAME = "sensor_msgs/msg/CompressedImage"


def _out_dir() -> Path:
    shm = Path("/dev/shm")
    return shm if shm.is_dir() and os.access(shm, os.W_OK) else Path(tempfile.gettempdir())


def run_once(path: Path, payloads: list[bytes], count: int, compression: str, msgdef: str) -> float:
    """Seconds to write `count` messages and close the file."""
    t0 = time.perf_counter()
    with SessionWriter(path, compression=compression) as w:
        t = 1_700_000_000_000_000_000
        for i in range(count):
            w.write(TOPIC, TYPE_NAME, msgdef, payloads[i % len(payloads)], t + i, t + i)
    elapsed = time.perf_counter() - t0
    path.unlink()
    return elapsed


def _payloads(size: int, count: int) -> list[bytes]:
    """Distinct random payloads, so no chunk compresses by repetition."""
    blob = os.urandom(size * count)
    return [blob[i * size:(i + 1) * size] for i in range(count)]


def _median_time(fn, runs: int) -> float:
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_recover(d: Path, msgdef: str) -> None:
    """Recover (and scan-based info) speed on a file cut just before its summary."""
    print()
    print(f"recover and info of a file cut before its summary, median of {RECOVER_RUNS} runs")
    print(f"{'message':>8} {'file MB':>8} {'recover msg/s':>14} {'recover MB/s':>13} "
          f"{'info scan ms':>13} {'info summary ms':>16}")
    for label, size, count in CASES:
        full, cut, out = d / "full.mcap", d / "cut.mcap", d / "out.mcap"
        payloads = _payloads(size, count)
        with SessionWriter(full) as w:
            for i in range(count):
                w.write(TOPIC, TYPE_NAME, msgdef, payloads[i % len(payloads)], i, i)
        data = full.read_bytes()
        cut.write_bytes(data[: len(data) - 1000])  # summary and last indexes gone: scan needed
        mb = len(data) / 1e6
        t_recover = _median_time(lambda cut=cut, out=out: recover(cut, out), RECOVER_RUNS)
        t_scan = _median_time(lambda cut=cut: read_info(cut), RECOVER_RUNS)
        t_summary = _median_time(lambda full=full: read_info(full), RECOVER_RUNS)
        print(f"{label:>8} {mb:>8.1f} {count / t_recover:>14,.0f} {mb / t_recover:>13.1f} "
              f"{t_scan * 1e3:>13.1f} {t_summary * 1e3:>16.1f}")
        for path in (full, cut, out):
            path.unlink()


def main() -> None:
    out = _out_dir()
    msgdef, _ = get_typestore(Stores.ROS2_JAZZY).generate_msgdef(TYPE_NAME, ros_version=2)
    print(f"SessionWriter throughput, median of {RUNS} runs, chunk 1 MiB, random payloads, files in {out}")
    print("MB/s counts payload bytes (1 MB = 1e6 B); 'vs none' = throughput / throughput without compression")
    print(f"{'message':>8} {'compression':>11} {'messages':>9} {'msg/s':>12} {'MB/s':>9} {'vs none':>8}")
    with tempfile.TemporaryDirectory(dir=out) as d:
        path = Path(d) / "bench.mcap"
        for label, size, count in CASES:
            payloads = _payloads(size, count)
            base: float | None = None
            rows = []
            for compression in COMPRESSIONS:
                times = [run_once(path, payloads, count, compression, msgdef) for _ in range(RUNS)]
                rows.append((compression, statistics.median(times)))
            base = dict(rows)["none"]
            for compression, median in rows:
                rate = count / median
                mb_s = count * size / median / 1e6
                print(f"{label:>8} {compression:>11} {count:>9} {rate:>12,.0f} {mb_s:>9.1f} "
                      f"{base / median:>7.2f}x")
        bench_recover(Path(d), msgdef)


if __name__ == "__main__":
    main()
