"""config/controller.yaml, the code tables and the client interface's error mapping."""

from __future__ import annotations

import numpy as np
import pytest

from drivers.common.configfile import ConfigError
from drivers.controller.codes import Command, Reply, Result, Subcode
from drivers.controller.config import default_controller_config, load_controller_config
from drivers.controller.errors import (
    ControllerError,
    InvalidArgument,
    LeaseHeld,
    NotReady,
    TrajectoryRejected,
    error_for_reply,
)
from drivers.controller.interface import Controller
from drivers.emulator.core import ControllerCore
from drivers.robot.config import default_robot_config

SHIPPED = default_controller_config()


def test_shipped_config_values():
    assert SHIPPED.interpolation_period == 0.004
    assert SHIPPED.feedback_rate == 250.0 and SHIPPED.status_rate == 10.0
    assert SHIPPED.max_points == 200
    assert SHIPPED.group_owners == {"R1": "master", "R2": "slave", "B1": "master"}
    assert SHIPPED.time_scale == 1.0
    # a lost link or holder is a vanished token (Zenoh's lease); the silences only catch a hung process,
    # so they stay well above the stalls a loaded machine causes
    assert SHIPPED.link_stall_timeout >= 1.0 and SHIPPED.lease_silence_timeout >= 1.0


def write(tmp_path, text):
    from drivers.common.configfile import config_dir

    base = (config_dir() / "controller.yaml").read_text()
    path = tmp_path / "controller.yaml"
    path.write_text(base + text)
    return path


@pytest.mark.parametrize("extra, field", [
    ("interpolation_period: -1\n", "interpolation_period"),
    ("max_points: 1\n", "max_points"),
    ("colour: red\n", "colour"),
    ("groups: {R1: boss}\n", "groups.R1"),
    ("stop: {acceleration_fraction: 1.5}\n", "stop.acceleration_fraction"),
    ("lease: {required: maybe, silence_timeout: 3.0}\n", "lease.required"),
    ("link: {timeout: 0.5}\n", "link.timeout"),
])
def test_bad_values_name_the_field(tmp_path, extra, field):
    with pytest.raises(ConfigError) as err:
        load_controller_config(write(tmp_path, extra))  # a later key overrides the shipped one
    assert err.value.field == field
    assert "controller.yaml" in str(err.value)


def test_group_ownership_is_configurable(tmp_path):
    cfg = load_controller_config(write(tmp_path, "groups: {R1: master, R2: master, B1: slave}\n"))
    rc = default_robot_config()
    master = ControllerCore(rc, cfg, "master")
    slave = ControllerCore(rc, cfg, "slave")
    assert master.joint_names == rc.group("R1").joints + rc.group("R2").joints
    assert slave.joint_names == ("ext_axis",)
    assert [g.name for g in master.status().groups] == ["R1", "R2"]


def test_codes_have_motoros_values():
    assert (Result.SUCCESS, Result.BUSY, Result.INVALID, Result.NOT_READY) == (0, 1, 3, 5)
    assert Subcode.INVALID_DATA_START_POS == 3011 and Subcode.NOT_READY_NOT_STARTED == 5008
    assert Command.STOP_MOTION == 200111 and Command.START_TRAJ_MODE == 200121
    assert Subcode.INVALID_DATA_SPEED.text == "invalid data speed"
    text = Reply(Result.INVALID, Subcode.INVALID_DATA_SPEED, "too fast").describe()
    assert "INVALID_DATA_SPEED" in text and "3/3013" in text and "too fast" in text


def test_error_for_reply_is_typed_and_carries_the_code():
    err = error_for_reply(Reply(Result.INVALID, Subcode.INVALID_DATA_POSITION, "bad", 3, "r1_joint_s"))
    assert isinstance(err, TrajectoryRejected) and err.subcode == 3012 and err.point == 3
    assert err.joint == "r1_joint_s" and "3012" in str(err)
    assert isinstance(error_for_reply(Reply(Result.NOT_READY, Subcode.NOT_READY_ESTOP, "x")), NotReady)
    assert isinstance(error_for_reply(Reply(Result.BUSY, 0, "x")), NotReady)
    assert isinstance(error_for_reply(Reply(Result.FAILURE, Subcode.LEASE_HELD, "x")), LeaseHeld)
    assert type(error_for_reply(Reply(Result.MP_FAILURE, 0, "x"))) is ControllerError
    assert isinstance(error_for_reply(Reply(Result.INVALID, Subcode.BAD_ARGUMENT, "x")), InvalidArgument)


def test_controller_is_abstract():
    with pytest.raises(TypeError):
        Controller()  # type: ignore[abstract]


def test_step_dt_must_be_the_period():
    core = ControllerCore(default_robot_config(), SHIPPED)
    core.step(SHIPPED.interpolation_period)
    with pytest.raises(ValueError, match="interpolation period"):
        core.step(0.01)
    fbs = core.run_until(1.0)
    assert len(fbs) == 249 and core.stamp == pytest.approx(1.0)
    assert np.all(fbs[-1].velocities == 0)
