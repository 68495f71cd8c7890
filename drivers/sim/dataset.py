"""Synthetic datasets in the CloPeMa annotation format, and the one scene-to-PNG function that the
dataset writer and the camera share (so a capture equals the written file byte for byte).

Image i of `generate(seed=S)` is the scene `S + i` of category `categories[i % len(categories)]`.
"""

from __future__ import annotations

import datetime as dt
import json
import logging
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np
import yaml
from tqdm import tqdm

from drivers.camera.model import CameraModel
from drivers.common.configfile import yaml_problem
from drivers.common.garments import CATEGORIES
from drivers.common.labels import LabelStyle, draw_labels
from drivers.sim.config import SimConfig, default_sim_config
from drivers.sim.errors import SimInputError
from drivers.sim.folding import recipe_moves
from drivers.sim.render import encode_png
from drivers.sim.world import GarmentWorld, Move

log = logging.getLogger(__name__)

SHEET_LABEL_STYLE = LabelStyle(scale=0.33, padding=1)    # a contact sheet's landmark names
SHEET_HEADER_STYLE = LabelStyle(scale=0.5)               # and each tile's file, type and shape


def recipe_folds(world: GarmentWorld, count: int) -> list[list[Move]]:
    """Up to `count` two-arm folds of the paper's recipes for the world's garment (`recipe_moves`)."""
    assert world.category is not None   # chosen when the world is made
    return recipe_moves(world.category, dict(zip(*world.flat_polygon(), strict=True)))[:count]


def scene_type(seed: int, category: str, config: SimConfig) -> str:
    """The dataset `type` of scene `seed` (a tshirt or a polo, a shirt or a sweater...), drawn from the
    seed alone."""
    types = config.dataset.types_of(category)
    return types[int(np.random.default_rng([seed, 2]).integers(len(types)))]


def build_world(seed: int, category: str, folded: bool = False,
                config: SimConfig | None = None, placement: str = "cell",
                folding: str = "geometric") -> GarmentWorld:
    """The scene of a seed: the garment, folded by the recipe (1..max folds) when `folded`; placed
    where the cell's scenes keep to (`"cell"`) or anywhere in view (`"table"`, for datasets). A polo's
    or a shirt's collar (`scene_type`, `dataset.collared`) stands above its neckline."""
    cfg = config or default_sim_config()
    world = GarmentWorld(seed=seed, category=category, config=cfg, placement=placement, folding=folding,
                         collared=scene_type(seed, category, cfg) in cfg.dataset.collared)
    if folded:
        rng = np.random.default_rng([seed, 1])
        n = int(rng.integers(1, cfg.dataset.folds_of(category) + 1))
        for moves in recipe_folds(world, n):
            world.apply_fold(moves)
    return world


def render_scene_png(seed: int, category: str, folded: bool = False,
                     config: SimConfig | None = None, placement: str = "cell") -> bytes:
    """PNG bytes of scene `seed` (the one function the dataset writer and the sim camera share)."""
    cfg = config or default_sim_config()
    world = build_world(seed, category, folded, cfg, placement)
    return encode_png(world.render(), cfg.render.png_compression)


def depth_image_name(image_name: str) -> str:
    """The name the depth image of `image_name` would have (the dataset pairs cloC<id> with cloD<id>;
    the sim renders no depth)."""
    path = Path(image_name)
    return f"{path.stem}_depth{path.suffix}"


def _pixels(camera: CameraModel, points: np.ndarray) -> list[list[float]]:
    return [[round(float(x), 3), round(float(y), 3)] for x, y in camera.table_to_pixel(points)]


def annotation(world: GarmentWorld, image_name: str, dataset_type: str) -> dict:
    """A CloPeMa-format annotation of the world's current state (pixels of its camera).

    Written as the dataset writes it: `node_names` one-element lists, in the dataset's order; a folded
    garment's nodes are every original node where it now lies and each fold line's two ends named
    `fold_<k>` (not an outline). foldcell's own keys for scoring folded images: `node_names_flat` and
    `poly_c_flat` (the flat garment before folding) and `moves`, each fold's grasp -> place in pixels.
    """
    camera = world.camera
    assert camera is not None
    names, points = world.annotated_nodes()
    if dataset_type not in world.config.dataset.collared:
        # a garment without a collar has only the neckline's ends annotated
        keep = [not name.startswith("collar-") for name in names]
        names = [name for name, kept in zip(names, keep, strict=True) if kept]
        points = points[np.array(keep, dtype=bool)]
    folded = bool(world.history)
    record: dict = {
        "path_c": image_name,
        "path_d": depth_image_name(image_name),
        "type": dataset_type,
        "facing": world.facing,
        "shape": "folded" if folded else world.shape,
        "node_names": [[name] for name in names],
        "poly_c": _pixels(camera, points),
        "moves": [[round(float(v), 3) for v in np.concatenate([camera.table_to_pixel(grasp)[0],
                                                               camera.table_to_pixel(place)[0]])]
                  for fold in world.history for grasp, place in fold.moves],
    }
    if folded:
        # the flat garment's model landmarks, named by the garment's own sides like `node_names`
        record["node_names_flat"] = [[name] for name in world.garment.names]
        record["poly_c_flat"] = _pixels(camera, world.garment.landmarks)
    return record


def _check_categories(categories: Sequence[str] | None) -> tuple[str, ...]:
    cats = tuple(categories) if categories else CATEGORIES
    for c in cats:
        if c not in CATEGORIES:
            raise SimInputError(f"categories: unknown category {c!r} (choose from {', '.join(CATEGORIES)})")
    return cats


def generate(out_dir: str | Path, count: int, seed: int, categories: Sequence[str] | None = None,
             folded: bool = False, progress: bool = True, config: SimConfig | None = None) -> list[Path]:
    """Write `count` garment images with annotation YAML beside them, plus empty-table images.

    Returns the written image paths. Deterministic for a seed.
    """
    cfg = config or default_sim_config()
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise SimInputError(f"count: must be a positive integer, got {count!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise SimInputError(f"seed: must be a non-negative integer, got {seed!r}")
    cats = _check_categories(categories)
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SimInputError(f"out_dir: cannot create {out}: {exc.strerror or exc}") from exc
    n_empty = max(1, count // cfg.dataset.empty_table_every)
    written: list[Path] = []
    with tqdm(total=count + n_empty, desc="dataset", unit="img", disable=not progress) as bar:
        for i in range(count):
            category = cats[i % len(cats)]
            world = build_world(seed + i, category, folded, cfg, placement="table")
            dataset_type = scene_type(seed + i, category, cfg)
            name = f"{category}_{i:04d}.png"
            png = encode_png(world.render(), cfg.render.png_compression)   # as render_scene_png
            (out / name).write_bytes(png)
            with open(out / f"{category}_{i:04d}.yaml", "w") as file:
                yaml.safe_dump(annotation(world, name, dataset_type), file, sort_keys=False,
                               default_flow_style=None)
            written.append(out / name)
            bar.update(1)
        for j in range(n_empty):
            world = GarmentWorld(seed=seed + count + j, category=cats[0], config=cfg)
            path = out / f"table_{j:04d}.png"
            path.write_bytes(encode_png(world.render_empty_table(), cfg.render.png_compression))
            written.append(path)
            bar.update(1)
    write_provenance(out, {"generated_by": "foldcell dataset generate", "count": count, "seed": seed,
                           "categories": list(cats), "folded": folded})
    log.info("wrote %d images to %s", len(written), out)
    return written


PROVENANCE_FILE = "provenance.json"


def write_provenance(out_dir: Path, what: dict) -> Path:
    """Record how a dataset folder was made (`PROVENANCE_FILE`: its arguments and the date), for
    whatever is learned from it to say so."""
    record = {**what, "date": dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")}
    path = out_dir / PROVENANCE_FILE
    path.write_text(json.dumps(record, indent=1) + "\n")
    return path


def contact_sheet(directory: str | Path, out: str | Path, tiles: int = 16, columns: int = 4,
                  tile_width: int = 480) -> Path:
    """A grid of the folder's annotated images with their polygons, landmark names and moves drawn."""
    folder = Path(directory)
    if not folder.is_dir():
        raise SimInputError(f"DIR: {folder} is not a directory")
    annotation_files = sorted(folder.glob("*.yaml"))
    if not annotation_files:
        raise SimInputError(f"DIR: no annotation YAML files in {folder}")
    imgs = []
    for path in annotation_files[:tiles]:
        try:
            data = yaml.safe_load(path.read_text())
        except yaml.YAMLError as exc:
            raise SimInputError(f"DIR: {path.name}: not valid YAML: {yaml_problem(exc)}") from exc
        if not isinstance(data, dict) or "path_c" not in data:
            raise SimInputError(f"DIR: {path.name}: not an annotation (no path_c)")
        img = cv2.imread(str(folder / data["path_c"]))
        if img is None:
            raise SimInputError(f"DIR: cannot read image {data['path_c']} named in {path.name}")
        h, w = img.shape[:2]
        scale = tile_width / w
        img = cv2.resize(img, (tile_width, round(h * scale)), interpolation=cv2.INTER_AREA)
        pts = np.array(data["poly_c"], dtype=float) * scale
        cv2.polylines(img, [np.round(pts * 16).astype(np.int32).reshape(-1, 1, 2)], True, (0, 255, 255), 1,
                      cv2.LINE_AA, shift=4)
        for move in data.get("moves", []):
            arrow = np.array(move, dtype=float) * scale
            tail, head = (int(arrow[0]), int(arrow[1])), (int(arrow[2]), int(arrow[3]))
            cv2.arrowedLine(img, tail, head, (255, 0, 255), 1, cv2.LINE_AA, tipLength=0.08)
        for x, y in pts:
            cv2.circle(img, (round(x), round(y)), 3, (0, 0, 255), -1, cv2.LINE_AA)
        header = draw_labels(img, [f"{path.stem}  {data['type']}  {data['shape']}"], [(0, 0)],
                             SHEET_HEADER_STYLE)
        garment = np.zeros(img.shape[:2], np.uint8)
        cv2.fillPoly(garment, [np.round(pts).astype(np.int32).reshape(-1, 1, 2)], 1)
        draw_labels(img, [name for (name,) in data["node_names"]], [tuple(p) for p in pts], SHEET_LABEL_STYLE,
                    gap=3, obstacles=header, away_from=tuple(pts.mean(axis=0)), keep_off=garment.astype(bool))
        imgs.append(img)
    blank = np.zeros_like(imgs[0])
    while len(imgs) % columns:
        imgs.append(blank)
    rows = [np.hstack(imgs[i:i + columns]) for i in range(0, len(imgs), columns)]
    sheet = np.vstack(rows)
    out = Path(out)
    if not cv2.imwrite(str(out), sheet, [cv2.IMWRITE_PNG_COMPRESSION, 9]):
        raise SimInputError(f"-o/--output: cannot write {out}")
    return out
