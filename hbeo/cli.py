"""Command line: ``python -m hbeo SUBCOMMAND ...`` (see ``--help``).

Bad input exits with status 2 and one line naming the file and the problem.
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from contextlib import ExitStack
from pathlib import Path

from hbeo.errors import HBEOError
from hbeo.rundir import DEFAULT_MODEL, RunDir


def _dataset_arg(p, profile="cpu"):
    p.add_argument("--dataset", default="procedural",
                   help="procedural | modelnet10 | modelnet10-vox30 | PATH to a ModelNet-layout folder "
                        "(default: procedural)")
    p.add_argument("--profile", default=profile,
                   help=f"ci | cpu | full: objects per class and run sizes (default: {profile})")


def _load_dataset(name: str, prof, **kw):
    """get_dataset with its warnings (e.g. skipped empty grids) printed to stderr as one line each."""
    from hbeo.data import datasets
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = datasets.get_dataset(name, profile=prof, **kw)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    # said once: later loads of the same dataset in this command stay quiet about it
    warnings.filterwarnings("ignore", message=r".*skipped \d+ empty grids")
    return ds


def cmd_data(args) -> int:
    if args.download:
        if args.dataset != "modelnet10":
            raise HBEOError("--download applies to --dataset modelnet10 only")
        from hbeo.data.download import fetch_modelnet10
        from hbeo import config
        root = fetch_modelnet10(Path(args.root) if args.root else config.data_dir())
        print(f"ModelNet10 ready in {root}")
    kw = {"root": args.root} if (args.dataset == "modelnet10" and args.root) else {}
    ds = _load_dataset(args.dataset, args.profile, **kw)
    if args.summary or not args.download:
        n_listed = int(ds.summary().loc["total", "total"])
        print(f"dataset {ds.name}: {n_listed} objects listed, {len(ds)} usable, {len(ds.classes)} classes")
        print(ds.summary().to_string())
    return 0


def _report_failures(run, step: str, failures: list, total: int, strict: bool, splits) -> int:
    """A batch's end: its bad items written to the run's failures.json (replacing that step's old
    ones) and printed to stderr; exit status 2 if there were any and ``--strict``, else 0."""
    from hbeo.rundir import failure_summary
    path = run.write_failures(step, failures, splits=splits)
    if failures:
        print(failure_summary(failures, total, path), file=sys.stderr)
    return 2 if (strict and failures) else 0


def cmd_voxelize(args) -> int:
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.data.gridset import build_gridset
    from hbeo.errors import DataError
    prof = config.get_profile(args.profile)
    ds = _load_dataset(args.dataset, prof)
    if (args.out or "").endswith(".npz"):     # one file of every object, the published vox30 layout
        from hbeo.data.gridfile import write_gridfile
        res = write_gridfile(ds, args.out, workers=args.workers or prof.data.workers, strict=args.strict)
        print(res.report())
        if res.failures:
            print(res.failure_report(), file=sys.stderr)
        return 0
    run = RunDir.for_run(prof.name, args.dataset, args.out)
    splits, failures, total = ("train", "test"), [], 0
    for split in splits:
        recs = datasets.select(ds, split, prof)
        total += len(recs)
        try:
            gs = build_gridset(ds, recs, split, workers=args.workers or prof.data.workers)
        except DataError as err:            # nothing of the split succeeded: report, then exit 2
            _report_failures(run, "voxelize", failures + getattr(err, "failures", []), total, True, splits)
            raise
        failures += gs.failures
        path = gs.save(run.grids(split))
        print(f"{split}: {len(gs)} grids -> {path}")
    return _report_failures(run, "voxelize", failures, total, args.strict, splits)


def cmd_subspace(args) -> int:
    import pandas as pd
    from hbeo.subspace import completion
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.data.gridset import build_gridset
    from hbeo.storage import atomic_text
    from hbeo.subspace.basis import ObjectSubspace
    prof = config.get_profile(args.profile)
    ds = _load_dataset(args.dataset, prof)
    run = RunDir.for_run(prof.name, args.dataset, args.out)
    sets = {s: build_gridset(ds, datasets.select(ds, s, prof), s, workers=prof.data.workers) for s in ("train", "test")}
    if args.components is not None:
        sub = ObjectSubspace(n_components=args.components)
    else:
        sub = ObjectSubspace(variance=args.variance, shared_dim=args.shared_dim)
    sub.fit(sets["train"].grids, sets["train"].labels, sets["train"].classes)
    sub.save(run.subspace)
    counts = pd.DataFrame({"train objects": sets["train"].counts(), "components": sub.n_components_})
    print(f"\nper-class components (variance fraction {sub.variance_used_}; paper: 30-70 per class at 0.6):")
    print(counts.to_string())
    print(f"shared dimension: {sub.dim_} (paper: 344)   -> {run.subspace}")
    known = completion.random_mask(sets["test"].grids.shape, args.known, seed=args.seed)
    rows = {}
    for mode, mask in (("full", None), ("partial", known)):
        df = completion.evaluate(sub, sets["test"], mask, method=args.method)
        atomic_text(run.table(f"subspace_completion_{mode}"), df.to_csv(index=False))
        rows[mode] = completion.by_class(df)
    table = pd.concat({m: r[["edt", "naive"]] for m, r in rows.items()}, axis=1)
    print(f"\ntest completion errors, mean per class (full projection; partial from a random "
          f"{args.known:.0%}-known mask, seed {args.seed}, {args.method}):")
    print(table.round(3).to_string())
    summary = {"dataset": ds.name, "profile": prof.name, "dim": sub.dim_, "variance_used": sub.variance_used_,
               "n_components": sub.n_components_, "known_fraction": args.known, "seed": args.seed,
               "method": args.method, "errors": {m: r.round(6).to_dict(orient="index") for m, r in rows.items()}}
    atomic_text(run.subspace_summary, json.dumps(summary, indent=2))
    return 0


def cmd_render(args) -> int:
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.errors import DataError
    from hbeo.render.renderset import render_set
    from hbeo.render.views import RenderSettings
    from hbeo.subspace.basis import ObjectSubspace
    prof = config.get_profile(args.profile)
    ds = _load_dataset(args.dataset, prof)
    run = RunDir.for_run(prof.name, args.dataset, args.out)
    sub_path = Path(args.subspace) if args.subspace else run.subspace
    subspace = ObjectSubspace.load(sub_path) if (args.subspace or sub_path.exists()) else None
    settings = RenderSettings.from_profile(prof, views_per_object=args.views, sampler=args.sampler,
                                           noise=args.noise, backend=args.backend, seed=args.seed)
    splits = ("train", "test") if args.split == "both" else (args.split,)
    failures, total = [], 0
    for split in splits:
        recs = datasets.select(ds, split, prof)
        total += len(recs)
        try:
            with warnings.catch_warnings(record=True) as caught:   # shards rendered again, and why
                warnings.simplefilter("always")
                m = render_set(ds, recs, split, run.renders(split), settings, subspace=subspace,
                               workers=args.workers or prof.data.workers, objects_per_shard=args.objects_per_shard,
                               progress=not args.quiet, scheduler=args.scheduler)
        except DataError as err:            # nothing of the split could be rendered: report, then exit 2
            _report_failures(run, "render", failures + getattr(err, "failures", []), total, True, splits)
            raise
        finally:
            for w in caught:
                print(f"warning: {w.message}", file=sys.stderr)
        failures += m.failures
        rate = (f"{m.images_per_s:.1f} images/s" if m.images_per_s else "already rendered, 0 new images")
        coeffs = f", coeffs k={m.coeffs_dim}" if m.coeffs_dim else ""
        print(f"{split}: {m.n_images} images of {len(recs) - len(m.failures)} objects{coeffs} -> {m.root}  ({rate})")
    return _report_failures(run, "render", failures, total, args.strict, splits)


def _loss_weights(text: str):
    from hbeo.model.network import LossWeights
    try:
        c, o, p = (float(x) for x in text.split(","))
    except ValueError:
        raise ValueError(f"--loss-weights takes three numbers gamma_c,gamma_o,gamma_p, got {text!r}") from None
    if min(c, o, p) < 0:
        raise ValueError(f"--loss-weights must not be negative, got {text!r}")
    return LossWeights(c, o, p)


def cmd_train(args) -> int:
    from hbeo import config
    from hbeo.model.fit import ViewOptions, fit_model
    from hbeo.run import ensure_render, ensure_subspace
    from hbeo.render.views import RenderSettings
    from hbeo.model import distributed
    prof = config.get_profile(args.profile)
    weights = _loss_weights(args.loss_weights)
    world = distributed.setup()                       # under torchrun: join the other processes
    _load_dataset(args.dataset, prof)                 # fail fast, print dataset warnings once
    run = RunDir.for_run(prof.name, args.dataset, args.out)
    settings = RenderSettings.from_profile(prof, views_per_object=args.views, sampler=args.sampler)
    source = args.data or prof.data.train_data
    quiet = args.quiet or not world.main
    if world.main:                                    # rank 0 prepares the shared files, the others wait
        if source == "stream":                        # grids and subspace only: views are rendered on the fly
            ensure_subspace(args.dataset, prof, run, progress=not quiet)
        else:
            ensure_render(args.dataset, prof, run, "train", settings=settings, progress=not quiet)
    distributed.barrier()
    view = ViewOptions(recenter=args.recenter, ref_distance=args.ref_distance)
    recipe = {k: prof.recipe.fit_kwargs()[k] if getattr(args, k) is None else getattr(args, k) for k in prof.recipe.fit_kwargs()}
    model, path = fit_model(run, prof, epochs=args.epochs, normalization=args.normalize, view=view, seed=args.seed,
                            out_name=args.name, progress=not quiet, loss=weights, max_steps=args.max_steps,
                            data=source, dataset=args.dataset, settings=settings, checkpoint_every=args.checkpoint_every,
                            loader_workers=args.loader_workers, **recipe)
    distributed.barrier()                             # the model file is complete before any process exits
    if world.main:
        print(f"model: {path} ({model.net.n_params():,} parameters, {len(model.classes)} classes, "
              f"{model.subspace.dim_} coefficients)" + (f"; {world.size} processes" if world.parallel else ""))
    distributed.finish()
    return 0


def _write_json(path, obj) -> None:
    import json
    from hbeo.storage import atomic_file
    with atomic_file(path, "w") as f:
        json.dump(obj, f, indent=2)


#: file types ``predict --mesh`` writes (trimesh's exporters)
MESH_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb")


def _verify_config(args):
    """The verify settings ``--verify`` / ``--verify-set`` ask for, or None (``--verify-set`` alone is an error)."""
    if args.verify_set and not args.verify:
        raise HBEOError("--verify-set needs --verify")
    if not args.verify:
        return None
    from hbeo.model.verify import VerifyConfig
    try:
        return VerifyConfig.parse(args.verify_set)
    except ValueError as err:
        raise HBEOError(f"--verify-set: {err}") from None


def _add_verify(p) -> None:
    p.add_argument("--verify", action="store_true",
                   help="check the network's top hypotheses (classes x rotation modes) against the depth and "
                        "complete the shape from it (hbeo.model.verify; settings chosen on validation, README)")
    p.add_argument("--verify-set", metavar="KEY=VALUE,...",
                   help="verify settings over the defaults, e.g. classes=1,noise_var=1 (hbeo.model.verify.VerifyConfig)")


def cmd_predict(args) -> int:
    from hbeo.errors import DataError
    from hbeo.storage import atomic_file, check_outputs
    from hbeo.model.depthfile import parse_intrinsics, read_depth, read_mask
    from hbeo.model.inference import HBEO
    # outputs first: a bad --out/--mesh, or one naming an input, fails before any work
    check_outputs({"--out": args.out, "--mesh": args.mesh},
                  {"--depth": args.depth, "--mask": args.mask, "--model": args.model})
    if args.mesh and Path(args.mesh).suffix.lower() not in MESH_SUFFIXES:
        raise DataError(args.mesh, f"--mesh: unsupported mesh format; expected {', '.join(MESH_SUFFIXES)}")
    depth = read_depth(args.depth, args.depth_scale)
    K = parse_intrinsics(args.intrinsics, depth.shape[1], depth.shape[0])
    mask = read_mask(args.mask, depth.shape) if args.mask else None
    verify = _verify_config(args)                       # bad settings fail before the model is read
    model = HBEO.load(args.model, precision=args.precision)
    verifier = None
    if verify is not None:
        from hbeo.model.verify import Verifier
        verifier = Verifier(model, verify)
    try:
        pred = model.predict(depth, K, mask, rolls=args.rolls)
    except DataError as err:              # an input the model cannot see: name the depth file
        raise DataError(args.depth, err.problem) from None
    if verifier is not None:
        pred = verifier.apply(depth * mask if mask is not None else depth, K, pred)
    mesh = model.to_mesh(pred) if args.mesh else None     # fails before anything is written
    result = {"model": str(args.model), "depth": str(args.depth), "precision": model.precision, "rolls": args.rolls,
              "verify": verifier.cfg.to_dict() if verifier is not None else None, **pred.to_dict(0)}
    data = None
    if mesh is not None:
        result["mesh"] = str(args.mesh)
        data = mesh.export(file_type=Path(args.mesh).suffix.lstrip(".").lower())
        data = data.encode() if isinstance(data, str) else data
    # both files are complete in temporary files before either is renamed into place
    with ExitStack() as files:
        files.enter_context(atomic_file(args.out, "w")).write(json.dumps(result, indent=2))
        if data is not None:
            files.enter_context(atomic_file(args.mesh)).write(data)
    for w in result["warnings"]:
        print(f"warning: {args.depth}: {w} (low confidence)", file=sys.stderr)
    print(f"{result['class']} (p={max(result['probabilities']):.2f}), axis-angle {result['axis_angle']} -> {args.out}")
    return 0


def cmd_evaluate(args) -> int:
    from hbeo.evaluation.evaluate import evaluate_model, split_records
    from hbeo.baselines.methods import check_method, load_method
    from hbeo.model.inference import HBEO
    from hbeo.storage import check_outputs
    check_outputs({"--out": args.out}, {"--model": args.model})
    pose = check_method(args.method, args.pose)
    model = HBEO.load(args.model, precision=args.precision)
    if args.rolls < 1 or (args.rolls > 1 and model.net.cfg.rotation != "bins"):
        raise ValueError(f"--rolls {args.rolls}: needs a positive count, and more than 1 needs a rotation-bins model "
                         f"({args.model} has {model.net.cfg.rotation})")
    profile = model.settings.get("profile", "cpu")
    ds = _load_dataset(args.dataset, profile)
    # before any baseline is fitted or view rendered (evaluate_model checks the same)
    unknown = sorted({r.cls for r in split_records(ds, args.split, args.per_class, profile)} - set(model.classes))
    if unknown:
        raise HBEOError(f"--dataset {args.dataset}: classes {', '.join(unknown)} are unknown to the model "
                        f"{args.model} (it knows {', '.join(model.classes)})")
    method = None if args.method == "hbeo" else load_method(args.method, Path(args.model).parent, profile,
                                                            progress=not args.quiet, max_steps=args.max_steps)
    if args.verify and method is not None:
        raise HBEOError("--verify applies to --method hbeo (HBEO's own answers), not to a baseline")
    verify = _verify_config(args)           # evaluate_model builds the verifier (its per-model set-up) once
    metrics = evaluate_model(model, ds, split=args.split, views=args.views, seed=args.seed, sampler=args.sampler,
                             noise=args.noise, per_class=args.per_class, progress=not args.quiet,
                             method=method, pose=pose, rolls=args.rolls, verify=verify)
    metrics["model"] = str(args.model)
    _write_json(args.out, metrics)
    if args.split == "val":
        from hbeo.evaluation.protocol import record_validation
        record_validation(RunDir(Path(args.model).parent), args.model, model, metrics)
    status = _report_failures(RunDir(Path(args.model).parent), "evaluate", metrics["failures"],
                              metrics["n_objects"] + len(metrics["failures"]), args.strict, [args.split])
    short = {k: metrics[k] for k in ("method", "pose", "accuracy", "pose_error_deg", "completion", "runtime_ms")}
    print(json.dumps(short, indent=2))
    return status


def cmd_convert_model(args) -> int:
    from hbeo.model.modelfile import convert_legacy
    from hbeo.baselines.conversion_check import same_predictions
    kind, path = convert_legacy(args.old, args.new, check=same_predictions)
    print(f"{args.old} -> {path}: {kind} model in the current format (weights and predictions checked identical)")
    return 0


def cmd_reproduce(args) -> int:
    from hbeo.report.notebooks import run_notebooks
    run_notebooks(profile=args.profile, dataset=args.dataset, out_dir=args.out, only=args.only, fresh=args.fresh)
    return 0


def cmd_report(args) -> int:
    if args.model_table:
        from hbeo.report.model_table import write_model_table
        path = write_model_table(args.run, args.readme)
        print(f"wrote {path}" + (f" and its block in {args.readme}" if args.readme else ""))
        return 0
    from hbeo.report.reproduction_md import write_reproduction, write_summary
    path = write_reproduction(args.run, args.out)
    print(f"wrote {path}" + (f" and the summary block of {write_summary(args.run, args.readme)}" if args.readme else ""))
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
    p.add_argument("--out", help="output folder (default: results/PROFILE-DATASET), or FILE.npz: every object "
                                 "in one file of the published modelnet10_vox30.npz layout")
    p.add_argument("--workers", type=int, default=0, help="processes (default: the profile's)")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 2 if any object fails (default: skip it, list it in failures.json)")
    p.set_defaults(func=cmd_voxelize)
    p = sub.add_parser("subspace", help="fit the shared VBPCA subspace; print components and completion errors")
    _dataset_arg(p, profile="full")
    p.add_argument("--out", help="output folder (default: results/PROFILE-DATASET)")
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
    p.add_argument("--out", help="output folder; sets go to OUT/render_SPLIT (default: results/PROFILE-DATASET)")
    p.add_argument("--split", choices=("train", "test", "both"), default="train", help="split(s) to render (train)")
    p.add_argument("--views", type=int, help="views per object (default: the profile's)")
    p.add_argument("--sampler", choices=("so3", "upright"), default="so3",
                   help="so3: uniform rotations (the paper's 3-DOF setting); upright: yaw and elevation")
    p.add_argument("--noise", action="store_true", help="apply the Kinect-like sensor noise model")
    p.add_argument("--workers", type=int, default=0,
                   help="processes of the local Dask cluster (default: the profile's; unused with --scheduler)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="render on the running Dask scheduler at ADDRESS (e.g. tcp://host:8786) instead of a "
                        "local cluster; its workers must see --out at the same path and run the same hbeo")
    p.add_argument("--backend", choices=("auto", "pyrender", "embree"), default="auto", help="renderer (auto)")
    p.add_argument("--seed", type=int, default=0, help="seed of the viewpoints and noise (0)")
    p.add_argument("--subspace", help="subspace.npz for shape coefficients (default: OUT/subspace.npz if present)")
    p.add_argument("--objects-per-shard", type=int, default=None,
                   help="objects per shard file (default: about 1024 images per shard)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 2 if any object fails (default: skip it, list it in failures.json)")
    p.set_defaults(func=cmd_render)
    p = sub.add_parser("train", help="train HBEONet (builds grids, subspace and renderings if missing)")
    _dataset_arg(p)
    p.add_argument("--out", help="run folder (default: results/PROFILE-DATASET)")
    p.add_argument("--epochs", type=int, help="epochs (default: the profile's)")
    p.add_argument("--max-steps", type=int, help="stop after this many optimizer steps (the schedule ends there)")
    p.add_argument("--checkpoint-every", type=int, metavar="N",
                   help="also write the checkpoint every N steps (default: after every epoch only); a killed run "
                        "resumes from it")
    p.add_argument("--loader-workers", type=int, default=0, metavar="N",
                   help="worker processes that prepare batches while the network trains (default 0: none)")
    p.add_argument("--views", type=int, help="rendered views per training object (default: the profile's)")
    p.add_argument("--data", choices=("memory", "shards", "stream"),
                   help="training images: the rendered set in memory, the rendered set read shard by shard, or "
                        "rendered on the fly with a fresh pose per object per pass (default: the profile's)")
    p.add_argument("--loss-weights", default="1,1,1",
                   help="gamma_c,gamma_o,gamma_p: weights of the class, pose and coefficient losses (1,1,1)")
    p.add_argument("--shape-loss", choices=("coeffs", "voxels"),
                   help="shape term: the standardized coefficient error (paper) or the completed grid's occupancy "
                        "error through the basis (default: the profile's recipe, hbeo.config.Profile.recipe)")
    p.add_argument("--sampler", choices=("so3", "upright"), default="so3",
                   help="training viewpoints: uniform SO(3) (the paper's) or upright (random yaw, no roll)")
    p.add_argument("--rotation", choices=("axis_angle", "6d", "bins"),
                   help="pose output: the paper's axis-angle, the continuous 6-D representation, or a distribution "
                        "over a grid of rotations (bins); default: the profile's recipe")
    p.add_argument("--normalize", choices=("none", "center"), default="none",
                   help="depth input: metres as rendered (paper, default) or centred on the object's median depth")
    p.add_argument("--augment-roll", action=argparse.BooleanOptionalAction,
                   help="roll each training view by a random angle about the optical axis every epoch (exact; "
                        "default: the profile's recipe)")
    p.add_argument("--recenter", action="store_true", help="turn every view to look straight at the object")
    p.add_argument("--ref-distance", type=float, help="distance-insensitive input: zoom to this object distance (m)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--name", default=DEFAULT_MODEL, help=f"model file name in the run folder ({DEFAULT_MODEL})")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=cmd_train)
    p = sub.add_parser("predict", help="class, pose and completed shape from one depth image")
    p.add_argument("--model", required=True, help="model file (model.hbeo)")
    p.add_argument("--precision", choices=("float32", "bfloat16"), default="float32",
                   help="network arithmetic (bfloat16: faster on CPUs with AVX512-BF16, ~99%% class agreement)")
    p.add_argument("--rolls", type=int, default=1,
                   help="average over this many camera rolls (rotation-bins models; N network passes; 1 = off)")
    p.add_argument("--depth", required=True, help="depth image: 16-bit PNG in mm, or float .npy/.tiff in m")
    p.add_argument("--intrinsics", required=True, help="fx,fy,cx,cy in pixels")
    p.add_argument("--mask", help="object mask image (non-zero = object), same size as the depth")
    p.add_argument("--depth-scale", type=float, help="metres per stored unit (default 0.001 for integer images)")
    p.add_argument("--out", required=True, help="result JSON")
    p.add_argument("--mesh", help="also write the completed shape, placed in the camera frame (.ply/.obj/.stl)")
    _add_verify(p)
    p.set_defaults(func=cmd_predict)
    p = sub.add_parser("evaluate", help="render a dataset's views, predict and write the metrics JSON")
    p.add_argument("--model", required=True, help="the run's model.hbeo (its camera and views are used for "
                                                  "every method; baselines live beside it)")
    p.add_argument("--precision", choices=("float32", "bfloat16"), default="float32",
                   help="HBEO's network arithmetic (default float32)")
    p.add_argument("--rolls", type=int, default=1,
                   help="HBEO test-time augmentation: average over this many camera rolls (bins models; 1 = off)")
    p.add_argument("--method", choices=("hbeo", "beo", "icp", "voxcnn"), default="hbeo",
                   help="hbeo (default), beo, icp or voxcnn (fitted/trained in the model's folder if missing)")
    p.add_argument("--max-steps", type=int,
                   help="voxcnn: when it must be trained first, stop after this many optimizer steps")
    _add_verify(p)
    p.add_argument("--pose", choices=("known", "1dof", "3dof"),
                   help="what the method must estimate: hbeo 3dof; beo known|1dof|3dof; icp 1dof|3dof; voxcnn known")
    p.add_argument("--dataset", default="procedural", help="procedural | modelnet10 | modelnet10-vox30 | PATH")
    p.add_argument("--split", choices=("train", "test", "val"), default="test",
                   help="test (default); val: the training objects that training held out, where choices are made "
                        "(each evaluation is added to validation.csv beside the model)")
    p.add_argument("--views", type=int, default=1, help="views per object (1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--sampler", choices=("so3", "upright"), help="viewpoints (default: the model's training sampler)")
    p.add_argument("--noise", action="store_true", help="apply Kinect-like sensor noise")
    p.add_argument("--per-class", type=int, help="at most this many objects per class")
    p.add_argument("--strict", action="store_true",
                   help="exit 2 when any object could not be evaluated (default: report it, score the rest)")
    p.add_argument("--out", required=True, help="metrics JSON (keys: see hbeo/evaluate.py)")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=cmd_evaluate)
    p = sub.add_parser("convert-model", help="rewrite an old-format (torch pickle) model file in the current "
                                             "format, reading it without running code it may carry")
    p.add_argument("old", help="old model file (model.hbeo or voxcnn.pt written by hbeo before format 2)")
    p.add_argument("new", help="new model file (may be OLD itself: replaced once the conversion checks out)")
    p.set_defaults(func=cmd_convert_model)
    p = sub.add_parser("reproduce", help="run the numbered notebooks with papermill into results/")
    _dataset_arg(p)
    p.add_argument("--out", help="output folder (default: results/PROFILE-DATASET)")
    p.add_argument("--only", nargs="*", help="notebook name prefixes to run (default: all)")
    p.add_argument("--fresh", action="store_true", help="first remove the run's models, baselines and metrics")
    p.set_defaults(func=cmd_reproduce)
    p = sub.add_parser("report", help="write paper/REPRODUCTION.md (reported vs. reproduced) from a finished run")
    p.add_argument("--run", required=True, help="run folder, e.g. results/cpu-modelnet10-vox30")
    p.add_argument("--out", help="output file (default: paper/REPRODUCTION.md)")
    p.add_argument("--model-table", action="store_true",
                   help="instead: the model table (validation / test) from the run's models.json -> model_table.md")
    p.add_argument("--readme", help="also replace the generated block (summary, or with --model-table the tables) in "
                                    "this README")
    p.set_defaults(func=cmd_report)
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
