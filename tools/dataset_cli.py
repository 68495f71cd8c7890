"""`foldcell dataset generate|sheet`: synthetic CloPeMa-format datasets from the simulated world."""

from __future__ import annotations

import argparse
import json
import logging
import sys

from drivers.common.configfile import ConfigError
from drivers.common.garments import CATEGORIES
from drivers.sim.errors import SimError
from tools.common import error_exit, path_argument

log = logging.getLogger(__name__)



def _generate(args: argparse.Namespace) -> int:
    from drivers.sim.dataset import generate
    if args.count < 1:
        return error_exit(f"--count: must be a positive integer, got {args.count}", 2)
    if args.seed < 0:
        return error_exit(f"--seed: must be a non-negative integer, got {args.seed}", 2)
    if args.out_dir is not None and args.positional_out_dir is not None:
        return error_exit("-o/--output: the folder is given twice (as -o and as the last argument)", 2)
    args.out_dir = args.out_dir or args.positional_out_dir
    if args.out_dir is None:
        return error_exit("-o/--output: the folder to write into is missing", 2)
    try:
        paths = generate(args.out_dir, args.count, args.seed, categories=args.categories or None,
                         folded=args.folded, progress=not args.json)
    except SimError as exc:
        return error_exit(str(exc), 2)
    except ConfigError as exc:
        return error_exit(str(exc), 2)
    except OSError as exc:
        return error_exit(f"{args.out_dir}: {exc.strerror or exc}", 1)
    if args.json:
        annotations = [str(p.with_suffix(".yaml")) for p in paths if not p.name.startswith("table_")]
        doc = {"out_dir": str(args.out_dir), "images": [str(p) for p in paths], "annotations": annotations}
        json.dump(doc, sys.stdout)
        sys.stdout.write("\n")
    return 0


def _sheet(args: argparse.Namespace) -> int:
    from drivers.sim.dataset import contact_sheet
    try:
        out = contact_sheet(args.dir, args.output)
    except SimError as exc:
        return error_exit(str(exc), 2)
    except (OSError, KeyError, ValueError) as exc:
        return error_exit(f"{args.dir}: bad annotation: {exc}", 2)
    if args.json:
        json.dump({"sheet": str(out)}, sys.stdout)
        sys.stdout.write("\n")
    else:
        print(f"wrote {out}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add `dataset generate` and `dataset sheet`."""
    ds = subparsers.add_parser("dataset", help="synthetic CloPeMa-format datasets from the simulated world",
                               description="Synthetic CloPeMa-format datasets from the simulated "
                                           "garment world.")
    sub = ds.add_subparsers(dest="dataset_command", metavar="{generate,sheet}")
    sub.required = True
    gen = sub.add_parser(
        "generate", help="write annotated garment images and empty-table images",
        description="Write N garment images (1280x1024 PNG) with CloPeMa annotation YAML beside them, plus "
                    "empty-table images table_NNNN.png. Image i shows scene SEED+i of category "
                    "CATEGORIES[i %% len]. Deterministic for a seed.")
    gen.add_argument("-o", "--output", dest="out_dir", type=path_argument, metavar="DIR",
                     help="folder to write into (created if missing)")
    gen.add_argument("positional_out_dir", nargs="?", type=path_argument, metavar="DIR",
                     help="the same as -o DIR (as earlier versions took it)")
    gen.add_argument("--count", type=int, required=True, metavar="N", help="number of garment images")
    gen.add_argument("--seed", type=int, default=0, metavar="S", help="first scene seed (default 0)")
    gen.add_argument("--categories", nargs="+", choices=CATEGORIES, metavar="CATEGORY",
                     help=f"categories to draw in turn (default all: {', '.join(CATEGORIES)})")
    gen.add_argument("--folded", action="store_true",
                     help="fold every garment by its recipe (1..max folds); adds poly_c_flat and "
                          "node_names_flat")
    gen.add_argument("--json", action="store_true", help="print the written files as JSON, no progress bar")
    gen.set_defaults(func=_generate)
    sh = sub.add_parser("sheet", help="a 4x4 contact sheet of a dataset with its annotations drawn",
                        description="Draw the first 16 annotated images of DIR, with polygons, landmark "
                                    "names and fold moves, on one 4x4 PNG.")
    sh.add_argument("dir", metavar="DIR", type=path_argument, help="a folder written by `dataset generate`")
    sh.add_argument("-o", "--output", required=True, type=path_argument, metavar="SHEET.png",
                    help="where to write the sheet")
    sh.add_argument("--json", action="store_true", help="print the output path as JSON")
    sh.set_defaults(func=_sheet)
