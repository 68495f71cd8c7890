"""A test process that plays a small fake cell session (no tests here; run with `python -m`).

Publishes in its cell: a sequence of `cell/state` changes (history accumulating), joint states at
a fixed rate, controller status at 10 Hz, a `cell/log` line per state, and optionally one camera
image (PNG of the simulated world's towel scene 3) with its logged `perception/observation`, and
malformed samples.
Prints `ready` once its publishers match a subscriber (or after --wait), `done` when the sequence ends.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time

import numpy as np

from drivers.robot.config import default_robot_config
from drivers.wire import messages
from drivers.wire.transport import Wire
from tools.common import StopSignal, add_wire_arguments, wire_settings

STATES = ("idle", "perceiving", "matching", "planning", "grasping", "folding", "verifying", "done")


def cell_state(cell: str, states: list[str], stamp_ns: int) -> object:
    history = [
        messages.new(
            "foldcell_msgs/msg/CellTransition",
            stamp=messages.stamp_from_ns(stamp_ns),
            trigger=f"to_{b}",
            source=a,
            dest=b,
        )
        for a, b in itertools.pairwise(states)
    ]
    return messages.new(
        "foldcell_msgs/msg/CellState",
        header=messages.header(stamp_ns),
        cell_id=cell,
        state=states[-1],
        garment="towel",
        fold_index=max(0, len(states) - 5),
        fold_count=2,
        attempt=1,
        stage="fold" if states[-1] == "folding" else "",
        history=history,
    )


def towel_image_and_observation(stamp_ns: int) -> tuple[object, object]:
    from drivers.sim.dataset import build_world, render_scene_png

    world = build_world(3, "towel")
    png = np.frombuffer(render_scene_png(3, "towel"), np.uint8)
    names, pts = world.truth_polygon()
    truth = world.camera.table_to_pixel(pts)
    image = messages.new(
        "sensor_msgs/msg/CompressedImage",
        header=messages.header(stamp_ns, "camera"),
        format="png",
        data=png,
    )
    landmarks = [
        messages.new("foldcell_msgs/msg/Landmark", name=n, x_px=float(x) + 3.0, y_px=float(y))
        for n, (x, y) in zip(names, truth, strict=False)
    ]
    polygon = [
        messages.new("geometry_msgs/msg/Point", x=float(x), y=float(y), z=0.0) for x, y in truth
    ]
    obs = messages.new(
        "foldcell_msgs/msg/GarmentObservation",
        header=messages.header(stamp_ns, "camera"),
        category="towel",
        landmarks=landmarks,
        polygon_px=polygon,
        polygon_table=polygon,
        cost=1.0,
    )
    return image, obs


def main() -> int:
    parser = argparse.ArgumentParser()
    add_wire_arguments(parser)
    parser.add_argument("--state-period", type=float, default=0.3)
    parser.add_argument("--joint-hz", type=float, default=250.0)
    parser.add_argument("--image", action="store_true")
    parser.add_argument(
        "--bad", action="append", default=[], help="relative keys to send one malformed sample on"
    )
    parser.add_argument("--forever", action="store_true", help="keep streaming after the sequence")
    parser.add_argument("--wait", type=float, default=2.0)
    args = parser.parse_args()
    settings = wire_settings(args, "cell")
    stop = StopSignal()
    robot = default_robot_config()
    names = list(robot.joint_names) if hasattr(robot, "joint_names") else [j.name for j in robot.joints]
    with Wire(settings, "fake-cell") as wire:
        pubs = {
            k: wire.publisher(k)
            for k in (
                "cell/state",
                "controller/joint_states",
                "controller/status",
                "cell/log",
                "camera/image",
                "perception/observation",
            )
        }
        bad_publishers = [pubs[rel] if rel in pubs else wire.publisher(rel) for rel in args.bad]
        image_pair = towel_image_and_observation(0) if args.image else None
        pubs["cell/state"].wait_for_subscribers(args.wait)
        print("ready", flush=True)
        t0 = time.monotonic()
        next_joint = next_status = t0
        index = 0
        seen = [STATES[0]]
        pubs["cell/state"].put(cell_state(settings.cell_id, seen, time.time_ns()))
        next_state = t0 + args.state_period
        while not stop.is_set():
            now = time.monotonic()
            if now >= next_joint:
                pos = [0.1 * np.sin(now - t0 + i) for i in range(len(names))]
                pubs["controller/joint_states"].put(
                    messages.new(
                        "sensor_msgs/msg/JointState",
                        header=messages.header(time.time_ns()),
                        name=names,
                        position=np.array(pos),
                        velocity=np.zeros(len(names)),
                        effort=np.zeros(len(names)),
                    )
                )
                next_joint += 1.0 / args.joint_hz
            if now >= next_status:
                pubs["controller/status"].put(
                    messages.new(
                        "foldcell_msgs/msg/ControllerStatus",
                        header=messages.header(time.time_ns()),
                        drives_powered=1,
                        e_stopped=0,
                        in_error=0,
                        in_motion=1 if seen[-1] in ("grasping", "folding") else 0,
                        mode=2,
                        motion_possible=1,
                        held=0,
                        trajectory_mode=1,
                        lease_holder="cell",
                        time_scale=1.0,
                    )
                )
                next_status += 0.1
            if now >= next_state and index + 1 < len(STATES):
                index += 1
                seen.append(STATES[index])
                stamp = time.time_ns()
                pubs["cell/state"].put(cell_state(settings.cell_id, seen, stamp))
                level = 40 if STATES[index] == "verifying" else 20
                pubs["cell/log"].put(
                    messages.new(
                        "rcl_interfaces/msg/Log",
                        stamp=messages.stamp_from_ns(stamp),
                        level=level,
                        name="cell",
                        msg=f"state {STATES[index]}",
                    )
                )
                if STATES[index] == "perceiving" and image_pair is not None:
                    image, obs = image_pair
                    image.header.stamp = obs.header.stamp = messages.stamp_from_ns(stamp)
                    pubs["camera/image"].put(image)
                    pubs["perception/observation"].put(obs)
                if index >= STATES.index("matching"):
                    # again at every later state: a watcher on drop lanes may lose one under load
                    for publisher in bad_publishers:
                        publisher.put_encoded(b"\x00\x01garbage", time.time_ns())
                next_state += args.state_period
                if index + 1 == len(STATES):
                    next_state = float("inf")  # the sequence is over: only the streams go on
                    print("done", flush=True)
                    if not args.forever:
                        time.sleep(0.2)
                        break
            wake = min(next_joint, next_status, next_state)
            stop.wait(max(0.0, wake - time.monotonic()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
