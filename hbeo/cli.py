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


def _dataset_arg(p, profile="cpu"):
    p.add_argument("--dataset", default="procedural",
                   help="procedural | modelnet10 | modelnet10-vox30 | PATH to a ModelNet-layout folder "
                        "(default: procedural)")
    p.add_argument("--profile", default=profile,
                   help=f"ci | cpu | full: objects per class and run sizes (default: {profile})")


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


def cmd_subspace(args) -> int:
    import json
    import pandas as pd
    from . import completion, config, datasets
    from .gridset import build_gridset
    from .subspace import ObjectSubspace
    prof = config.get_profile(args.profile)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = datasets.get_dataset(args.dataset, profile=prof)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    out = config.run_dir(prof.name, args.dataset, args.out)
    sets = {s: build_gridset(ds, datasets.select(ds, s, prof), s, workers=prof.workers) for s in ("train", "test")}
    if args.components is not None:
        sub = ObjectSubspace(n_components=args.components)
    else:
        sub = ObjectSubspace(variance=args.variance, shared_dim=args.shared_dim)
    sub.fit(sets["train"].grids, sets["train"].labels, sets["train"].classes)
    sub.save(out / "subspace.npz")
    counts = pd.DataFrame({"train objects": sets["train"].counts(), "components": sub.n_components_})
    print(f"\nper-class components (variance fraction {sub.variance_used_}; paper: 30-70 per class at 0.6):")
    print(counts.to_string())
    print(f"shared dimension: {sub.dim_} (paper: 344)   -> {out / 'subspace.npz'}")
    known = completion.random_mask(sets["test"].grids.shape, args.known, seed=args.seed)
    rows = {}
    for mode, mask in (("full", None), ("partial", known)):
        df = completion.evaluate(sub, sets["test"], mask, method=args.method)
        df.to_csv(out / f"subspace_completion_{mode}.csv", index=False)
        rows[mode] = completion.by_class(df)
    table = pd.concat({m: r[["edt", "naive"]] for m, r in rows.items()}, axis=1)
    print(f"\ntest completion errors, mean per class (full projection; partial from a random "
          f"{args.known:.0%}-known mask, seed {args.seed}, {args.method}):")
    print(table.round(3).to_string())
    summary = {"dataset": ds.name, "profile": prof.name, "dim": sub.dim_, "variance_used": sub.variance_used_,
               "n_components": sub.n_components_, "known_fraction": args.known, "seed": args.seed,
               "method": args.method, "errors": {m: r.round(6).to_dict(orient="index") for m, r in rows.items()}}
    (out / "subspace_summary.json").write_text(json.dumps(summary, indent=2))
    return 0


def cmd_render(args) -> int:
    from . import config, datasets
    from .renderset import RenderSettings, render_set
    from .subspace import ObjectSubspace
    prof = config.get_profile(args.profile)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = datasets.get_dataset(args.dataset, profile=prof)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    out = config.run_dir(prof.name, args.dataset, args.out)
    sub_path = Path(args.subspace) if args.subspace else out / "subspace.npz"
    subspace = ObjectSubspace.load(sub_path) if (args.subspace or sub_path.exists()) else None
    settings = RenderSettings.from_profile(prof, views_per_object=args.views, sampler=args.sampler,
                                           noise=args.noise, backend=args.backend, seed=args.seed)
    splits = ("train", "test") if args.split == "both" else (args.split,)
    for split in splits:
        recs = datasets.select(ds, split, prof)
        m = render_set(ds, recs, split, out / f"render_{split}", settings, subspace=subspace,
                       workers=args.workers or prof.workers, objects_per_shard=args.objects_per_shard,
                       progress=not args.quiet)
        rate = (f"{m.images_per_s:.1f} images/s" if m.images_per_s else "already rendered, 0 new images")
        coeffs = f", coeffs k={m.coeffs_dim}" if m.coeffs_dim else ""
        print(f"{split}: {m.n_images} images of {len(recs)} objects{coeffs} -> {m.root}  ({rate})")
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
    p = sub.add_parser("subspace", help="fit the shared VBPCA subspace; print components and completion errors")
    _dataset_arg(p, profile="full")
    p.add_argument("--out", help="output folder (default: results/PROFILE/DATASET)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--variance", type=float, default=0.6, help="variance fraction per class (default 0.6, the paper's)")
    g.add_argument("--shared-dim", type=int, help="choose one variance fraction giving this shared dimension (paper: 344)")
    g.add_argument("--components", type=int, help="fixed component count per class")
    p.add_argument("--method", choices=("lstsq", "lasso"), default="lstsq", help="partial projection solver")
    p.add_argument("--known", type=float, default=0.5, help="fraction of voxels known in the partial test (0.5)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random mask")
    p.set_defaults(func=cmd_subspace)
    p = sub.add_parser("render", help="render segmented depth images with pose/class/shape labels (resumable)")
    _dataset_arg(p)
    p.add_argument("--out", help="output folder; sets go to OUT/render_SPLIT (default: results/PROFILE/DATASET)")
    p.add_argument("--split", choices=("train", "test", "both"), default="train", help="split(s) to render (train)")
    p.add_argument("--views", type=int, help="views per object (default: the profile's)")
    p.add_argument("--sampler", choices=("so3", "upright"), default="so3",
                   help="so3: uniform rotations (the paper's 3-DOF setting); upright: yaw and elevation")
    p.add_argument("--noise", action="store_true", help="apply the Kinect-like sensor noise model")
    p.add_argument("--workers", type=int, default=0, help="processes (default: the profile's)")
    p.add_argument("--backend", choices=("auto", "pyrender", "embree"), default="auto", help="renderer (auto)")
    p.add_argument("--seed", type=int, default=0, help="seed of the viewpoints and noise (0)")
    p.add_argument("--subspace", help="subspace.npz for shape coefficients (default: OUT/subspace.npz if present)")
    p.add_argument("--objects-per-shard", type=int, default=None,
                   help="objects per shard file (default: about 1024 images per shard)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render)
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
