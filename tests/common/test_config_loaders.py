"""Every loader that reads its dataclass with `load_fields`: a wrong value written into a copy of the
shipped file is refused naming that file, the value's dotted path in it and the reason."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import yaml

from cell.perception.config import load_perception_config
from cell.planning.config import load_planning_config
from drivers.camera.model import load_camera_config
from drivers.common.configfile import ConfigError, config_dir
from drivers.controller.config import load_controller_config
from drivers.motoros.config import load_motoros_config
from drivers.robot.table import load_table_config
from drivers.sessions.recorder import load_rejection_bounds
from drivers.sim.config import load_sim_config
from drivers.sim.physics.config import load_physics_config
from drivers.wire.limits import load_query_rates

QUERYABLES = tuple(yaml.safe_load((config_dir() / "limits.yaml").read_text())["query_rates"])
QUERY = QUERYABLES[0]


def _query_rates(path: Path) -> object:
    return load_query_rates(QUERYABLES, path.parent)


LOADERS: dict[str, Callable[[Path], Any]] = {
    "controller.yaml": load_controller_config, "perception.yaml": load_perception_config,
    "planning.yaml": load_planning_config, "motoros.yaml": load_motoros_config,
    "camera.yaml": load_camera_config, "table.yaml": load_table_config, "sim.yaml": load_sim_config,
    "physics.yaml": load_physics_config, "limits.yaml": _query_rates,
}

CASES = [
    ("controller.yaml", ("lease", "silence_timeout"), 0.0, "must be > 0"),
    ("controller.yaml", ("stop", "acceleration_fraction"), 1.5, "must be <= 1.0"),
    ("controller.yaml", ("link", "stall_time"), 5.0, "unknown field"),
    ("controller.yaml", ("max_points",), 1, "must be >= 2"),
    ("perception.yaml", ("segmentation", "work_size"), [8, 256], "must be >= 16"),
    ("perception.yaml", ("segmentation", "adapt_light"), "yes", "must be true or false"),
    ("perception.yaml", ("table", "gain_grid"), [0, 10], "must be >= 1"),
    ("perception.yaml", ("folded", "merge_fraction"), 0.9, "must be <= 0.5"),
    ("perception.yaml", ("models", "angle_var_floor"), 0.0, "must be > 0"),
    ("perception.yaml", ("recognition", "augment", "stretch"), [2.0, 1.0], "low <= high"),
    ("perception.yaml", ("recognition", "augment", "wrinkle_waves"), [8.5, 40], "must be integers"),
    ("planning.yaml", ("ik", "damping"), 0.0, "must be > 0"),
    ("planning.yaml", ("collision", "backend"), "ode", "must be one of coal, fcl"),
    ("planning.yaml", ("trajectory", "jerk_scale"), 2.0, "must be <= 1.0"),
    ("planning.yaml", ("motion", "perceive"), [0.0] * 12, "must have 13 numbers"),
    ("planning.yaml", ("grasp", "yaw_offsets"), [], "must not be empty"),
    ("planning.yaml", ("folds", "max_pulls"), -1, "must be >= 0"),
    ("planning.yaml", ("folds", "one_arm_edge_distance"), 0.0, "must be > 0"),
    ("motoros.yaml", ("port",), 70000, "must be <= 65534"),
    ("motoros.yaml", ("dialect",), "ros2", "must be one of"),
    ("camera.yaml", ("fx",), 0.0, "must be > 0"),
    ("camera.yaml", ("distortion",), [0.0, 0.0], "must have 5 numbers"),
    ("camera.yaml", ("mount",), "ceiling", "must be one of fixed, wrist"),
    ("table.yaml", ("near_edge_x",), -0.1, "must be >= 0.0"),
    ("sim.yaml", ("pose", "attempts"), 0, "must be >= 1"),
    ("sim.yaml", ("edges", "collar_spread"), 1.0, "must be <= 0.9"),
    ("sim.yaml", ("dataset", "collared"), "shirt", "must be a list of non-empty strings"),
    ("physics.yaml", ("cloth", "poisson"), 0.6, "must be <= 0.49"),
    ("physics.yaml", ("cloth", "self_friction"), 1.0, "must be at most friction"),
    ("physics.yaml", ("simulation", "solver"), "Jacobi", "must be one of CG, Newton, PGS"),
    ("physics.yaml", ("silhouette", "layer_aera"), 0.01, "unknown field"),
    ("limits.yaml", ("query_rates", QUERY, "burst"), 0, "must be >= 1"),
]


def _write(tmp_path: Path, name: str, keys: tuple[str, ...], value: object = None, *,
           delete: bool = False) -> Path:
    """A copy of the shipped `name` with the value at `keys` set to `value` (or deleted)."""
    data = yaml.safe_load((config_dir() / name).read_text())
    node = data
    for key in keys[:-1]:
        node = node[key]
    if delete:
        del node[keys[-1]]
    else:
        node[keys[-1]] = value
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.mark.parametrize(("name", "keys", "value", "reason"), CASES,
                         ids=[f"{name}:{'.'.join(keys)}" for name, keys, _, _ in CASES])
def test_a_wrong_value_is_refused_naming_file_field_and_reason(tmp_path: Path, name: str,
                                                               keys: tuple[str, ...], value: object,
                                                               reason: str) -> None:
    path = _write(tmp_path, name, keys, value)
    with pytest.raises(ConfigError) as err:
        LOADERS[name](path)
    assert err.value.file == str(path)
    assert err.value.field == ".".join(keys)
    assert reason in err.value.reason
    assert str(err.value).startswith(f"{path}: {'.'.join(keys)}: ")


def test_the_recorders_rejection_bounds_are_refused_naming_the_field(tmp_path: Path) -> None:
    path = _write(tmp_path, "limits.yaml", ("rejected", "head_bytes"), -1)
    with pytest.raises(ConfigError, match=r"rejected\.head_bytes: must be >= 0"):
        load_rejection_bounds(path)


@pytest.mark.parametrize(("name", "section"), [("controller.yaml", "lease"), ("perception.yaml", "folded"),
                                               ("planning.yaml", "folds"), ("physics.yaml", "cloth")])
def test_a_missing_section_is_refused(tmp_path: Path, name: str, section: str) -> None:
    with pytest.raises(ConfigError, match=rf"{name}: {section}: missing"):
        LOADERS[name](_write(tmp_path, name, (section,), delete=True))


def test_a_field_with_a_code_default_is_still_required_in_the_file(tmp_path: Path) -> None:
    """`rule(default=...)` is for code building the dataclass itself, not for a file leaving it out."""
    path = _write(tmp_path, "perception.yaml", ("segmentation", "core_density"), delete=True)
    with pytest.raises(ConfigError, match=r"segmentation\.core_density: missing"):
        load_perception_config(path)


def test_planning_one_arm_edge_distance_stays_optional(tmp_path: Path) -> None:
    path = _write(tmp_path, "planning.yaml", ("folds", "one_arm_edge_distance"), delete=True)
    assert load_planning_config(path).one_arm_edge_distance == float("inf")
