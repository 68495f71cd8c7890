"""CLI of garment perception: `perceive`, `table fit`, `models learn`, `eval`."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from drivers.common.configfile import ConfigError

log = logging.getLogger(__name__)


class _UsageError(Exception):
    pass


def _fail(msg: str, code: int) -> int:
    print(f"foldcell: error: {msg}", file=sys.stderr)
    return code


def _guard(fn):  # noqa: ANN001 - wraps a handler, maps typed errors to exit codes
    def run(args: argparse.Namespace) -> int:
        from cell.perception.annotations import AnnotationError
        from cell.perception.errors import ImageError, ModelError, PerceptionError
        try:
            return fn(args)
        except (_UsageError, ConfigError, ImageError, ModelError, AnnotationError) as exc:
            return _fail(str(exc), 2)
        except PerceptionError as exc:
            return _fail(str(exc), 1)
    return run


def read_image(path: str | Path) -> np.ndarray:
    from cell.perception.errors import ImageError
    p = Path(path)
    if not p.is_file():
        raise ImageError(f"{p}: no such image file")
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None or img.size == 0:
        raise ImageError(f"{p}: cannot decode the image (unreadable or empty)")
    sample = img[::4, ::4]
    if not np.any(sample[..., 0] != sample[..., 1]) and not np.any(sample[..., 1] != sample[..., 2]):
        raise ImageError(f"{p}: a grayscale image; perception needs colour (the table model is a colour model)")
    return img


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("perceive", help="find the garment, its category and landmarks in an image")
    p.add_argument("image", help="colour image of the table seen from above")
    p.add_argument("--category", help="match only this model (towel, pants, short-sleeve, long-sleeve)")
    p.add_argument("--table-model", help="table colour model YAML (default: from config/perception.yaml)")
    p.add_argument("--overlay", help="write the image with the polygon and landmarks drawn to this PNG")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=_guard(cmd_perceive))

    t = subparsers.add_parser("table", help="table colour model")
    tsub = t.add_subparsers(dest="table_command", required=True)
    tf = tsub.add_parser("fit", help="fit the table colour GMM from empty-table or annotated images")
    tf.add_argument("images", nargs="*", help="images of the empty table")
    tf.add_argument("--annotations", help="CloPeMa-format dataset directory; uses pixels off the garment")
    tf.add_argument("--out", required=True, help="YAML file to write")
    tf.set_defaults(func=_guard(cmd_table_fit))

    m = subparsers.add_parser("models", help="polygonal garment models")
    msub = m.add_subparsers(dest="models_command", required=True)
    ml = msub.add_parser("learn", help="fit the polygonal models from CloPeMa-format annotations")
    ml.add_argument("dataset", help="directory of annotation YAML files")
    ml.add_argument("--out-dir", help="where to write <category>.yaml (default: config/garments)")
    ml.set_defaults(func=_guard(cmd_models_learn))

    e = subparsers.add_parser("eval", help="evaluate perception on a CloPeMa-format dataset")
    e.add_argument("dataset", help="directory of images and annotation YAML files")
    e.add_argument("--table-model", help="table colour model YAML")
    e.add_argument("--cm-per-px", type=float, default=0.09, help="scale for the cm figures (default 0.09)")
    e.add_argument("--worst", type=_non_negative_int, default=5,
                   help="list this many images with the largest errors (default 5)")
    e.add_argument("--json", action="store_true", help="print one JSON object on stdout (per image under 'images')")
    e.set_defaults(func=_guard(cmd_eval))


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _load_common(args: argparse.Namespace):  # noqa: ANN202
    from cell.perception.config import load_perception_config
    from cell.perception.pipeline import load_garment_models, load_table_model
    cfg = load_perception_config()
    table = load_table_model(args.table_model, cfg)
    return cfg, table, load_garment_models(cfg)


def draw_overlay(img: np.ndarray, obs: Any) -> np.ndarray:
    out = img.copy()
    if obs.contour is not None:
        cv2.polylines(out, [obs.contour.reshape(-1, 1, 2).astype(np.int32)], True, (0, 0, 255), 2)
    cv2.polylines(out, [np.round(obs.polygon).astype(np.int32).reshape(-1, 1, 2)], True, (255, 0, 0), 2)
    for name, (x, y) in obs.landmarks.items():
        cv2.circle(out, (int(round(x)), int(round(y))), 7, (0, 255, 255), -1)
        cv2.putText(out, name, (int(x) + 8, int(y) - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 2)
    cv2.putText(out, f"{obs.category} cost {obs.cost:.1f}", (20, 40), cv2.FONT_HERSHEY_SIMPLEX, 1.0,
                (0, 0, 0), 2)
    return out


def cmd_perceive(args: argparse.Namespace) -> int:
    from cell.perception.pipeline import perceive
    cfg, table, models = _load_common(args)
    if args.category is not None and args.category not in models:
        raise _UsageError(f"--category: unknown category {args.category!r} (one of {', '.join(models)})")
    img = read_image(args.image)
    obs = perceive(img, table, models, cfg, args.category)
    if args.overlay:
        if not cv2.imwrite(args.overlay, draw_overlay(img, obs)):
            raise _UsageError(f"--overlay: cannot write {args.overlay}")
    if args.json:
        print(json.dumps(obs.to_json()))
    else:
        print(f"category: {obs.category}  cost: {obs.cost:.3f}")
        for name, (x, y) in obs.landmarks.items():
            print(f"  {name:20s} {x:8.1f} {y:8.1f}")
        print("polygon: " + " ".join(f"({x:.0f},{y:.0f})" for x, y in obs.polygon))
        if len(obs.costs) > 1:
            ranked = sorted(obs.costs.items(), key=lambda kv: kv[1])
            print("costs: " + ", ".join(f"{k} {v:.2f}" for k, v in ranked))
        print("timings ms: " + ", ".join(f"{k} {v:.1f}" for k, v in obs.timings_ms.items()))
    return 0


def load_dataset(directory: str | Path) -> list[tuple[Path, Any]]:
    """(annotation file, Annotation) for every parsable annotation YAML in the directory."""
    from cell.perception.annotations import AnnotationError, parse_annotation
    d = Path(directory)
    if not d.is_dir():
        raise _UsageError(f"{d}: not a directory")
    out = []
    for f in sorted(d.glob("*.yaml")) + sorted(d.glob("*.yml")):
        try:
            data = yaml.safe_load(f.read_text())
            if not isinstance(data, dict) or "path_c" not in data:
                continue
            out.append((f, parse_annotation(data)))
        except (yaml.YAMLError, AnnotationError, OSError) as exc:
            log.warning("skipping %s: %s", f, exc)
    return out


def cmd_table_fit(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from cell.perception.config import load_perception_config
    from cell.perception.table_model import fit_table_model
    cfg = load_perception_config()
    images, masks = [], []
    if args.annotations:
        for f, ann in tqdm(load_dataset(args.annotations), desc="images", file=sys.stderr):
            img = read_image(f.parent / ann.image)
            garment = np.zeros(img.shape[:2], np.uint8)
            cv2.fillPoly(garment, [np.round(ann.polygon).astype(np.int32)], 1)
            k = 2 * cfg.table.annotation_margin_px + 1
            garment = cv2.dilate(garment, np.ones((k, k), np.uint8))
            images.append(img)
            masks.append(garment == 0)
    for path in tqdm(args.images, desc="images", file=sys.stderr, disable=not args.images):
        images.append(read_image(path))
        masks.append(None)
    if not images:
        raise _UsageError("give empty-table IMAGES or --annotations DIR")
    model = fit_table_model(images, masks, cfg)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("# Table colour model written by `foldcell table fit`.\n"
                   + yaml.safe_dump(model.to_dict(), sort_keys=False))
    print(f"wrote {out} ({len(images)} images)")
    return 0


def write_model_file(path: Path, model: Any) -> None:
    """Write a model YAML, keeping an existing top-level `recipe` key."""
    data = model.to_dict()
    if path.is_file():
        try:
            old = yaml.safe_load(path.read_text())
        except yaml.YAMLError:
            old = None
        if isinstance(old, dict) and "recipe" in old:
            data["recipe"] = old["recipe"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("# Polygonal model written by `foldcell models learn` (recipe: by the planner).\n"
                    + yaml.safe_dump(data, sort_keys=False))


SIMPLIFY_VERTICES = {"towel": 10, "pants": 14, "short-sleeve": 18, "long-sleeve": 18}


def cmd_models_learn(args: argparse.Namespace) -> int:
    from cell.perception.config import load_perception_config
    from cell.perception.models import CATEGORIES, DESIGN_LANDMARKS, learn_model
    cfg = load_perception_config()
    out_dir = Path(args.out_dir) if args.out_dir else cfg.garments_dir
    polys: dict[str, list[np.ndarray]] = {c: [] for c in CATEGORIES}
    for f, ann in load_dataset(args.dataset):
        if ann.shape == "folded":
            continue
        try:
            polys[ann.category].append(ann.model_points())
        except ValueError as exc:
            log.warning("skipping %s: %s", f, exc)
    learned = 0
    for c in CATEGORIES:
        if not polys[c]:
            print(f"{c}: no annotations, model left unchanged", file=sys.stderr)
            continue
        n = SIMPLIFY_VERTICES[c]
        existing = out_dir / f"{c}.yaml"
        if existing.is_file():
            try:
                n = int(yaml.safe_load(existing.read_text()).get("simplify_vertices", n))
            except (yaml.YAMLError, AttributeError, TypeError, ValueError):
                pass
        model = learn_model(c, polys[c], DESIGN_LANDMARKS[c], n,
                            {"angle": cfg.angle_var_floor, "length": cfg.length_var_floor})
        write_model_file(existing, model)
        learned += 1
        print(f"{c}: {len(polys[c])} polygons -> {existing}")
    if not learned:
        raise _UsageError(f"{args.dataset}: no usable flat annotations")
    return 0


# cyclic relabellings under which a category's shape is the same (in landmark-array shifts)
SYMMETRIC_SHIFTS = {"towel": (0, 2)}


def replay_folds(model: Any, ann: Any, merge_fraction: float) -> Any:
    """The folded model after the annotation's fold history, from its flat landmarks."""
    from cell.perception.folded import derive_folded_model, folded_polygon, group_moves
    from cell.perception.geometry import polygon_edge_lengths
    missing = [n for n in model.names if n not in ann.flat_landmarks]
    if missing:
        raise _UsageError(f"{ann.image}: node_names_flat lacks {', '.join(missing)}")
    pts = np.asarray([ann.flat_landmarks[n] for n in model.names])
    for s, (g, p) in enumerate(group_moves(ann.moves), start=1):
        merge = merge_fraction * float(polygon_edge_lengths(pts).sum())
        nxt = derive_folded_model(model, pts, (g, p), s, merge_fraction)
        poly, names = folded_polygon(pts, model.names, g, p, s, merge)
        model, pts = nxt, np.asarray([poly[names.index(n)] for n in nxt.names])
    return model


def cmd_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from cell.perception.errors import ImageError, ModelError, PerceptionError
    from cell.perception.models import DESIGN_LANDMARKS
    from cell.perception.pipeline import perceive
    if not args.cm_per_px > 0:
        raise _UsageError(f"--cm-per-px must be > 0, got {args.cm_per_px}")
    cfg, table, models = _load_common(args)
    data = load_dataset(args.dataset)
    per: dict[str, dict[str, list]] = {}
    images: list[dict[str, Any]] = []
    unreadable: list[str] = []
    skipped = 0
    for f, ann in tqdm(data, desc="eval", file=sys.stderr):
        key = ann.category
        use_models = models
        names = DESIGN_LANDMARKS[ann.category]
        if ann.shape == "folded":
            if ann.flat_landmarks is None or not ann.moves:
                skipped += 1        # no fold history to replay
                continue
            try:
                folded_model = replay_folds(models[ann.category], ann, cfg.merge_fraction)
            except ModelError as exc:
                log.warning("%s: cannot replay its folds: %s", f, exc)
                skipped += 1
                continue
            use_models = {ann.category: folded_model}
            names = tuple(n for n in folded_model.names if n in ann.landmarks)
            key = f"{ann.category} (folded)"
        try:
            img = read_image(f.parent / ann.image)
        except ImageError as exc:  # one broken file does not end the evaluation
            log.warning("%s: %s", f, exc)
            unreadable.append(f.name)
            continue
        st = per.setdefault(key, {"d": [], "d_raw": [], "fail": [], "t": []})
        try:
            obs = perceive(img, table, use_models, cfg, ann.category)
        except PerceptionError as exc:
            st["fail"].append(str(exc))
            images.append({"file": f.name, "category": key, "error": str(exc)})
            continue
        gt = np.asarray([ann.landmarks[n] for n in names])
        est = np.asarray([obs.landmarks[n] for n in names])
        raw = np.linalg.norm(est - gt, axis=1)
        st["d_raw"].extend(raw.tolist())
        if key in SYMMETRIC_SHIFTS:
            # a towel turned by 180 deg looks the same: score the better of the two namings
            best = min((np.roll(est, s, axis=0) for s in SYMMETRIC_SHIFTS[ann.category]),
                       key=lambda e: float(np.linalg.norm(e - gt, axis=1).sum()))
            raw = np.linalg.norm(best - gt, axis=1)
        st["d"].extend(raw.tolist())
        st["t"].append(obs.timings_ms)
        images.append({"file": f.name, "category": key, "mean_px": float(raw.mean()), "max_px": float(raw.max()),
                       "cost": float(obs.cost)})
    report: dict[str, Any] = {"skipped_folded": skipped, "unreadable": unreadable, "categories": {},
                              "images": images}
    for c, st in per.items():
        d = np.asarray(st["d"]) if st["d"] else np.asarray([np.nan])
        d_raw = np.asarray(st["d_raw"]) if st["d_raw"] else np.asarray([np.nan])
        n = len(st["t"]) + len(st["fail"])
        times = {k: float(np.median([t[k] for t in st["t"]])) if st["t"] else None
                 for k in ("segment", "simplify", "match", "total")}
        report["categories"][c] = {
            "images": n, "segmentation_failures": len(st["fail"]),
            "failure_rate": len(st["fail"]) / n if n else 0.0,
            "px": {"median": float(np.median(d)), "mean": float(np.mean(d)), "std": float(np.std(d))},
            "cm": {"median": float(np.median(d)) * args.cm_per_px, "mean": float(np.mean(d)) * args.cm_per_px,
                   "std": float(np.std(d)) * args.cm_per_px},
            "median_timings_ms": times,
            "symmetric_scoring": c in SYMMETRIC_SHIFTS,
            "px_as_named": {"median": float(np.median(d_raw)), "mean": float(np.mean(d_raw))},
            "failures": st["fail"],
        }
    if args.json:
        print(json.dumps(report))
    else:
        print(f"{'category':14s} {'n':>4s} {'fail':>4s} {'med px':>7s} {'mean px':>7s} {'std px':>7s} "
              f"{'med cm':>7s} {'mean cm':>7s} {'std cm':>7s}  median ms seg/simp/match/total")
        for c, r in report["categories"].items():
            t = r["median_timings_ms"]
            ts = "/".join(f"{t[k]:.1f}" if t[k] is not None else "-"
                          for k in ("segment", "simplify", "match", "total"))
            print(f"{c:14s} {r['images']:4d} {r['segmentation_failures']:4d} {r['px']['median']:7.2f} "
                  f"{r['px']['mean']:7.2f} {r['px']['std']:7.2f} {r['cm']['median']:7.3f} "
                  f"{r['cm']['mean']:7.3f} "
                  f"{r['cm']['std']:7.3f}  {ts}")
        for c, r in report["categories"].items():
            if r["symmetric_scoring"]:
                print(f"{c}: scored up to its 180 deg symmetry; as named: "
                      f"median {r['px_as_named']['median']:.2f} px, "
                      f"mean {r['px_as_named']['mean']:.2f} px")
        worst = sorted((i for i in images if "mean_px" in i), key=lambda i: -i["mean_px"])[:args.worst]
        if worst:
            print(f"worst {len(worst)} images (mean / max landmark error, px; match cost):")
            for i in worst:
                print(f"  {i['file']:28s} {i['category']:14s} {i['mean_px']:8.1f} {i['max_px']:8.1f} {i['cost']:8.1f}")
        if skipped:
            print(f"skipped {skipped} folded images")
        if unreadable:
            print(f"skipped {len(unreadable)} unreadable images: {', '.join(unreadable)}")
    return 0


def write_synthetic_dataset(out_dir: str | Path, count_per_category: int, seed: int,
                            empty_tables: int = 0, images: bool = True) -> Path:
    """A small CloPeMa-format set made by cell.perception.synthetic (until the sim's generator lands)."""
    from cell.perception.models import CATEGORIES
    from cell.perception.synthetic import random_garment, render
    types = {"towel": "towel", "pants": "pants", "short-sleeve": "tshirt", "long-sleeve": "sweater"}
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    k = 0
    for c in CATEGORIES:
        for _ in range(count_per_category):
            g = random_garment(c, rng)
            name = f"{c}_{k:04d}"
            if images:
                cv2.imwrite(str(out / f"{name}.png"), render(g, rng))
            ann = {"path_c": f"{name}.png", "path_d": "", "type": types[c], "facing": "up", "shape": "flat",
                   "node_names": [[n] for n in g.names], "poly_c": [[round(float(x), 2), round(float(y), 2)]
                                                                    for x, y in g.landmarks],
                   "moves": []}
            (out / f"{name}.yaml").write_text(yaml.safe_dump(ann, sort_keys=False))
            k += 1
    for t in range(empty_tables):
        cv2.imwrite(str(out / f"table_{t:04d}.png"), render(None, rng))
    return out
