"""Recorder loss on SIGKILL: what a killed `foldcell log record` loses of a 250 Hz numbered stream (with a
250 Hz joint-state stream beside it, a running cell's load), over several kills at random moments, and
the recorder's CPU while it records. The test (tests/sessions/test_recorder.py) checks the bound with an
allowance for a loaded machine; these are the figures.

    .venv/bin/python -m tests.bench recorder
"""

from __future__ import annotations

import random
import statistics
import tempfile
from pathlib import Path

from drivers.sessions.mcap.config import load_session_log_config
from tests.bench.targets import check
from tests.conftest import Endpoint
from tests.sessions.crash_loss import RATE_HZ, kill_recorder_once

KILLS = 6
RECORD_S = (1.0, 3.0)        # publishing time before each kill, drawn at random
LOSS_TARGET_S = 0.1
CPU_TARGET = 0.5             # of one core, at a running cell's rates


def main() -> None:
    rng = random.Random()
    config = load_session_log_config()
    print(f"flush_interval_s {config.flush_interval_s}, chunk_size {config.chunk_size} B, "
          f"{RATE_HZ:g} Hz numbered lines + {RATE_HZ:g} Hz joint states")
    losses = []
    with tempfile.TemporaryDirectory() as directory:
        for kill in range(KILLS):
            loss = kill_recorder_once(Endpoint("bench-recorder"), Path(directory), rng.uniform(*RECORD_S),
                                      f"kill{kill}")
            losses.append(loss)
            print(f"kill {kill + 1}: lost {loss.seconds * 1e3:6.1f} ms, {loss.lines:4d} of {loss.sent} "
                  f"lines; recorder CPU {loss.cpu_share * 100:.1f} % of a core", flush=True)
    worst = max(loss.seconds for loss in losses)
    print(f"loss: median {statistics.median(loss.seconds for loss in losses) * 1e3:.1f} ms, "
          f"worst {worst * 1e3:.1f} ms ({max(loss.lines for loss in losses)} lines)")
    cpu = statistics.median(loss.cpu_share for loss in losses)
    print(f"recorder CPU: median {cpu * 100:.1f} % of a core")
    check("recorder", "recorder loss on SIGKILL, worst of kills", worst, "<=", LOSS_TARGET_S, "s")
    check("recorder", "recorder CPU while recording, median", cpu, "<=", CPU_TARGET, "cores")
