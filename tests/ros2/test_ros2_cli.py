"""`foldcell ros2` refuses what ROS 2 cannot name or reach, before it joins anything, and says why."""

from __future__ import annotations

import pytest

from tools.cli import main


@pytest.mark.parametrize(("argv", "message"), [
    (["ros2", "--print", "--cell", "cell-1"], "--cell 'cell-1' is not a ROS 2 name token"),
    (["ros2", "--cell", "*"], "--cell: the bridge shows one cell"),
    (["ros2", "--print", "--domain-id", "300"], "--domain-id: must be 0..232, got 300"),
    (["ros2", "--print", "--ros-connect", "localhost:7447"], "--ros-connect: 'localhost:7447' is not a Zenoh "
                                                              "endpoint"),
])
def test_bad_input_is_an_error_naming_it(argv, message, capsys, monkeypatch):
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err


def test_the_domain_comes_from_ros_domain_id(capsys, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "9")
    assert main(["ros2", "--print", "--cell", "c2"]) == 0
    out = capsys.readouterr().out
    assert "9/foldcell/c2/controller/joint_states/sensor_msgs::msg::dds_::JointState_/RIHS01_" in out
    assert "service /foldcell/c2/cell/command  foldcell_msgs/srv/CellCommand" in out
    monkeypatch.setenv("ROS_DOMAIN_ID", "x")
    assert main(["ros2", "--print"]) == 2
    assert "ROS_DOMAIN_ID: must be a whole number" in capsys.readouterr().err
