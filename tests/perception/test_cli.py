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
from numpy.typing import NDArray

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
    assert set(out["timings_ms"]) == {"segment", "simplify", "match", "recognise", "total"}
    assert set(out["probabilities"]) == {"towel", "pants", "short-sleeve", "long-sleeve"}
    assert sum(out["probabilities"].values()) == pytest.approx(1.0, abs=1e-3)
    assert out["confidence"] == out["probabilities"]["short-sleeve"] == max(out["probabilities"].values())
    # milliseconds: a whole perception takes tens of them
    stages = sum(out["timings_ms"][k] for k in ("segment", "simplify", "match", "recognise"))
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
    assert up["confidence"] is None and up["probabilities"] == {}    # the category was given
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
    white = tmp_path / "white.png"
    cv2.imwrite(str(white), np.full((480, 640, 3), 255, np.uint8))
    assert run(["perceive", str(white)]) == 2
    assert "every pixel has the same colour (RGB 255, 255, 255)" in capsys.readouterr().err
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


def _disc(radius: float) -> NDArray:
    angles = np.linspace(0, 2 * np.pi, 90, endpoint=False)
    return np.c_[640 + radius * np.cos(angles), 512 + radius * np.sin(angles)]


@pytest.mark.parametrize(("shape", "category", "cause"), [
    # a bar fits no model: the pants model fitted to it, for one, is far off
    ("bar", "pants", "the pants model fits it badly"),
    # a disc is nearly as good a towel as a towel, but the recogniser cannot tell which garment it is
    ("disc", None, "the recognition is unsure"),
])
def test_strict_perceive_says_a_shape_that_is_no_garment_is_none(
        tmp_path: Path, capsys: pytest.CaptureFixture, shape: str, category: str | None, cause: str) -> None:
    bar = np.array([[340, 462], [940, 462], [940, 562], [340, 562]], float)
    outline = bar if shape == "bar" else _disc(220)
    path = tmp_path / f"{shape}.png"
    cv2.imwrite(str(path), ClothScene(light_seed=3).render(outline))
    argv = ["perceive", str(path), "--json"] + (["--category", category] if category else [])
    assert run(argv) == 0   # said, not refused, without --strict
    captured = capsys.readouterr()
    assert cause in json.loads(captured.out)["doubt"], captured.out
    assert f"foldcell: maybe not a garment: {cause}" in captured.err, captured.err
    assert run([*argv, "--strict"]) == 1
    assert f"foldcell: not a garment: {cause}" in capsys.readouterr().err


def test_strict_perceive_takes_a_garment_for_one(shirt_png, capsys: pytest.CaptureFixture) -> None:
    assert run(["perceive", str(shirt_png[0]), "--strict", "--json"]) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)["doubt"] is None and "garment" not in captured.err, captured


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
    shipped = (cfg / "garments" / "towel.yaml").read_text()
    assert run(["models", "learn", str(data), "-o", str(cfg / "garments")]) == 2   # the shipped ones: no
    assert "--force" in capsys.readouterr().err and (cfg / "garments" / "towel.yaml").read_text() == shipped
    assert run(["models", "learn", str(data), "-o", str(cfg / "garments"), "--force", "--json"]) == 0
    learned = json.loads(capsys.readouterr().out)
    assert learned["models"]["towel"] == {"polygons": 2, "file": str(cfg / "garments" / "towel.yaml")}
    assert yaml.safe_load((cfg / "garments" / "towel.yaml").read_text())["recipe"] == {"folds": ["half"]}
    tm = tmp_path / "tm.yaml"
    assert run(["table", "fit", "--annotations", str(data), "--output", str(tm), "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == {"output": str(tm), "images": 8}
    assert run(["table", "fit", str(data / "table_0000.png"), "--output", str(tm)]) == 0
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
    """Mirror images of the garments, turned over (face up <-> face down, names staying on the
    wearer's sides), with misspelt names (`collar-rigth` among them), teach the same model and the
    same collared variant (from the polos, whose collar nodes are annotated)."""
    data = tmp_path / "data"
    generate(data, 8, seed=5, progress=False, categories=["short-sleeve"])
    mirrored = tmp_path / "mirrored"
    mirrored.mkdir()
    for path in sorted(data.glob("*.yaml")):
        ann = yaml.safe_load(path.read_text())
        if "node_names" not in ann:
            continue
        ann["facing"] = {"front": "back", "back": "front"}[ann["facing"]]
        ann["poly_c"] = [[1279.0 - x, y] for x, y in ann["poly_c"]]
        misspelt = [n.replace("right", "rigth").replace("sleeve", "sleave") for (n,) in ann["node_names"]]
        ann["node_names"] = [[n] for n in misspelt]
        (mirrored / path.name).write_text(yaml.safe_dump(ann, sort_keys=False))
    out_front, out_back = tmp_path / "front", tmp_path / "back"
    assert run(["models", "learn", str(data), "--output", str(out_front)]) == 0
    assert run(["models", "learn", str(mirrored), "--output", str(out_back)]) == 0
    front = yaml.safe_load((out_front / "short-sleeve.yaml").read_text())
    back = yaml.safe_load((out_back / "short-sleeve.yaml").read_text())
    assert "collar-right" in [v["name"] for v in front["collared"]["vertices"]]
    for learned_front, learned_back in ((front, back), (front["collared"], back["collared"])):
        assert [v["name"] for v in learned_back["vertices"]] == [v["name"] for v in learned_front["vertices"]]
        for f, b in zip(learned_front["vertices"], learned_back["vertices"], strict=True):
            assert b["angle_mean"] == pytest.approx(f["angle_mean"], abs=1e-3)
            assert b["edge_length_mean"] == pytest.approx(f["edge_length_mean"], abs=1e-3)


@pytest.fixture(scope="module")
def eight_garments(tmp_path_factory: pytest.TempPathFactory) -> Path:
    data = tmp_path_factory.mktemp("recognise")
    generate(data, 8, seed=60, progress=False)   # two garments of each category
    return data


def _types(data: Path) -> dict[str, str]:
    """Annotation file -> category, read from the files themselves."""
    from drivers.common.garments import TYPE_TO_CATEGORY
    return {p.name: TYPE_TO_CATEGORY[yaml.safe_load(p.read_text())["type"]] for p in data.glob("*.yaml")}


def test_eval_recognise_prints_a_confusion_matrix(eight_garments: Path,
                                                  capsys: pytest.CaptureFixture) -> None:
    truth = _types(eight_garments)
    assert run(["eval", str(eight_garments), "--recognise", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["columns"] == ["towel", "pants", "short-sleeve", "long-sleeve", "failed"]
    assert {row: sum(cells.values()) for row, cells in report["confusion"].items()} == \
        dict.fromkeys(("towel", "pants", "short-sleeve", "long-sleeve"), 2)
    recognised = {i["file"]: i["recognised"] for i in report["per_image"]}
    assert {i["file"]: i["truth"] for i in report["per_image"]} == truth
    right = sum(recognised[f] == truth[f] for f in truth)
    assert report["correct"] == right and report["accuracy"] == pytest.approx(right / 8)
    assert right == 8, recognised
    for image in report["per_image"]:
        assert report["confusion"][image["truth"]][image["recognised"]] >= 1
        assert 0.25 < image["confidence"] <= 1.0
    assert run(["eval", str(eight_garments), "--recognise"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split()[-6:] == ["towel", "pants", "short-sleeve", "long-sleeve", "failed", "recall"]
    rows = {line.split()[0]: line.split()[1:] for line in lines[1:5]}
    for category, cells in report["confusion"].items():
        assert rows[category] == [str(cells[c]) for c in report["columns"]] + [f"{cells[category]}/2"]
    assert lines[5] == "accuracy 100.0% (8 of 8 images)"


def test_learn_recognition_writes_a_recogniser_with_its_provenance(eight_garments: Path, tmp_path: Path,
                                                                   capsys: pytest.CaptureFixture) -> None:
    from cell.perception.recognition import recogniser_from_fields
    from drivers.common.configfile import load_yaml
    out = tmp_path / "recognition.yaml"
    assert run(["models", "learn-recognition", str(eight_garments), "--output", str(out), "--json",
                "--note", "eight garments"]) == 0
    summary = json.loads(capsys.readouterr().out)
    settings = yaml.safe_load((config_dir() / "perception.yaml").read_text())["recognition"]
    augmentations = settings["augmentations"]
    assert summary["examples"] == 8 and summary["output"] == str(out)
    # every outline and its augmented copies, unless a copy was too thin to match
    assert all(2 <= n <= 2 * (1 + augmentations) for n in summary["samples"].values())
    recogniser = recogniser_from_fields(load_yaml(out))
    assert recogniser.categories == ("towel", "pants", "short-sleeve", "long-sleeve")
    provenance = recogniser.provenance
    assert provenance["data"] == [str(eight_garments.resolve())] and provenance["note"] == "eight garments"
    assert provenance["command"] == f"foldcell models learn-recognition {eight_garments}"
    assert provenance["seed"] == 0 and provenance["date"].endswith("Z")
    assert run(["models", "learn-recognition", str(tmp_path), "--output", str(out)]) == 2
    assert "no usable annotated images" in capsys.readouterr().err


def test_overlay_shows_the_wearer_s_left_on_the_image_s_right_of_a_face_up_garment(tmp_path: Path) -> None:
    """The overlay's colours follow the dataset's convention: on upright face-up pants the dots
    coloured as the wearer's left lie right of those coloured as the wearer's right."""
    from dataclasses import replace as replace_config

    from drivers.sim.config import default_sim_config
    from drivers.sim.dataset import build_world
    from tools.overlay import WEARER_LEFT_BGR, WEARER_RIGHT_BGR
    sim = default_sim_config()
    sim = replace_config(sim, pose=replace_config(sim.pose, rotation=0.1, face_down=0.0))
    image_path, overlay_path = tmp_path / "pants.png", tmp_path / "overlay.png"
    cv2.imwrite(str(image_path), build_world(5, "pants", config=sim).render())
    assert run(["perceive", str(image_path), "--overlay", str(overlay_path)]) == 0
    drawn = cv2.imread(str(overlay_path))
    drawn[:200] = 0                                                    # the legend
    left = np.argwhere(np.all(drawn == WEARER_LEFT_BGR, axis=2))
    right = np.argwhere(np.all(drawn == WEARER_RIGHT_BGR, axis=2))
    assert len(left) > 100 and len(right) > 100                        # dots of both sides drawn
    assert left[:, 1].mean() > right[:, 1].mean() + 100


def test_eval_with_the_category_unknown_scores_landmarks_of_recognised_garments(
        eight_garments: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """Table I with the category not given: every garment recognised is scored as with it given; one
    whose annotation says another category counts as a failure, named."""
    assert run(["eval", str(eight_garments), "--category-unknown", "--json"]) == 0
    unknown = json.loads(capsys.readouterr().out)
    assert run(["eval", str(eight_garments), "--json"]) == 0
    given = json.loads(capsys.readouterr().out)
    for category, result in unknown["categories"].items():
        assert result["images"] == 2 and result["segmentation_failures"] == 0
        as_given = given["categories"][category]["cm"]["median"]
        assert result["cm"]["median"] == pytest.approx(as_given, abs=0.05)
    relabelled = tmp_path / "relabelled"
    shutil.copytree(eight_garments, relabelled)
    pants = sorted(relabelled.glob("pants_*.yaml"))[0]
    record = yaml.safe_load(pants.read_text())
    record["type"] = "towel"
    record["node_names"] = [["bottom-left"], ["bottom-right"], ["top-right"], ["top-left"]]
    record["poly_c"] = record["poly_c"][:4]
    pants.write_text(yaml.safe_dump(record))
    assert run(["eval", str(relabelled), "--category-unknown", "--json"]) == 0
    towel = json.loads(capsys.readouterr().out)["categories"]["towel"]
    assert towel["images"] == 3 and towel["segmentation_failures"] == 1
    assert run(["eval", str(relabelled), "--json"]) == 0          # given, the same file is scored as a towel
    assert json.loads(capsys.readouterr().out)["categories"]["towel"]["segmentation_failures"] == 0
