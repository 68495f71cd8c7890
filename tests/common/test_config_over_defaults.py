"""A `--config` file that sets a few values: the rest come from the shipped config/cell.yaml."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from cell.config import load_cell_config
from drivers.common.configfile import ConfigError, config_dir
from drivers.sessions.mcap.config import load_session_log_config
from drivers.wire.settings import load_wire_settings

SHIPPED = yaml.safe_load((config_dir() / "cell.yaml").read_text())


def test_a_partial_file_changes_what_it_sets_and_nothing_else(tmp_path: Path) -> None:
    partial = tmp_path / "mine.yaml"
    partial.write_text("cell_id: mine\ncell:\n  max_attempts: 7\n")
    settings = load_wire_settings(partial)
    assert settings.cell_id == "mine"
    assert list(settings.listen) == SHIPPED["zenoh"]["listen"]
    assert settings.zenoh_config_file.is_file()
    cell = load_cell_config(partial)
    assert cell.max_attempts == 7
    shipped = load_cell_config()
    for field in dataclasses.fields(cell):
        if field.name != "max_attempts":
            assert getattr(cell, field.name) == getattr(shipped, field.name), field.name
    assert cell.verify_min_iou == SHIPPED["cell"]["verify_min_iou"]
    assert load_session_log_config(partial) == load_session_log_config()   # read from the same --config


def test_a_bad_value_in_the_partial_file_names_that_file_and_field(tmp_path: Path) -> None:
    partial = tmp_path / "bad.yaml"
    partial.write_text("cell:\n  max_attempts: 0\n")
    with pytest.raises(ConfigError) as err:
        load_cell_config(partial)
    assert str(partial) in str(err.value) and "max_attempts" in str(err.value)
