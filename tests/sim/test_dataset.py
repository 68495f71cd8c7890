"""Synthetic datasets: files, CloPeMa keys, determinism, the shared scene PNG, sheet and CLI."""

import argparse
import json

import cv2
import numpy as np
import pytest
import yaml

from cell.perception.annotations import load_annotations
from drivers.common.garments import LANDMARKS, TYPE_TO_CATEGORY
from drivers.common.plane import signed_area
from drivers.sim.dataset import build_world, contact_sheet, generate, render_scene_png
from drivers.sim.errors import SimInputError
from tools import dataset_cli

KEYS = ["path_c", "path_d", "type", "facing", "shape", "node_names", "poly_c", "moves"]


@pytest.fixture(scope="module")
def flat_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("flat")
    generate(d, 4, seed=3, progress=False)
    return d


def test_writes_images_annotations_and_empty_tables(flat_dir):
    names = sorted(p.name for p in flat_dir.iterdir())
    assert names == ["long-sleeve_0003.png", "long-sleeve_0003.yaml", "pants_0001.png", "pants_0001.yaml",
                     "provenance.json", "short-sleeve_0002.png", "short-sleeve_0002.yaml", "table_0000.png",
                     "towel_0000.png", "towel_0000.yaml"]
    made = json.loads((flat_dir / "provenance.json").read_text())
    assert made["seed"] == 3 and made["count"] == 4 and made["generated_by"] == "foldcell dataset generate"
    for y in flat_dir.glob("*.yaml"):
        ann = yaml.safe_load(y.read_text())
        assert list(ann) == KEYS
        assert ann["path_c"] == y.with_suffix(".png").name and ann["path_d"] == y.stem + "_depth.png"
        assert ann["facing"] in ("front", "back")
        assert ann["shape"] in ("flat", "wrinkled") and ann["moves"] == []
        assert all(len(n) == 1 for n in ann["node_names"]) and len(ann["poly_c"]) == len(ann["node_names"])
        img = cv2.imread(str(flat_dir / ann["path_c"]))
        assert img.shape == (1024, 1280, 3)
        pts = np.array(ann["poly_c"])
        assert np.all((pts >= 0) & (pts <= [1279, 1023]))
    assert yaml.safe_load((flat_dir / "short-sleeve_0002.yaml").read_text())["type"] in ("tshirt", "polo")


def test_annotation_matches_the_world_truth(flat_dir):
    ann = yaml.safe_load((flat_dir / "pants_0001.yaml").read_text())
    w = build_world(4, "pants", placement="table")
    names, pts = w.annotated_nodes()
    assert [n[0] for n in ann["node_names"]] == names == list(LANDMARKS["pants"])
    assert ann["facing"] == w.facing
    assert np.allclose(ann["poly_c"], w.camera.table_to_pixel(pts), atol=1e-3)


def _seen_in_pixels(world):
    names, points = world.truth_polygon()
    return dict(zip(names, world.camera.table_to_pixel(points), strict=True))


def test_annotations_round_trip_through_the_annotation_reader(tmp_path):
    """What the sim writes, read back as the dataset is read: the wearer's sides as written, the
    cell's (face-up) naming from `landmarks_as_seen`, clockwise model points for either facing,
    collars where the type has one."""
    generate(tmp_path, 24, seed=40, progress=False)
    facings, collars = set(), {}
    for path, record in load_annotations(tmp_path):
        i = int(path.stem.split("_")[-1])
        world = build_world(40 + i, record.category, placement="table")
        facings.add(record.facing)
        assert record.facing == world.facing and record.shape == world.shape
        assert TYPE_TO_CATEGORY[record.type] == record.category
        truth = dict(zip(*world.annotated_nodes(), strict=True))
        for name, point in record.nodes:
            assert np.allclose(point, world.camera.table_to_pixel(truth[name][None])[0], atol=1e-2)
        seen = _seen_in_pixels(world)
        for name, point in record.landmarks_as_seen().items():
            if name in seen:
                assert np.allclose(point, seen[name], atol=1e-2), (path.name, name)
        assert signed_area(record.model_points()) > 0, path.name     # clockwise on screen, as seen
        if record.category in ("short-sleeve", "long-sleeve"):
            names = [name for name, _ in record.nodes]
            collars[record.type] = "collar-left" in names
            assert "neckline-left" in names and "neckline-right" in names
    assert facings == {"front", "back"}
    assert len(collars) >= 3 and all(has == (kind in ("polo", "shirt")) for kind, has in collars.items())


def test_folded_annotations_are_written_as_the_dataset_writes_them(tmp_path):
    generate(tmp_path, 8, seed=8, folded=True, progress=False)
    for path, record in load_annotations(tmp_path):
        folds = record.fold_lines
        assert len(folds) == len(record.moves) // 2 >= 1, path.name
        # every original node is still there, where it now lies
        names = [name for name, _ in record.nodes if not name.startswith("fold_")]
        assert set(LANDMARKS[record.category]) <= set(names)
        assert record.flat_landmarks is not None
        assert set(record.flat_landmarks) == set(LANDMARKS[record.category])


def test_scene_png_is_the_written_file_byte_for_byte(flat_dir):
    assert render_scene_png(3, "towel", placement="table") == (flat_dir / "towel_0000.png").read_bytes()
    assert (render_scene_png(5, "short-sleeve", placement="table")
            == (flat_dir / "short-sleeve_0002.png").read_bytes())


def test_generation_is_deterministic(flat_dir, tmp_path):
    generate(tmp_path, 4, seed=3, progress=False)
    for p in flat_dir.iterdir():
        if p.name != "provenance.json":   # it says when
            assert (tmp_path / p.name).read_bytes() == p.read_bytes(), p.name


def test_folded_dataset_has_flat_landmarks_and_moves(tmp_path):
    generate(tmp_path, 4, seed=8, folded=True, progress=False)
    for y in tmp_path.glob("*.yaml"):
        ann = yaml.safe_load(y.read_text())
        assert ann["shape"] == "folded"
        assert len(ann["moves"]) >= 2 and all(len(m) == 4 for m in ann["moves"])
        assert "poly_c_flat" in ann and len(ann["poly_c_flat"]) == len(ann["node_names_flat"])
        assert any(n[0].startswith("fold") for n in ann["node_names"])
        # each move's grasp point is on the flat garment's landmark polygon or inside it
        assert len(ann["node_names"]) >= 3


def test_contact_sheet_is_a_grid(flat_dir, tmp_path):
    out = contact_sheet(flat_dir, tmp_path / "sheet.png", tiles=16, columns=4, tile_width=320)
    sheet = cv2.imread(str(out))
    assert sheet.shape == (256, 1280, 3)
    with pytest.raises(SimInputError, match="DIR"):
        contact_sheet(tmp_path / "missing", tmp_path / "x.png")


def test_bad_arguments_are_named(tmp_path):
    with pytest.raises(SimInputError, match="count"):
        generate(tmp_path, 0, seed=1, progress=False)
    with pytest.raises(SimInputError, match="categories"):
        generate(tmp_path, 1, seed=1, categories=["hat"], progress=False)


def _parser():
    p = argparse.ArgumentParser(prog="foldcell")
    dataset_cli.register(p.add_subparsers())
    return p


def test_cli_generate_json_and_errors(tmp_path, capsys):
    p = _parser()
    args = p.parse_args(["dataset", "generate", str(tmp_path / "d"), "--count", "2", "--seed", "4",
                         "--categories", "towel", "--json"])
    assert args.func(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [n.split("/")[-1] for n in doc["images"]] == ["towel_0000.png", "towel_0001.png", "table_0000.png"]
    args = p.parse_args(["dataset", "generate", str(tmp_path / "e"), "--count", "0"])
    assert args.func(args) == 2
    assert capsys.readouterr().err.startswith("foldcell: error: --count")
    with pytest.raises(SystemExit) as exc:
        p.parse_args(["dataset", "generate", str(tmp_path), "--count", "1", "--categories", "hat"])
    assert exc.value.code == 2
    args = p.parse_args(["dataset", "sheet", str(tmp_path / "nothing"), "--output", str(tmp_path / "s.png")])
    assert args.func(args) == 2
    assert "foldcell: error: DIR" in capsys.readouterr().err
