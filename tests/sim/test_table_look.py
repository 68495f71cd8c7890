"""The simulated table: one look per seed drawn from `table_look`'s ranges; planks, seams, uneven light."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from drivers.camera.model import CameraModel
from drivers.common.configfile import ConfigError, config_dir
from drivers.robot.table import default_table_config
from drivers.sim.config import SimConfig, default_sim_config, load_sim_config
from drivers.sim.render import Appearance, SceneRenderer, draw_table_look, table_texture

CFG = default_sim_config()
LOOK = Appearance(bgr=(40.0, 40.0, 170.0), texture="knit", table_like=False, wrinkled=False, seed=0)


def _with_look(**changes) -> SimConfig:
    return replace(CFG, render=replace(CFG.render, table_look=replace(CFG.render.table_look, **changes)))


def test_the_look_is_drawn_from_its_ranges_by_its_seed() -> None:
    ranges = CFG.render.table_look
    looks = [draw_table_look(replace(ranges, seed=seed)) for seed in range(30)]
    low, high = ranges.wood_bgr
    for look in looks:
        assert all(lo <= v <= hi for v, lo, hi in zip(look.wood_bgr, low, high, strict=True))
        assert ranges.seam_darkness[0] <= look.seam_darkness <= ranges.seam_darkness[1]
        assert ranges.grain_contrast[0] <= look.grain_contrast <= ranges.grain_contrast[1]
    assert draw_table_look(replace(ranges, seed=3)) == looks[3]             # seeded
    assert len({look.wood_bgr for look in looks}) == len(looks)             # and varied


def test_planks_have_seams_and_grain() -> None:
    texture = table_texture(CFG.render, default_table_config()).image
    margin = round(CFG.render.floor_margin / CFG.render.texture_resolution)
    wood = texture[margin:-margin, margin:-margin].mean(axis=2)
    rows = wood.mean(axis=1)          # planks run along the columns: a seam darkens a whole row,
    # sharply (the grain's rings change slowly)
    around = np.minimum(np.roll(rows, 5), np.roll(rows, -5))
    seams = rows < around * (1 - 0.5 * draw_table_look(CFG.render.table_look).seam_darkness)
    plank_rows = np.diff(np.flatnonzero(seams))
    plank_rows = plank_rows[plank_rows > 5] * CFG.render.texture_resolution
    width = CFG.render.table_look.plank_width
    assert len(plank_rows) >= 3 and np.all((plank_rows > 0.9 * width[0]) & (plank_rows < 1.1 * width[1]))
    # grain: the wood varies inside a plank, far beyond sensor noise
    assert np.std(wood[5:40, :]) > 3.0


def test_light_falls_off_by_the_configured_gradient() -> None:
    def illumination(config: SimConfig) -> np.ndarray:
        render = replace(config.render, bright_gain=0.0, exposure_jitter=0.0)
        return SceneRenderer(render, default_table_config(), LOOK, 4, CameraModel()).illum

    flat = illumination(_with_look(light_gradient=(0.0, 0.0), vignette=(0.0, 0.0)))
    ramp = illumination(_with_look(light_gradient=(0.2, 0.2), vignette=(0.0, 0.0)))
    assert np.ptp(flat) < 1e-3 * flat.max()
    assert 0.1 < 1 - ramp.min() / ramp.max() < 0.25
    vignetted = illumination(_with_look(light_gradient=(0.0, 0.0), vignette=(0.4, 0.4)))
    assert vignetted[0, 0] < 0.75 * vignetted[512, 640]


def test_bad_ranges_are_named(tmp_path) -> None:
    data = yaml.safe_load((config_dir() / "sim.yaml").read_text())
    data["table_look"]["wood_bgr"] = [[200, 200, 200], [100, 100, 100]]
    path = tmp_path / "sim.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"table_look\.wood_bgr"):
        load_sim_config(path)
    data["table_look"]["wood_bgr"] = [[100, 100, 100], [200, 200, 200]]
    data["table_look"]["vignette"] = [0.5, 1.5]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r"table_look\.vignette"):
        load_sim_config(path)
