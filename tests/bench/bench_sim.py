"""Benchmark of the simulated world: render time per 1280x1024 image, PNG encoding, dataset rate, and a
capture round-trip over loopback Zenoh (a raw PNG reply from a queryable; the CDR-typed camera process
is built on top of this by the camera server).

Run: .venv/bin/python -m tests.bench.bench_sim
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from drivers.common.garments import CATEGORIES
from drivers.sim.config import default_sim_config
from drivers.sim.dataset import build_world, generate
from drivers.sim.render import encode_png

REPEATS = 15


def stats(samples: list[float]) -> str:
    a = np.array(samples) * 1000.0
    return f"median {np.median(a):7.1f} ms   p99 {np.percentile(a, 99):7.1f} ms   (n={len(a)})"


def bench_render() -> None:
    cfg = default_sim_config()
    all_render: list[float] = []
    all_encode: list[float] = []
    for folded in (False, True):
        for cat in CATEGORIES:
            world = build_world(100, cat, folded)
            world.render()                     # warm: table texture and the camera's cached frame
            ts, es = [], []
            for _ in range(REPEATS):
                t0 = time.perf_counter()
                img = world.render()
                t1 = time.perf_counter()
                encode_png(img, cfg.render.png_compression)
                t2 = time.perf_counter()
                ts.append(t1 - t0)
                es.append(t2 - t1)
            all_render += ts
            all_encode += es
            state = "folded" if folded else "flat  "
            print(f"render {cat:13s} {state} ({len(world.layers)} layers): {stats(ts)}")
    print(f"render, all scenes:            {stats(all_render)}")
    print(f"PNG encode (lossless):         {stats(all_encode)}")
    cold = []
    for seed in range(4):
        t0 = time.perf_counter()
        build_world(200 + seed, CATEGORIES[seed % 4]).render()
        cold.append(time.perf_counter() - t0)
    print(f"new scene + first render:      {stats(cold)}")


def bench_dataset() -> None:
    with tempfile.TemporaryDirectory() as d:
        t0 = time.perf_counter()
        generate(d, 16, seed=1, progress=False)
        dt = time.perf_counter() - t0
    print(f"dataset generate --count 16:   {dt:.2f} s ({16 / dt:.1f} garment images/s incl. 4 empty tables)")


def bench_zenoh_capture() -> None:
    """Capture round trip through the real camera process: render, PNG, CompressedImage over loopback
    Zenoh."""
    import subprocess
    import time

    from drivers.camera.zenoh_client import ZenohCamera
    from drivers.wire.transport import Wire
    from tests.conftest import Endpoint, foldcell_argv, wait_until

    ep = Endpoint("bench")
    server = subprocess.Popen(foldcell_argv("camera", "serve", "--garment", "short-sleeve", "--seed", "4",
                                            *ep.args()), stderr=subprocess.DEVNULL)
    try:
        with Wire(ep.settings(), "bench-capture") as wire, ZenohCamera(wire, 10.0) as camera:
            assert wait_until(lambda: any(k.endswith("alive/camera") for k in wire.alive()), 30)
            camera.capture()  # warm-up
            samples = []
            for _ in range(40):
                t0 = time.perf_counter()
                camera.capture()
                samples.append(time.perf_counter() - t0)
    finally:
        server.send_signal(2)
        server.wait(10)
    print(f"capture round trip via `foldcell camera serve` (render + PNG + CompressedImage over loopback "
          f"Zenoh + decode), n=40: {stats(samples)}")


def main() -> None:
    bench_render()
    bench_dataset()
    bench_zenoh_capture()


if __name__ == "__main__":
    main()
