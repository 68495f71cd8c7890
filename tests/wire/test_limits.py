"""Size bounds per key: derived from the message layouts, tight for the largest trajectory, above every
legitimate payload, below Zenoh's own limit; an oversize sample is refused undecoded and the
subscription goes on."""

from __future__ import annotations

import threading

import cv2
import numpy as np
import pytest
import yaml

from drivers.common.garments import LANDMARKS
from drivers.controller.config import default_controller_config
from drivers.robot.config import default_robot_config
from drivers.wire import messages
from drivers.wire.limits import load_quantities, png_max_bytes
from drivers.wire.messages import WireError
from drivers.wire.registry import KEYS, payload_limit
from drivers.wire.settings import load_wire_settings
from drivers.wire.transport import Wire, cdr_encoding
from statemachine.machine import HISTORY_LENGTH, TRANSITIONS
from tests.conftest import REPO, wait_until

TRAJECTORY = "trajectory_msgs/msg/JointTrajectory"


def _types() -> set[str]:
    return {t for spec in KEYS for t in (spec.type_name, spec.reply_type) if t}


def test_every_type_on_the_wire_has_a_bound_below_zenoh_s_own_limit():
    limits = {t: payload_limit(t) for t in _types()}
    zenoh_limit = int(load_wire_settings().zenoh_config().get_json("transport/link/rx/max_message_size"))
    assert 2 * max(limits.values()) < zenoh_limit, (max(limits.items(), key=lambda kv: kv[1]), zenoh_limit)


def test_the_largest_trajectory_fits_and_the_bound_is_tight():
    rc, config = default_robot_config(), default_controller_config()
    name = "n" * load_quantities()["name"]
    joints = len(rc.joint_names)
    point = messages.new("trajectory_msgs/msg/JointTrajectoryPoint", positions=np.ones(joints),
                         velocities=np.ones(joints), accelerations=np.ones(joints), effort=np.ones(joints))
    largest = messages.new(TRAJECTORY, header=messages.header(frame_id=name), joint_names=[name] * joints,
                           points=[point] * config.max_points)
    size = len(messages.encode(TRAJECTORY, largest))
    assert size <= payload_limit(TRAJECTORY) <= 1.1 * size, (size, payload_limit(TRAJECTORY))


@pytest.mark.parametrize("level", [0, 9])
def test_the_largest_png_of_the_camera_fits(level):
    pixels = np.random.default_rng(3).integers(0, 65535, (1024, 1280, 4), dtype=np.uint16)
    ok, data = cv2.imencode(".png", pixels, [cv2.IMWRITE_PNG_COMPRESSION, level])
    assert ok and len(data) <= png_max_bytes(1280, 1024)


def test_the_configured_counts_cover_what_the_cell_sends():
    quantities = load_quantities()
    assert quantities["transitions"] >= HISTORY_LENGTH
    assert quantities["triggers"] >= len({t.trigger for t in TRANSITIONS})
    assert quantities["landmarks"] >= max(len(names) for names in LANDMARKS.values()) + 1  # + the label
    with open(REPO / "config" / "cell.yaml") as f:   # the processes the cell can list as lost
        assert quantities["processes"] >= len(yaml.safe_load(f)["cell"]["required_processes"])


def test_an_oversize_sample_is_refused_undecoded_and_the_subscription_goes_on(endpoint):
    limit = payload_limit("rcl_interfaces/msg/Log")
    errors: list[WireError] = []
    received: list[str] = []
    lock = threading.Lock()

    def on_error(err: WireError) -> None:
        with lock:
            errors.append(err)

    with Wire(endpoint.settings(), "test-sink") as sink, Wire(endpoint.settings(), "test-source") as src:
        sink.subscribe("cell/log", lambda _k, msg, _r: received.append(msg.msg), on_error=on_error)
        publisher = src.publisher("cell/log")
        assert publisher.wait_for_subscribers(10)
        oversize = bytes(4 * limit)
        # a stranger's put: a Wire publisher would not send it
        src.session.put(src.key("cell/log"), oversize, encoding=cdr_encoding("rcl_interfaces/msg/Log"))
        publisher.put(messages.new("rcl_interfaces/msg/Log", stamp=messages.stamp_now(), msg="after"))
        assert wait_until(lambda: received == ["after"], 10), received
        assert wait_until(lambda: len(errors) == 1, 10)
    assert f"payload of {len(oversize)} bytes is over the limit of {limit} bytes" in str(errors[0])
