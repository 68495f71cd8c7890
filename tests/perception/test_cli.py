"""perception CLI: perceive --json, table fit, models learn, eval, and clean errors."""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from drivers.common.configfile import config_dir
from drivers.sim.dataset import generate
from tests.perception.scenes import ClothScene, garment_scene, random_garment
from tools.perception_cli import register, write_model_file


def run(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(prog="foldcell")
    register(ap.add_subparsers())
    args = ap.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def own_config(tmp_path_factory: pytest.TempPathFactory, fitted_perception) -> Path:
    """A copy of config/ with the garment and table models fitted by this test run (`fitted_perception`)."""
    cfg = tmp_path_factory.mktemp("cfg") / "config"
    shutil.copytree(config_dir(), cfg)
    _, table, models = fitted_perception
    for category, model in models.items():
        write_model_file(cfg / "garments" / f"{category}.yaml", model)
    (cfg / "perception" / "table_gmm.yaml").write_text(yaml.safe_dump(table.to_dict(), sort_keys=False))
    return cfg


@pytest.fixture(autouse=True)
def _use_own_config(own_config: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FOLDCELL_CONFIG_DIR", str(own_config))


@pytest.fixture(scope="module")
def shirt_png(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    scene = garment_scene("short-sleeve", 21)
    path = tmp_path_factory.mktemp("img") / "shirt.png"
    cv2.imwrite(str(path), scene.image)
    return path, scene.garment


def test_perceive_json(shirt_png, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    path, garment = shirt_png
    overlay = tmp_path / "o.png"
    assert run(["perceive", str(path), "--json", "--overlay", str(overlay)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["category"] == "short-sleeve"
    assert set(out) >= {"category", "landmarks", "polygon", "cost", "timings_ms"}
    assert set(out["timings_ms"]) == {"segment", "simplify", "match", "total"}
    # milliseconds: a whole perception takes tens of them
    stages = sum(out["timings_ms"][k] for k in ("segment", "simplify", "match"))
    assert out["timings_ms"]["total"] == pytest.approx(stages, abs=0.01)
    assert 1.0 < out["timings_ms"]["total"] < 60_000
    truth = garment.truth()
    errs = [np.linalg.norm(np.subtract(out["landmarks"][n], truth[n])) for n in garment.names]
    assert np.median(errs) < 3.0
    assert cv2.imread(str(overlay)) is not None


def test_bad_inputs_give_clean_errors(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    assert run(["perceive", str(tmp_path / "missing.png")]) == 2
    assert "foldcell: error:" in capsys.readouterr().err
    empty = tmp_path / "empty.png"
    empty.write_bytes(b"")
    assert run(["perceive", str(empty)]) == 2
    assert "cannot decode" in capsys.readouterr().err
    gray = tmp_path / "gray.png"
    cv2.imwrite(str(gray), cv2.cvtColor(garment_scene("towel", 2).image, cv2.COLOR_BGR2GRAY))
    assert run(["perceive", str(gray)]) == 2
    assert "grayscale" in capsys.readouterr().err
    scene = ClothScene(light_seed=2)
    table = tmp_path / "table.png"
    cv2.imwrite(str(table), scene.render(None))
    assert run(["perceive", str(table)]) == 1
    assert "no garment" in capsys.readouterr().err.lower()
    outline = random_garment("towel", np.random.default_rng(2)).outline
    border = tmp_path / "border.png"
    cv2.imwrite(str(border), scene.render(outline - outline.min(axis=0) + [-20, 100]))
    assert run(["perceive", str(border)]) == 1
    assert "border" in capsys.readouterr().err


def test_model_file_with_missing_field(shirt_png, tmp_path: Path,
                                      monkeypatch: pytest.MonkeyPatch,
                                      capsys: pytest.CaptureFixture) -> None:
    cfg = tmp_path / "config"
    shutil.copytree(config_dir(), cfg)   # config_dir() is the test's own copy here
    f = cfg / "garments" / "pants.yaml"
    data = yaml.safe_load(f.read_text())
    del data["simplify_vertices"]
    f.write_text(yaml.safe_dump(data))
    monkeypatch.setenv("FOLDCELL_CONFIG_DIR", str(cfg))
    assert run(["perceive", str(shirt_png[0])]) == 2
    err = capsys.readouterr().err
    assert "pants.yaml: simplify_vertices: missing" in err and "Traceback" not in err


def test_learn_fit_eval_round_trip(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                   capsys: pytest.CaptureFixture) -> None:
    cfg = tmp_path / "config"
    shutil.copytree(config_dir(), cfg)
    (cfg / "garments" / "towel.yaml").write_text(
        (cfg / "garments" / "towel.yaml").read_text() + "recipe:\n  folds: [half]\n")
    monkeypatch.setenv("FOLDCELL_CONFIG_DIR", str(cfg))
    data = tmp_path / "data"
    generate(data, 8, seed=3, progress=False)   # two garments of each category, two empty tables
    assert run(["models", "learn", str(data)]) == 0
    assert yaml.safe_load((cfg / "garments" / "towel.yaml").read_text())["recipe"] == {"folds": ["half"]}
    tm = tmp_path / "tm.yaml"
    assert run(["table", "fit", "--annotations", str(data), "--out", str(tm)]) == 0
    assert run(["table", "fit", str(data / "table_0000.png"), "--out", str(tm)]) == 0
    capsys.readouterr()
    assert run(["eval", str(data), "--table-model", str(tm), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert set(rep["categories"]) == {"towel", "pants", "short-sleeve", "long-sleeve"}
    for r in rep["categories"].values():
        assert r["images"] == 2 and r["cm"]["median"] < 1.0
    assert len(rep["images"]) == 8 and not rep["unreadable"]
    # a broken image file is reported and skipped; the rest is still evaluated
    broken = sorted(data.glob("towel_*.png"))[0]
    broken.write_bytes(b"not a png")
    capsys.readouterr()
    assert run(["eval", str(data), "--table-model", str(tm), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["unreadable"] == [broken.with_suffix(".yaml").name]
    assert rep["categories"]["towel"]["images"] == 1
