"""CLI of garment perception: `perceive`, `table fit`, `models learn`, `eval`."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import datetime
import json
import logging
import sys
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from drivers.common.configfile import ConfigError
from drivers.common.garments import CATEGORIES
from tools import overlay
from tools.common import error_exit, path_argument

log = logging.getLogger(__name__)


class _UsageError(Exception):
    pass



def _guard(fn):
    def run(args: argparse.Namespace) -> int:
        from cell.perception.annotations import AnnotationError
        from cell.perception.errors import ImageError, ModelError, PerceptionError
        try:
            return fn(args)
        except (_UsageError, ConfigError, ImageError, ModelError, AnnotationError) as exc:
            return error_exit(str(exc), 2)
        except PerceptionError as exc:
            return error_exit(str(exc), 1)
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
    if not np.any(sample != sample[0, 0]):
        b, g, r = (int(v) for v in sample[0, 0])
        raise ImageError(f"{p}: every pixel has the same colour (RGB {r}, {g}, {b}): nothing to perceive")
    if not np.any(sample[..., 0] != sample[..., 1]) and not np.any(sample[..., 1] != sample[..., 2]):
        raise ImageError(f"{p}: a grayscale image (its colour channels are equal); perception needs colour "
                         "(the table model is a colour model)")
    return img


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("perceive", help="find the garment, its category and landmarks in an image")
    p.add_argument("image", type=path_argument, help="colour image of the table seen from above")
    p.add_argument("--category", choices=CATEGORIES, help="match only this model")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 when what was found may be no garment (a bad fit or an unsure recognition)")
    p.add_argument("--table-model", type=path_argument, metavar="FILE",
                   help="table colour model YAML (default: from config/perception.yaml)")
    p.add_argument("-o", "--output", "--overlay", dest="overlay", type=path_argument, metavar="OVERLAY.png",
                   help="write the image with the polygon and landmarks drawn to this PNG")
    p.add_argument("--facing", choices=("front", "back"), default="front",
                   help="which side of the garment faces the camera: left/right name the garment's own "
                        "sides as worn, as the CloPeMa dataset does, so a garment lying face down "
                        "(back) gets its names mirrored (default front; the outline alone cannot tell)")
    p.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    p.set_defaults(func=_guard(cmd_perceive))

    t = subparsers.add_parser("table", help="table colour model")
    tsub = t.add_subparsers(dest="table_command", required=True)
    tf = tsub.add_parser("fit", help="fit the table colour GMM from empty-table or annotated images")
    tf.add_argument("images", nargs="*", type=path_argument, help="images of the empty table")
    tf.add_argument("--annotations", type=path_argument, metavar="DIR",
                    help="CloPeMa-format dataset directory; uses pixels off the garment")
    tf.add_argument("-o", "--output", required=True, type=path_argument, metavar="FILE",
                    help="YAML file to write")
    tf.add_argument("--json", action="store_true", help="print one JSON object on stdout, no progress bar")
    tf.add_argument("--data-note", default="",
                    help="how the images were made (e.g. the `dataset generate` command and seed); "
                         "recorded in the file's provenance with the command and the date")
    tf.set_defaults(func=_guard(cmd_table_fit))

    m = subparsers.add_parser("models", help="polygonal garment models")
    msub = m.add_subparsers(dest="models_command", required=True)
    ml = msub.add_parser("learn", help="fit the polygonal models from CloPeMa-format annotations")
    ml.add_argument("dataset", type=path_argument, help="directory of annotation YAML files")
    ml.add_argument("-o", "--output", required=True, type=path_argument, metavar="DIR",
                    help="where to write <category>.yaml")
    ml.add_argument("--force", action="store_true",
                    help="allow writing over the shipped models (config/garments)")
    ml.add_argument("--json", action="store_true", help="print one JSON object on stdout")
    ml.set_defaults(func=_guard(cmd_models_learn))
    mr = msub.add_parser("learn-recognition",
                         help="learn the category recogniser from CloPeMa-format datasets "
                              "(images + annotations)")
    mr.add_argument("datasets", nargs="+", metavar="DATASET", type=path_argument,
                    help="directories of images and annotation YAML")
    mr.add_argument("--table-model", type=path_argument, metavar="FILE",
                    help="table colour model YAML for segmenting the images")
    mr.add_argument("-o", "--output", required=True, type=path_argument, metavar="FILE",
                    help="YAML file to write")
    mr.add_argument("--force", action="store_true",
                    help="allow writing over the shipped recogniser (config/perception.yaml's "
                         "recognition.model)")
    mr.add_argument("--note", help="how the data was made, kept in the file's provenance")
    mr.add_argument("--json", action="store_true", help="print one JSON object on stdout, no progress bar")
    mr.set_defaults(func=_guard(cmd_learn_recognition))

    e = subparsers.add_parser("eval", help="evaluate perception on a CloPeMa-format dataset")
    e.add_argument("dataset", type=path_argument, help="directory of images and annotation YAML files")
    e.add_argument("--table-model", type=path_argument, metavar="FILE", help="table colour model YAML")
    e.add_argument("--cm-per-px", type=float, default=0.09, help="scale for the cm figures (default 0.09)")
    e.add_argument("--worst", type=_non_negative_int, default=5,
                   help="list this many images with the largest errors (default 5)")
    e.add_argument("--json", action="store_true",
                   help="print one JSON object on stdout (per image under 'images')")
    e.add_argument("--recognise", action="store_true",
                   help="score category recognition instead (category not given): a confusion matrix")
    e.add_argument("--category-unknown", action="store_true",
                   help="landmark errors with each flat garment's category recognised, not given "
                        "(a wrong category counts as a failure of that image)")
    e.set_defaults(func=_guard(cmd_eval))


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def _load_common(args: argparse.Namespace):
    from cell.perception.config import load_perception_config
    from cell.perception.pipeline import load_garment_models, load_table_model
    cfg = load_perception_config()
    table = load_table_model(args.table_model, cfg)
    return cfg, table, load_garment_models(cfg)


def as_facing(obs: Any, facing: str) -> Any:
    """The observation named for a garment lying with `facing` up (perception names it face up)."""
    if facing == "front":
        return obs
    from drivers.common.garments import mirror_name
    from drivers.common.landmarks import Landmarks
    seen = obs.landmarks
    mirrored = Landmarks(seen.frame, [mirror_name(n) for n in seen], seen.array())
    return dataclasses.replace(obs, landmarks=mirrored)


def timings_ms(obs: Any) -> dict[str, float]:
    """An observation's stage timings and their total, in ms (what scripts read)."""
    return {**{stage: seconds * 1e3 for stage, seconds in obs.timings_s.items()}, "total": obs.total_s * 1e3}


def observation_json(obs: Any) -> dict[str, Any]:
    """`perceive --json`: category, how sure the recognition is (null when the category was given)
    and every category's probability, landmarks and polygon (px), cost, timings (ms), every model's cost."""
    return {
        "category": obs.category,
        "confidence": None if obs.confidence is None else round(obs.confidence, 4),
        "probabilities": {k: round(v, 4) for k, v in obs.probabilities.items()},
        "landmarks": {k: [round(v[0], 2), round(v[1], 2)] for k, v in obs.landmarks.items()},
        "polygon": [[round(float(x), 2), round(float(y), 2)] for x, y in obs.polygon],
        "cost": float(obs.cost),
        "timings_ms": {k: round(v, 3) for k, v in timings_ms(obs).items()},
        "costs": {k: float(v) for k, v in obs.costs.items()},
    }


def cmd_perceive(args: argparse.Namespace) -> int:
    from cell.perception.pipeline import perceive
    cfg, table, models = _load_common(args)
    img = read_image(args.image)
    obs = as_facing(perceive(img, table, models, cfg, args.category), args.facing)
    doubt = obs.doubt(cfg.recognition)
    if args.overlay and not cv2.imwrite(str(args.overlay), overlay.draw_overlay(img, obs, args.facing,
                                                                          obs.confidence)):
        raise _UsageError(f"-o/--output: cannot write {args.overlay}")
    if args.json:
        print(json.dumps({**observation_json(obs), "facing": args.facing, "doubt": doubt}))
    else:
        sure = "" if obs.confidence is None else f"  confidence: {obs.confidence:.3f}"
        print(f"category: {obs.category}{sure}  cost: {obs.cost:.3f}")
        for name, (x, y) in obs.landmarks.items():
            print(f"  {name:20s} {x:8.1f} {y:8.1f}")
        print("polygon: " + " ".join(f"({x:.0f},{y:.0f})" for x, y in obs.polygon))
        if obs.probabilities:
            print("probabilities: " + ", ".join(f"{k} {v:.3f}" for k, v in obs.probabilities.items()))
        if len(obs.costs) > 1:
            ranked = sorted(obs.costs.items(), key=lambda kv: kv[1])
            print("costs: " + ", ".join(f"{k} {v:.2f}" for k, v in ranked))
        print("timings ms: " + ", ".join(f"{k} {v:.1f}" for k, v in timings_ms(obs).items()))
    if doubt is not None:
        print(f"foldcell: {'not' if args.strict else 'maybe not'} a garment: {doubt}", file=sys.stderr)
        return 1 if args.strict else 0
    return 0


def cmd_table_fit(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from cell.perception.annotations import load_annotations
    from cell.perception.config import load_perception_config
    from cell.perception.table_model import annotation_table_mask, fit_table_model
    cfg = load_perception_config()
    images: list[np.ndarray] = []
    masks: list[np.ndarray | None] = []
    if args.annotations:
        for path, annotation in tqdm(load_annotations(args.annotations), desc="images", file=sys.stderr,
                                 disable=True if args.json else None):
            img = read_image(path.parent / annotation.image)
            images.append(img)
            masks.append(annotation_table_mask(annotation, img.shape[:2], cfg.table))
    for path in tqdm(args.images, desc="images", file=sys.stderr,
                     disable=True if args.json or not args.images else None):
        images.append(read_image(path))
        masks.append(None)
    if not images:
        raise _UsageError("give empty-table IMAGES or --annotations DIR")
    model = fit_table_model(images, masks, cfg)
    data = [f"annotated images in {args.annotations}"] if args.annotations else []
    data += [f"{len(args.images)} table images"] if args.images else []
    provenance = {"data": ", ".join(data) + (f" ({args.data_note})" if args.data_note else ""),
                  "date": datetime.date.today().isoformat(),
                  "command": " ".join(["foldcell table fit", *map(str, args.images),
                                       *(["--annotations", str(args.annotations)] if args.annotations
                                         else []),
                                       "--output", str(args.output)])}
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("# Table colour model written by `foldcell table fit`.\n"
                   + yaml.safe_dump({**model.to_dict(), "provenance": provenance}, sort_keys=False))
    if args.json:
        print(json.dumps({"output": str(out), "images": len(images)}))
    else:
        print(f"wrote {out} ({len(images)} image{'s' if len(images) != 1 else ''})")
    return 0


def write_model_file(path: Path, model: Any, provenance: str | None = None) -> None:
    """Write a model YAML, keeping an existing top-level `recipe` key; `provenance` (what it was
    learned from, how and when) goes in its `comment`."""
    data = model.to_dict()
    if provenance:
        data["comment"] = provenance
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


def _provenance(args: argparse.Namespace, count: int) -> str:
    """Where a learned model comes from: the command, the date, the data (and how the data was made
    when its folder says, as `foldcell dataset generate` records it)."""
    import datetime as dt
    import shlex

    from drivers.sim.dataset import PROVENANCE_FILE
    date = dt.datetime.now(dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    command = ["foldcell", "models", "learn", str(args.dataset)]
    command += ["--output", str(args.output)]
    text = f"learned {date} by `{shlex.join(command)}` from {count} flat annotations in {args.dataset}"
    made = Path(args.dataset) / PROVENANCE_FILE
    with contextlib.suppress(OSError, ValueError):
        record = json.loads(made.read_text())
        text += "; data: " + ", ".join(f"{key} {value}" for key, value in record.items())
    return text


def cmd_models_learn(args: argparse.Namespace) -> int:
    from cell.perception.annotations import load_annotations
    from cell.perception.config import load_perception_config
    from cell.perception.model_learning import COLLARED_SIMPLIFY_VERTICES, SIMPLIFY_VERTICES, learn_models
    from drivers.common.garments import CATEGORIES
    cfg = load_perception_config()
    out_dir = Path(args.output)
    _refuse_shipped(out_dir, cfg.garments_dir, args.force, "models")
    vertices = {c: _vertices_kept(out_dir / f"{c}.yaml", SIMPLIFY_VERTICES[c],
                                  COLLARED_SIMPLIFY_VERTICES.get(c)) for c in CATEGORIES}
    floors = {"angle": cfg.angle_var_floor, "length": cfg.length_var_floor}
    learned = learn_models(load_annotations(args.dataset), floors, vertices)
    if not learned:   # before any line per category: bad input is told in one line
        raise _UsageError(f"{args.dataset}: no usable flat annotations")
    written: dict[str, dict[str, Any]] = {}
    for category in CATEGORIES:
        if category not in learned:
            print(f"{category}: no annotations, no model written", file=sys.stderr)
            continue
        result, path = learned[category], out_dir / f"{category}.yaml"
        write_model_file(path, result.model, _provenance(args, result.polygons))
        written[category] = {"polygons": result.polygons, "file": str(path)}
        if result.model.collared is not None:
            written[category]["collared"] = result.collared
        if not args.json:
            with_collar = f" ({result.collared} with a collar)" if result.model.collared is not None else ""
            print(f"{category}: {result.polygons} polygons{with_collar} -> {path}")
    if args.json:
        print(json.dumps({"output": str(out_dir), "models": written}))
    return 0


def _vertices_kept(existing: Path, vertices: int, collared: int | None) -> tuple[int, int | None]:
    """The simplify vertices a model file being replaced sets (its own choice is kept), else the defaults."""
    if existing.is_file():
        with contextlib.suppress(OSError, yaml.YAMLError, AttributeError, KeyError, TypeError, ValueError):
            old = yaml.safe_load(existing.read_text())
            vertices = int(old.get("simplify_vertices", vertices))
            collared = int(old["collared"]["simplify_vertices"])
    return vertices, collared


def _refuse_shipped(out: Path, shipped: Path, force: bool, what: str) -> None:
    """Learning writes beside the shipped files, never over them unless asked (--force)."""
    if not force and out.resolve() == shipped.resolve():
        raise _UsageError(f"--output: {out} holds the shipped {what}; give another path, or --force to "
                          "replace them")


def report_json(report: Any, cm_per_px: float) -> dict[str, Any]:
    """`eval --json`: per category the errors (px and cm), failures and median timings (ms)."""
    categories = {}
    for category, result in report.categories.items():
        errors, as_named = result.errors_px, result.errors_as_named_px
        categories[category] = {
            "images": result.images, "segmentation_failures": len(result.failures),
            "failure_rate": result.failure_rate,
            "px": {"median": errors.median, "mean": errors.mean, "std": errors.std},
            "cm": {"median": errors.median * cm_per_px, "mean": errors.mean * cm_per_px,
                   "std": errors.std * cm_per_px},
            "median_timings_ms": {stage: None if seconds is None else seconds * 1e3
                                  for stage, seconds in result.median_timings_s.items()},
            "symmetric_scoring": result.symmetric_scoring,
            "px_as_named": {"median": as_named.median, "mean": as_named.mean},
            "failures": result.failures,
        }
    images = [{"file": i.file, "category": i.category, "error": i.error} if i.error is not None else
              {"file": i.file, "category": i.category, "mean_px": i.mean_px, "max_px": i.max_px,
               "cost": i.cost}
              for i in report.images]
    return {"skipped_folded": report.skipped_folded, "unreadable": report.unreadable,
            "categories": categories, "images": images}


def print_report(report: dict[str, Any], worst: int) -> None:
    print(f"{'category':14s} {'n':>4s} {'fail':>4s} {'med px':>7s} {'mean px':>7s} {'std px':>7s} "
          f"{'med cm':>7s} {'mean cm':>7s} {'std cm':>7s}  median ms seg/simp/match/total")
    for category, r in report["categories"].items():
        t = r["median_timings_ms"]
        times = "/".join(f"{t[k]:.1f}" if t[k] is not None else "-"
                         for k in ("segment", "simplify", "match", "total"))
        print(f"{category:14s} {r['images']:4d} {r['segmentation_failures']:4d} {r['px']['median']:7.2f} "
              f"{r['px']['mean']:7.2f} {r['px']['std']:7.2f} {r['cm']['median']:7.3f} "
              f"{r['cm']['mean']:7.3f} {r['cm']['std']:7.3f}  {times}")
    for category, r in report["categories"].items():
        if r["symmetric_scoring"]:
            print(f"{category}: scored up to its 180 deg symmetry; as named: "
                  f"median {r['px_as_named']['median']:.2f} px, mean {r['px_as_named']['mean']:.2f} px")
    largest = sorted((i for i in report["images"] if "mean_px" in i), key=lambda i: -i["mean_px"])[:worst]
    if largest:
        print(f"worst {len(largest)} images (mean / max landmark error, px; match cost):")
        for i in largest:
            print(f"  {i['file']:28s} {i['category']:14s} {i['mean_px']:8.1f} {i['max_px']:8.1f} "
                  f"{i['cost']:8.1f}")
    if report["skipped_folded"]:
        print(f"skipped {report['skipped_folded']} folded images")
    if report["unreadable"]:
        print(f"skipped {len(report['unreadable'])} unreadable images: {', '.join(report['unreadable'])}")


def cmd_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from cell.evaluation.dataset import evaluate
    from cell.perception.annotations import load_annotations
    if not args.cm_per_px > 0:
        raise _UsageError(f"--cm-per-px must be > 0, got {args.cm_per_px}")
    cfg, table, models = _load_common(args)
    dataset = load_annotations(args.dataset)
    if not len(dataset):
        raise _UsageError(f"{args.dataset}: no annotated images to evaluate")
    if args.recognise:
        return _eval_recognition(dataset, table, models, cfg, args.json)
    result = evaluate(tqdm(dataset, desc="eval", file=sys.stderr), read_image, table, models, cfg,
                      category_given=not args.category_unknown)
    report = report_json(result, args.cm_per_px)
    if args.json:
        print(json.dumps(report))
    else:
        print_report(report, args.worst)
    return 0


def _eval_recognition(dataset: Any, table: Any, models: Any, cfg: Any, as_json: bool) -> int:
    from tqdm import tqdm

    from cell.evaluation.recognition import confusion_table, evaluate_recognition
    bar = tqdm(dataset, desc="eval", file=sys.stderr, disable=True if as_json else None)
    report = evaluate_recognition(bar, read_image, table, models, cfg)
    if as_json:
        print(json.dumps(report.to_dict()))
        return 0
    print("\n".join(confusion_table(report)))
    if report.skipped_folded:
        print(f"skipped {report.skipped_folded} images folded more than {cfg.recognition.max_folds} times")
    if report.unreadable:
        print(f"skipped {len(report.unreadable)} unreadable images: {', '.join(report.unreadable)}")
    return 0


def cmd_learn_recognition(args: argparse.Namespace) -> int:
    import datetime

    from tqdm import tqdm

    from cell.perception.annotations import load_annotations
    from cell.perception.recognition_learning import examples_from_dataset, learn_recogniser
    cfg, table, models = _load_common(args)
    _refuse_shipped(Path(args.output), cfg.recognition.model, args.force, "recogniser")
    examples = []
    for dataset in args.datasets:
        examples += examples_from_dataset(load_annotations(dataset), read_image, table, cfg)
    if not examples:
        raise _UsageError(f"{', '.join(map(str, args.datasets))}: no usable annotated images")
    command = ["foldcell", "models", "learn-recognition", *map(str, args.datasets),
               *(["--table-model", str(args.table_model)] if args.table_model else [])]
    provenance = {"data": [str(Path(d).resolve()) for d in args.datasets],
                  "date": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
                  "command": " ".join(command),
                  **({"note": args.note} if args.note else {})}
    recogniser = learn_recogniser(examples, models, cfg, provenance, lambda items: tqdm(
        items, desc="outlines", file=sys.stderr, disable=True if args.json else None))
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("# Category recogniser written by `foldcell models learn-recognition` "
                   "(cell/perception/recognition.py).\n"
                   + yaml.safe_dump(recogniser.to_dict(), sort_keys=False))
    summary = {"output": str(out), "examples": len(examples), "samples": recogniser.provenance["samples"]}
    print(json.dumps(summary) if args.json else
          f"wrote {out} ({len(examples)} outlines; samples per category with augmentation: "
          + ", ".join(f"{c} {n}" for c, n in summary["samples"].items()) + ")")
    return 0
