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


def test_perceive_facing_back_mirrors_the_names(shirt_png, capsys: pytest.CaptureFixture) -> None:
    """The same image said to show the garment face down: every name moves to its mirror image
    (the wearer's left is then on the image's left), the points stay."""
    path, _ = shirt_png
    assert run(["perceive", str(path), "--json", "--category", "short-sleeve"]) == 0
    up = json.loads(capsys.readouterr().out)
    assert run(["perceive", str(path), "--json", "--category", "short-sleeve", "--facing", "back"]) == 0
    down = json.loads(capsys.readouterr().out)
    assert up["facing"] == "front" and down["facing"] == "back"
    assert down["landmarks"]["left-shoulder"] == up["landmarks"]["right-shoulder"]
    assert down["landmarks"]["bottom-right"] == up["landmarks"]["bottom-left"]


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


def test_models_learn_reads_face_down_garments_and_real_format_files(tmp_path: Path) -> None:
    """Face-down garments (mirror images whose names stay on the wearer's sides), misspelt names and
    a shirt's collar nodes teach the same model as the face-up garments they mirror."""
    data = tmp_path / "data"
    generate(data, 8, seed=5, progress=False, categories=["short-sleeve"])
    mirrored = tmp_path / "mirrored"
    mirrored.mkdir()
    for path in sorted(data.glob("*.yaml")):
        ann = yaml.safe_load(path.read_text())
        if "node_names" not in ann:
            continue
        ann["facing"] = "back"
        ann["poly_c"] = [[1279.0 - x, y] for x, y in ann["poly_c"]]
        misspelt = [n.replace("right", "rigth").replace("sleeve", "sleave") for (n,) in ann["node_names"]]
        ann["node_names"] = [[n] for n in misspelt]
        ann["node_names"] += [["collar-rigth"]]
        ann["poly_c"] += [[640.0, 100.0]]
        (mirrored / path.name).write_text(yaml.safe_dump(ann, sort_keys=False))
    out_front, out_back = tmp_path / "front", tmp_path / "back"
    assert run(["models", "learn", str(data), "--out-dir", str(out_front)]) == 0
    assert run(["models", "learn", str(mirrored), "--out-dir", str(out_back)]) == 0
    front = yaml.safe_load((out_front / "short-sleeve.yaml").read_text())
    back = yaml.safe_load((out_back / "short-sleeve.yaml").read_text())
    assert [v["name"] for v in back["vertices"]] == [v["name"] for v in front["vertices"]]
    for f, b in zip(front["vertices"], back["vertices"], strict=True):
        assert b["angle_mean"] == pytest.approx(f["angle_mean"], abs=1e-3)
        assert b["edge_length_mean"] == pytest.approx(f["edge_length_mean"], abs=1e-3)
