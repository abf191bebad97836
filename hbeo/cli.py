"""Command line: ``python -m hbeo SUBCOMMAND ...`` (see ``--help``).

Bad input exits with status 2 and one line naming the file and the problem.
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

from .errors import HBEOError

NOTEBOOKS_DIR = Path(__file__).resolve().parent.parent / "notebooks"


def _dataset_arg(p):
    p.add_argument("--dataset", default="procedural",
                   help="procedural | modelnet10 | modelnet10-vox30 | PATH to a ModelNet-layout folder "
                        "(default: procedural)")
    p.add_argument("--profile", default="cpu", help="ci | cpu | full (sizes procedural data; default: cpu)")


def cmd_data(args) -> int:
    from . import datasets
    if args.download:
        if args.dataset != "modelnet10":
            raise HBEOError("--download applies to --dataset modelnet10 only")
        from .download import fetch_modelnet10
        from . import config
        root = fetch_modelnet10(Path(args.root) if args.root else config.data_dir())
        print(f"ModelNet10 ready in {root}")
    kw = {"root": args.root} if (args.dataset == "modelnet10" and args.root) else {}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = datasets.get_dataset(args.dataset, profile=args.profile, **kw)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    if args.summary or not args.download:
        print(f"dataset {ds.name}: {len(ds)} objects, {len(ds.classes)} classes")
        print(ds.summary().to_string())
    return 0


def cmd_voxelize(args) -> int:
    from . import config, datasets
    from .gridset import build_gridset
    prof = config.get_profile(args.profile)
    ds = datasets.get_dataset(args.dataset, profile=prof)
    out = config.run_dir(prof.name, args.dataset, args.out)
    for split in ("train", "test"):
        recs = datasets.select(ds, split, prof)
        gs = build_gridset(ds, recs, split, workers=args.workers or prof.workers)
        path = gs.save(out / f"grids_{split}.npz")
        print(f"{split}: {len(gs)} grids -> {path}")
    return 0


def cmd_reproduce(args) -> int:
    from .reproduce import run_notebooks
    run_notebooks(profile=args.profile, dataset=args.dataset, out_dir=args.out,
                  only=args.only)
    return 0


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m hbeo",
                                 description="Hybrid Bayesian Eigenobjects: data, voxelization, reproduction.")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    p = sub.add_parser("data", help="list a dataset (class counts) or download ModelNet10")
    _dataset_arg(p)
    p.add_argument("--summary", action="store_true", help="print per-class object counts per split")
    p.add_argument("--download", action="store_true", help="download and extract ModelNet10 (needs internet)")
    p.add_argument("--root", help="folder for the ModelNet10 download (default: $HBEO_DATA or ~/.cache/hbeo)")
    p.set_defaults(func=cmd_data)
    p = sub.add_parser("voxelize", help="voxelize a dataset into 30^3 grids (cached, resumable)")
    _dataset_arg(p)
    p.add_argument("--out", help="output folder (default: results/PROFILE/DATASET)")
    p.add_argument("--workers", type=int, default=0, help="processes (default: the profile's)")
    p.set_defaults(func=cmd_voxelize)
    p = sub.add_parser("reproduce", help="run the numbered notebooks with papermill into results/")
    _dataset_arg(p)
    p.add_argument("--out", help="output folder (default: results/PROFILE/DATASET)")
    p.add_argument("--only", nargs="*", help="notebook name prefixes to run (default: all)")
    p.set_defaults(func=cmd_reproduce)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if not getattr(args, "func", None):
        ap.print_help()
        return 0
    try:
        return args.func(args)
    except (HBEOError, ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
