"""Benchmark of the simulated world: render time per 1280x1024 image, PNG encoding, dataset rate, and a
capture round-trip over loopback Zenoh (a raw PNG reply from a queryable; the CDR-typed camera process
is built on top of this by the camera server).

Run: .venv/bin/python -m tests.bench.bench_sim
"""

from __future__ import annotations

import socket
import tempfile
import time

import numpy as np

from drivers.sim.config import CATEGORIES, default_sim_config
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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def bench_zenoh_capture() -> None:
    import zenoh
    port = _free_port()

    def conf(listen: bool) -> zenoh.Config:
        c = zenoh.Config()
        c.insert_json5("scouting/multicast/enabled", "false")
        key = "listen/endpoints" if listen else "connect/endpoints"
        c.insert_json5(key, f'["tcp/127.0.0.1:{port}"]')
        return c

    world = build_world(1, "towel")
    cfg = default_sim_config()

    def on_query(query: zenoh.Query) -> None:
        query.reply(query.key_expr, encode_png(world.render(), cfg.render.png_compression))

    server = zenoh.open(conf(True))
    queryable = server.declare_queryable("foldcell/bench/camera/capture", on_query)
    client = zenoh.open(conf(False))
    time.sleep(0.5)
    rts: list[float] = []
    size = 0
    for i in range(REPEATS + 5):
        t0 = time.perf_counter()
        replies = list(client.get("foldcell/bench/camera/capture", timeout=5.0))
        dt = time.perf_counter() - t0
        ok = [r.ok for r in replies if r.ok is not None]
        if not ok:
            raise RuntimeError("no reply from the capture queryable")
        size = len(ok[0].payload.to_bytes())
        if i >= 3:
            rts.append(dt)
    print(f"capture round-trip over Zenoh (render + PNG + loopback TCP, {size / 1e6:.2f} MB): {stats(rts)}")
    queryable.undeclare()
    client.close()
    server.close()


def main() -> None:
    bench_render()
    bench_dataset()
    bench_zenoh_capture()


if __name__ == "__main__":
    main()
