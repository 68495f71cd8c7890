"""A config section read field by field from its dataclass (`rule`, `load_fields`): every value as the
YAML file says it, and a wrong one refused naming file, field and reason."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import yaml

from drivers.common.configfile import ConfigError, config_dir
from drivers.sim.config import load_sim_config

SHIPPED = yaml.safe_load((config_dir() / "sim.yaml").read_text())


def test_every_render_and_fold_rule_value_is_the_files() -> None:
    config = load_sim_config()
    render = {f.name: getattr(config.render, f.name) for f in dataclasses.fields(config.render)}
    render.pop("table_look")
    assert render.keys() == SHIPPED["render"].keys()
    for name, value in SHIPPED["render"].items():
        assert render[name] == (tuple(value) if isinstance(value, list) else value), name
    assert dataclasses.asdict(config.fold_rules) == SHIPPED["fold_rules"]


@pytest.mark.parametrize(("section", "field", "value", "reason"), [
    ("render", "png_compression", 12, "must be <= 9"),
    ("render", "texture_resolution", 0.0, "must be > 0"),
    ("render", "floor_bgr", [1.0, 2.0], "must have 3 numbers"),
    ("render", "wrinkle_count", [2.5, 7], "must be integers"),
    ("render", "shadow_blur", 1.5, "must be an integer"),
    ("fold_rules", "crumple", "a lot", "must be a finite number"),
    ("fold_rules", "grasp_heigth", 0.03, "unknown field"),
])
def test_a_wrong_value_is_refused_naming_file_field_and_reason(tmp_path: Path, section: str, field: str,
                                                               value: object, reason: str) -> None:
    data = yaml.safe_load((config_dir() / "sim.yaml").read_text())
    data[section][field] = value
    path = tmp_path / "sim.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_sim_config(path)
    assert str(path) in str(err.value) and f"{section}.{field}" in str(err.value) and reason in str(err.value)


def test_a_missing_value_is_refused(tmp_path: Path) -> None:
    data = yaml.safe_load((config_dir() / "sim.yaml").read_text())
    del data["render"]["noise_sigma"]
    path = tmp_path / "sim.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"render\.noise_sigma: missing"):
        load_sim_config(path)
