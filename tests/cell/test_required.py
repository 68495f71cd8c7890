"""The names the cell counts as required are exactly the processes it depends on."""

from __future__ import annotations

from cell.config import load_cell_config
from drivers.camera.node import PROCESS_NAME as CAMERA
from drivers.controller.interface import PROCESS_NAMES


def test_required_processes_are_the_controller_layouts_and_the_camera():
    assert set(load_cell_config().required_processes) == {*PROCESS_NAMES.values(), CAMERA}
