"""Command line: ``python -m hbeo SUBCOMMAND ...`` (see ``--help``). Parsing only: each subcommand calls one
package function (mostly a stage of :class:`hbeo.run.Run`). Bad input exits 2 with one line naming the file and the problem.
"""
from __future__ import annotations

import argparse
import json
import sys
import traceback

from hbeo import config
from hbeo.cli_args import (COUNT, FRACTION, NONNEG, OPEN_FRACTION, POSITIVE, image_size as _image_size, number,
                           join_list_values as _join_list_values, local_workers as _local_workers)
from hbeo.errors import HBEOError, os_error_line
from hbeo.render.poses import SAMPLER_HELP, SAMPLERS
from hbeo.rundir import DEFAULT_MODEL

#: the --sampler help: the readings of the view protocol (hbeo.render.poses)
_SAMPLER_HELP = "; ".join(f"{k}: {v}" for k, v in SAMPLER_HELP.items()).replace("%", "%%")


# --------------------------------------------------------------------------- refusing what means nothing

class _Parser(argparse.ArgumentParser):
    """argparse with usage errors as one line, ``error: OPTION: problem (see ... --help)``, exit 2."""

    def error(self, message):
        print(f"error: {message.removeprefix('argument ')} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(2)


#: the --workers help of the commands that start local processes
_WORKERS_HELP = "local processes (default: the profile's; 0: one per core this process may use)"


# --------------------------------------------------------------------------- the one error boundary

def missing_package_line(name: str) -> str:
    """The one line for a third-party package this Python lacks: which package, which Python, and the set-up
    that installs it (an environment problem, not a bug)."""
    return (f"this Python ({sys.executable}) has no package '{name.split('.')[0]}', which hbeo needs here: "
            "`make setup` installs hbeo's dependencies into .venv; run hbeo as `.venv/bin/python -m hbeo ...` "
            "(or activate .venv first)")


def _bug(err: BaseException) -> int:
    traceback.print_exc()
    print(f"error: unexpected {type(err).__name__}: this is a bug in hbeo; please report it with the command and "
          "the traceback above on the project's issue tracker (docs/your-depth-image.md, 'Bad input')", file=sys.stderr)
    return 1


def _dataset_arg(p, profile="cpu"):
    p.add_argument("--dataset", default="procedural",
                   help="procedural | modelnet10 | modelnet10-vox30 | PATH to a ModelNet-layout folder "
                        "(default: procedural)")
    p.add_argument("--profile", default=profile,
                   help=f"{' | '.join(config.PROFILES)}: objects per class and run sizes (default: {profile})")


def _run(args, **kw):
    from hbeo.run import Run
    return Run.open(args.profile, args.dataset, args.out, **kw)


def cmd_data(args) -> int:
    from hbeo.run import dataset_summary
    print(dataset_summary(args.dataset, args.profile, args.root, args.download, args.summary or not args.download))
    return 0


def cmd_voxelize(args) -> int:
    if (args.out or "").endswith(".npz"):     # one file of every object, the published vox30 layout
        from hbeo.run import voxelize_to_file
        print(voxelize_to_file(args.profile, args.dataset, args.out, args.workers, args.strict))
        return 0
    return 2 if (_run(args).voxelize(args.workers) and args.strict) else 0


def cmd_subspace(args) -> int:
    print(_run(args).subspace_report(args.variance, args.shared_dim, args.components, args.method, args.known, args.seed))
    return 0


def cmd_render(args) -> int:
    from hbeo.render.views import RenderSettings
    run = _run(args)
    settings = RenderSettings.from_profile(run.profile, views_per_object=args.views, sampler=args.sampler,
                                           noise=args.noise, backend=args.backend, seed=args.seed)
    splits = ("train", "test") if args.split == "both" else (args.split,)
    failed = run.render(splits, settings, args.subspace, args.workers, args.objects_per_shard, not args.quiet,
                        args.scheduler)
    return 2 if (failed and args.strict) else 0


def cmd_train(args) -> int:
    from hbeo.model import distributed
    from hbeo.model.fit import TrainOptions, parse_fc, parse_loss_weights
    from hbeo.model.trainingdata import ViewOptions
    same = ("epochs", "rotation", "augment_roll", "shape_loss", "data", "sampler", "views", "backend", "seed",
            "name", "max_steps", "checkpoint_every", "loader_workers", "class_balance", "render_ahead",
            "draw_workers", "augment_mirror", "image_size", "batch_size", "lr", "warmup_steps",
            "noise", "noise_scale", "noise_fraction")                                     # TrainOptions' names
    opts = TrainOptions(normalization=args.normalize, view=ViewOptions(args.recenter, args.ref_distance),
                        loss=parse_loss_weights(args.loss_weights), fc=parse_fc(args.fc) if args.fc else None,
                        **{k: getattr(args, k) for k in same})
    world = distributed.setup()                       # under torchrun: join the other processes
    t = _run(args).train(opts, progress=not (args.quiet or not world.main))
    if world.main:
        print(f"model: {t.path} ({t.model.net.n_params():,} parameters, {len(t.model.classes)} classes, "
              f"{t.model.subspace.dim_} coefficients)" + (f"; {world.size} processes" if world.parallel else ""))
    distributed.finish()
    return 0


def _add_verify(p) -> None:
    p.add_argument("--verify", action="store_true",
                   help="check the network's top hypotheses (classes x rotation modes) against the depth and "
                        "complete the shape from it (hbeo.model.verify; settings chosen on validation, docs/experiments.md)")
    p.add_argument("--verify-set", metavar="KEY=VALUE,...",
                   help="verify settings over the defaults, e.g. classes=1,noise_var=1 (hbeo.model.verify.VerifyConfig)")


def _add_ensemble(p) -> None:
    p.add_argument("--ensemble", action="append", default=[], metavar="MODEL",
                   help="another model file (a training seed of --model's recipe) whose answers are averaged with "
                        "--model's: class probabilities, rotation distributions and coefficients (rotation-bins "
                        "models with the same classes, camera and subspace; repeat for more; each adds a network pass)")


def _add_mirror(p) -> None:
    p.add_argument("--mirror", action="store_true",
                   help="average HBEO's class answer over each image and its left-right mirror (twice the network "
                        "passes; pose and shape stay the unmirrored image's; hbeo.model.inference.HBEO.set_mirror)")


def _add_prior(p) -> None:
    p.add_argument("--prior-tau", type=number(float, 0, 1), default=0.0, metavar="TAU",
                   help="prior correction: class logits minus TAU * log(training class prior), TAU in [0, 1] "
                        "(0: the paper's, default; 1: divide by the prior; hbeo.model.inference.HBEO.set_prior_tau)")


def _add_completion(p) -> None:
    p.add_argument("--completion", choices=("nonempty", "paper"),
                   help="HBEO's completion rule: nonempty (the default: the threshold chosen on validation, never an "
                        "empty grid; an evaluation also scores the paper's rule beside) or paper (back-projection "
                        ">= 0.5 only); hbeo.model.completion_rule")
    p.add_argument("--completion-threshold", type=float, metavar="T",
                   help="the completion rule's threshold instead of its own (0 < T < 1; the never-empty rule's when "
                        "--completion is not given), e.g. to evaluate again under an earlier default")


def _completion(args):
    """``--completion`` and ``--completion-threshold`` as set_completion takes them (a name, a rule or None)."""
    if args.completion_threshold is None:
        return args.completion
    from hbeo.model.completion_rule import DEFAULT, rule
    if args.completion == "paper":
        raise ValueError("--completion-threshold: the paper's rule is back-projection >= 0.5; a threshold is the "
                         "never-empty rule's (--completion nonempty)")
    return rule(args.completion or DEFAULT, args.completion_threshold)


def cmd_predict(args) -> int:
    from hbeo.model.answer import predict_file, verify_config
    verify = verify_config(args.verify, args.verify_set)  # bad settings fail before the model is read
    answer = predict_file(args.model, args.depth, args.intrinsics, args.mask, args.depth_scale, args.rolls, verify,
                          args.precision, out=args.out, mesh_path=args.mesh, prior_tau=args.prior_tau,
                          members=args.ensemble, mirror=args.mirror, completion=_completion(args),
                          face_object=args.face_object)
    for w in answer.warnings:
        print(f"warning: {args.depth}: {w} (low confidence)", file=sys.stderr)
    r = answer.to_json()
    print(f"{r['class']} (p={max(r['probabilities']):.2f}), axis-angle {r['axis_angle']} -> {args.out}")
    return 0


def cmd_evaluate(args) -> int:
    from hbeo.evaluation.protocol import evaluate_file
    from hbeo.model.answer import verify_config
    metrics = evaluate_file(args.model, args.dataset, args.out, split=args.split, views=args.views, seed=args.seed,
                            sampler=args.sampler, noise=args.noise, per_class=args.per_class, method=args.method,
                            pose=args.pose, precision=args.precision, rolls=args.rolls, verify=verify_config(args.verify, args.verify_set),
                            max_steps=args.max_steps, progress=not args.quiet, prior_tau=args.prior_tau,
                            members=args.ensemble, mirror=args.mirror, completion=_completion(args),
                            batched=args.batch, noise_scale=args.noise_scale)
    short = {k: metrics[k] for k in ("method", "pose", "accuracy", "pose_error_deg", "completion", "runtime_ms")}
    if "completion_paper" in metrics:               # the paper's rule on the same queries, beside
        short["completion_paper"] = {k: v for k, v in metrics["completion_paper"].items() if k != "per_query"}
    print(json.dumps(short, indent=2))
    return 2 if (metrics["failures"] and args.strict) else 0


def cmd_convert_model(args) -> int:
    from hbeo.model.modelfile import convert_legacy
    from hbeo.baselines.conversion_check import same_predictions
    kind, path = convert_legacy(args.old, args.new, check=same_predictions)
    print(f"{args.old} -> {path}: {kind} model in the current format (weights and predictions checked identical)")
    return 0


def cmd_reproduce(args) -> int:
    from hbeo.report.notebooks import run_notebooks
    run_notebooks(profile=args.profile, dataset=args.dataset, out_dir=args.out, only=args.only, fresh=args.fresh,
                  training_seed=args.seed)
    return 0


def cmd_report(args) -> int:
    from hbeo.report import model_table, reproduction_md as md
    if args.seeds is not None:                    # the spread over training seeds (hbeo.report.seeds)
        from hbeo.report.seeds import write_seed_table
        if args.model_table or args.readme:
            raise HBEOError("--seeds writes the seed table alone; --model-table and --readme take --run")
        print("wrote " + ", ".join(map(str, write_seed_table(args.seeds, args.out))))
        return 0
    if args.completion_decomposition:             # the completion gap, taken apart (hbeo.report.completion_gap)
        from hbeo.report.completion_gap import write_decomposition
        print("wrote " + ", ".join(map(str, write_decomposition(args.completion_decomposition))))
        return 0
    if args.model_table:
        path = model_table.write_model_table(args.run, args.readme)
        print(f"wrote {path}" + (f" and its block in {args.readme}" if args.readme else ""))
        return 0
    md.check_finished_run(args.run)               # a folder that is not a finished run: one line, exit 2
    path = md.write_reproduction(args.run, args.out)
    print(f"wrote {path}" + (f" and the summary block of {md.write_summary(args.run, args.readme)}" if args.readme else ""))
    return 0


def cmd_book(args) -> int:
    from hbeo.report.book import build_book
    index = build_book(args.run, args.out)        # an unwritable output folder: main's OSError line, exit 2
    print(f"[hbeo] book: {index}")
    return 0


def cmd_experiment_list(args) -> int:
    from hbeo.report.experiments import listing
    print(listing(args.experiments))
    return 0


def cmd_experiment_run(args) -> int:
    from hbeo.report.experiments import run
    run(args.name, args.experiments, dry_run=args.dry_run)
    return 0


def cmd_experiment_table(args) -> int:
    from hbeo.report.experiments import write_table
    print("\n".join(f"wrote {p}" for p in write_table(args.experiments, args.readme)))
    return 0


def _experiment_parser(sub) -> None:
    p = sub.add_parser("experiment", help="the model table's experiments (experiments/*/NN-NAME.toml): list, run, table",
                       description="Each row of a run's model table is a spec, experiments/RUN/NN-NAME.toml "
                                   "(hbeo.report.experiments); models.json is generated from them.")
    verbs = p.add_subparsers(dest="action", metavar="ACTION", required=True)
    for name, func, what in (("list", cmd_experiment_list, "every spec: status, rule, whether its metrics files exist"),
                             ("run", cmd_experiment_run, "train, evaluate and write one spec's metrics files"),
                             ("table", cmd_experiment_table, "regenerate models.json and the model table from the specs")):
        v = _command(verbs, func, name, help=what)
        v.add_argument("--experiments", metavar="DIR", help="the specs' folder (default: the repository's experiments/)")
        if name == "run":
            v.add_argument("name", help="the spec's name (or NN-NAME), as `experiment list` shows it")
            v.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
        if name == "table":
            v.add_argument("--readme", help="also replace the model and targets blocks in this README")


def _command(sub, func, name: str, **kw) -> argparse.ArgumentParser:
    p = sub.add_parser(name, description=kw.get("help"), **kw)      # the list's line heads the command's --help
    p.set_defaults(func=func)
    return p


def build_parser() -> argparse.ArgumentParser:
    ap = _Parser(prog="python -m hbeo",
                                 description="Hybrid Bayesian Eigenobjects: data, voxelization, reproduction.")
    sub = ap.add_subparsers(dest="command", metavar="COMMAND")
    p = _command(sub, cmd_data, "data", help="list a dataset (class counts) or download ModelNet10")
    _dataset_arg(p)
    p.add_argument("--summary", action="store_true", help="print per-class object counts per split")
    p.add_argument("--download", action="store_true", help="download and extract ModelNet10 (needs internet)")
    p.add_argument("--root", help="folder for the ModelNet10 download (default: $HBEO_DATA or ~/.cache/hbeo)")
    p = _command(sub, cmd_voxelize, "voxelize", help="voxelize a dataset into 30^3 grids (cached, resumable)")
    _dataset_arg(p)
    p.add_argument("--out", help="output folder (default: results/PROFILE-DATASET), or FILE.npz: every object "
                                 "in one file of the published modelnet10_vox30.npz layout")
    p.add_argument("--workers", type=_local_workers, help=_WORKERS_HELP)
    p.add_argument("--strict", action="store_true",
                   help="exit with status 2 if any object fails (default: skip it, list it in failures.json)")
    p = _command(sub, cmd_subspace, "subspace", help="fit the shared VBPCA subspace; print components and completion errors")
    _dataset_arg(p, profile="full")
    p.add_argument("--out", help="output folder (default: results/PROFILE-DATASET)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--variance", type=FRACTION, default=0.6, help="variance fraction per class (default 0.6, the paper's)")
    g.add_argument("--shared-dim", type=COUNT, help="choose one variance fraction giving this shared dimension (paper: 344)")
    g.add_argument("--components", type=COUNT, help="fixed component count per class")
    p.add_argument("--method", choices=("lstsq", "lasso"), default="lstsq", help="partial projection solver")
    p.add_argument("--known", type=OPEN_FRACTION, default=0.5, help="fraction of voxels known in the partial test (0.5)")
    p.add_argument("--seed", type=NONNEG, default=0, help="seed of the random mask")
    p = _command(sub, cmd_render, "render", help="render segmented depth images with pose/class/shape labels (resumable)")
    _dataset_arg(p)
    p.add_argument("--out", help="output folder; sets go to OUT/render_SPLIT (default: results/PROFILE-DATASET)")
    p.add_argument("--split", choices=("train", "test", "both"), default="train", help="split(s) to render (train)")
    p.add_argument("--views", type=COUNT, help="views per object (default: the profile's)")
    p.add_argument("--sampler", choices=SAMPLERS, default="so3", help=_SAMPLER_HELP)
    p.add_argument("--noise", action="store_true", help="apply the Kinect-like sensor noise model")
    p.add_argument("--workers", type=_local_workers,
                   help="processes of the local Dask cluster (default: the profile's; 0: one per core this process "
                        "may use; unused with --scheduler)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="render on the running Dask scheduler at ADDRESS (e.g. tcp://host:8786) instead of a "
                        "local cluster; its workers must see --out at the same path and run the same hbeo")
    p.add_argument("--backend", choices=("auto", "pyrender", "embree", "torch"), default="auto",
                   help="renderer (auto); torch: ray-march each object's grid (grid datasets only)")
    p.add_argument("--seed", type=NONNEG, default=0, help="seed of the viewpoints and noise (0)")
    p.add_argument("--subspace", help="subspace.npz for shape coefficients (default: OUT/subspace.npz if present)")
    p.add_argument("--objects-per-shard", type=COUNT, help="objects per shard file (default: about 1024 images per shard)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--strict", action="store_true",
                   help="exit with status 2 if any object fails (default: skip it, list it in failures.json)")
    p = _command(sub, cmd_train, "train", help="train HBEONet (builds grids, subspace and renderings if missing)")
    _dataset_arg(p)
    p.add_argument("--out", help="run folder (default: results/PROFILE-DATASET)")
    p.add_argument("--epochs", type=COUNT, help="epochs (default: the profile's)")
    p.add_argument("--max-steps", type=COUNT, help="stop after this many optimizer steps (the schedule ends there)")
    p.add_argument("--checkpoint-every", type=COUNT, metavar="N",
                   help="also write the checkpoint every N steps (default: after every epoch only); a killed run "
                        "resumes from it")
    p.add_argument("--loader-workers", type=NONNEG, default=0, metavar="N",
                   help="worker processes that prepare batches while the network trains (default 0: none)")
    p.add_argument("--render-ahead", type=NONNEG, metavar="N",
                   help="--data stream --backend torch: images rendered in one march, served to the next batches "
                        "(default: up to 2048 on a GPU, as its free memory allows; one batch on the CPU); the same images")
    p.add_argument("--draw-workers", type=NONNEG, metavar="N",
                   help="--data stream --backend torch: processes that draw the next march's poses while this one "
                        "renders (default: up to 8 on a GPU, none on the CPU); the same images")
    p.add_argument("--views", type=COUNT, help="rendered views per training object (default: the profile's)")
    p.add_argument("--image-size", type=_image_size, metavar="W,H",
                   help="training image size in pixels, the camera scaled to it (default: the profile's; the model "
                        "is evaluated at its own size)")
    p.add_argument("--batch-size", type=COUNT, metavar="N", help="images per optimizer step (default: the profile's)")
    p.add_argument("--lr", type=POSITIVE, help="peak learning rate of AdamW (default: the profile's)")
    p.add_argument("--warmup-steps", type=COUNT, metavar="N",
                   help="steps of the learning rate's linear warm-up (default: 100, or one epoch when shorter)")
    p.add_argument("--data", choices=("memory", "shards", "stream"),
                   help="training images: the rendered set in memory, the rendered set read shard by shard, or "
                        "rendered on the fly with a fresh pose per object per pass (default: the profile's)")
    p.add_argument("--loss-weights", default="1,1,1",
                   help="gamma_c,gamma_o,gamma_p: weights of the class, pose and coefficient losses (1,1,1)")
    p.add_argument("--fc", help="W1,W2,W3: widths of HBEONet's three shared fully connected layers (default: the "
                                "profile's, hbeo.config.NetworkConfig.fc)")
    p.add_argument("--shape-loss", choices=("coeffs", "voxels"),
                   help="shape term: the standardized coefficient error (paper) or the completed grid's occupancy "
                        "error through the basis (default: the profile's recipe, hbeo.config.RecipeConfig.fit_kwargs)")
    p.add_argument("--class-balance", choices=("none", "sampler", "loss"),
                   help="class imbalance: none (the paper's), sampler (each class drawn equally often) or loss "
                        "(inverse-frequency weighted cross-entropy); default: the profile's recipe")
    p.add_argument("--sampler", choices=SAMPLERS, default="so3", help="training viewpoints; " + _SAMPLER_HELP)
    p.add_argument("--backend", choices=("auto", "pyrender", "embree", "torch"), default="auto",
                   help="renderer of the training views (auto); torch: ray-march each object's grid (grid "
                        "datasets only); with --data stream, whole batches on the training device")
    p.add_argument("--rotation", choices=("axis_angle", "6d", "bins"),
                   help="pose output: the paper's axis-angle, the continuous 6-D representation, or a distribution "
                        "over a grid of rotations (bins); default: the profile's recipe")
    p.add_argument("--normalize", choices=("none", "center"), default="none",
                   help="depth input: metres as rendered (paper, default) or centred on the object's median depth")
    p.add_argument("--augment-roll", action=argparse.BooleanOptionalAction,
                   help="roll each training view by a random angle about the optical axis every epoch (exact; "
                        "default: the profile's recipe)")
    p.add_argument("--augment-mirror", action="store_true",
                   help="mirror each training view left-right with probability 1/2 every epoch, its object across "
                        "its class's mirror plane (exact; --data memory; default off)")
    p.add_argument("--noise", action="store_true",
                   help="train on views with the Kinect-like sensor noise, each view its own draw (render settings: "
                        "a run folder with clean renderings refuses it; use another --out)")
    p.add_argument("--noise-scale", type=COUNT, default=1, metavar="S",
                   help="with --noise: render each training view at S times the image size, apply the noise there "
                        "and read every S-th pixel, as predict reads a sensor's frame (8 at 80x60: a 640x480 "
                        "sensor; S*S times the rendering); 1 (default): the noise at the image's size")
    p.add_argument("--noise-fraction", type=FRACTION, default=1.0, metavar="F",
                   help="with --noise: only each object's first F * --views views carry the noise (a whole number), "
                        "the rest are the clean set's views (not --data stream); 1 (default): every view")
    p.add_argument("--recenter", action="store_true", help="turn every view to look straight at the object")
    p.add_argument("--ref-distance", type=POSITIVE, help="distance-insensitive input: zoom to this object distance (m)")
    p.add_argument("--seed", type=NONNEG, help="training seed (default 0)")
    p.add_argument("--name", default=DEFAULT_MODEL, help=f"model file name in the run folder ({DEFAULT_MODEL})")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p = _command(sub, cmd_predict, "predict", help="class, pose and completed shape from one depth image")
    p.add_argument("--model", required=True, help="model file (model.hbeo)")
    p.add_argument("--precision", choices=("float32", "bfloat16"), default="float32",
                   help="network arithmetic (bfloat16: faster on CPUs with AVX512-BF16, ~99%% class agreement)")
    p.add_argument("--rolls", type=COUNT, default=1,
                   help="average over this many camera rolls (rotation-bins models; N network passes; 1 = off)")
    p.add_argument("--depth", required=True, help="depth image: 16-bit PNG in mm, or float .npy/.tiff in m")
    p.add_argument("--intrinsics", required=True, help="fx,fy,cx,cy in pixels")
    p.add_argument("--mask", help="object mask image (PNG, .npy or .tiff: 0 = background, one non-zero value = "
                   "object; a blurred mask is refused), same size as the depth")
    p.add_argument("--depth-scale", type=POSITIVE, help="metres per stored unit (default 0.001 for integer images)")
    p.add_argument("--out", required=True, help="result JSON")
    p.add_argument("--mesh", help="also write the completed shape, placed in the camera frame (.ply/.obj/.stl)")
    p.add_argument("--face-object", action="store_true",
                   help="turn the view toward the object's estimated centre first, as far as the model needs "
                        "(two passes; for an object off the optical axis of a model trained without --recenter; "
                        "docs/your-depth-image.md)")
    _add_verify(p)
    _add_prior(p)
    _add_ensemble(p)
    _add_mirror(p)
    _add_completion(p)
    p = _command(sub, cmd_evaluate, "evaluate", help="render a dataset's views, predict and write the metrics JSON")
    p.add_argument("--model", required=True, help="the run's model.hbeo (its camera and views are used for "
                                                  "every method; baselines live beside it)")
    p.add_argument("--precision", choices=("float32", "bfloat16"), default="float32",
                   help="HBEO's network arithmetic (default float32)")
    p.add_argument("--rolls", type=COUNT, default=1,
                   help="HBEO test-time augmentation: average over this many camera rolls (bins models; 1 = off)")
    p.add_argument("--method", choices=("hbeo", "beo", "icp", "voxcnn"), default="hbeo",
                   help="hbeo (default), beo, icp or voxcnn (fitted/trained in the model's folder if missing)")
    p.add_argument("--max-steps", type=COUNT,
                   help="voxcnn: when it must be trained first, stop after this many optimizer steps")
    _add_verify(p)
    _add_prior(p)
    _add_ensemble(p)
    _add_mirror(p)
    _add_completion(p)
    p.add_argument("--pose", choices=("known", "1dof", "3dof"),
                   help="what the method must estimate: hbeo 3dof; beo known|1dof|3dof; icp 1dof|3dof; voxcnn known")
    p.add_argument("--batch", action="store_true",
                   help="HBEO's one pass: each chunk of views through the network in one call (the same answers; "
                        "ms per query is the batch's time shared; not with --verify)")
    p.add_argument("--dataset", default="procedural", help="procedural | modelnet10 | modelnet10-vox30 | PATH")
    p.add_argument("--split", choices=("train", "test", "val"), default="test",
                   help="test (default); val: the training objects that training held out, where choices are made "
                        "(each evaluation is added to validation.csv beside the model)")
    p.add_argument("--views", type=COUNT, default=1, help="views per object (1)")
    p.add_argument("--seed", type=NONNEG, default=0)
    p.add_argument("--sampler", choices=SAMPLERS,
                   help="viewpoints (default: the model's training sampler); " + _SAMPLER_HELP)
    p.add_argument("--noise", action="store_true", help="apply Kinect-like sensor noise")
    p.add_argument("--noise-scale", type=COUNT, default=1, metavar="S",
                   help="with --noise: render each query at S times the model's image size, apply the noise there "
                        "and read every S-th pixel, as predict reads a finer frame (8 at 80x60: a 640x480 "
                        "sensor); 1 (default): the noise at the model's size, coarser relative to the object")
    p.add_argument("--per-class", type=COUNT, help="at most this many objects per class")
    p.add_argument("--strict", action="store_true",
                   help="exit 2 when any object could not be evaluated (default: report it, score the rest)")
    p.add_argument("--out", required=True, help="metrics JSON (keys: see hbeo/evaluation/evaluate.py)")
    p.add_argument("--quiet", action="store_true")
    p = _command(sub, cmd_convert_model, "convert-model", help="rewrite an old-format (torch pickle) model file in the current "
                                             "format, reading it without running code it may carry")
    p.add_argument("old", help="old model file (model.hbeo or voxcnn.pt written by hbeo before format 2)")
    p.add_argument("new", help="new model file (may be OLD itself: replaced once the conversion checks out)")
    p = _command(sub, cmd_reproduce, "reproduce", help="run the numbered notebooks with papermill into results/")
    _dataset_arg(p, profile="quick")
    p.add_argument("--out", help="output folder (default: results/PROFILE-DATASET, -seedS added for --seed S; a "
                   "relative path is taken from the repository root)")
    p.add_argument("--seed", type=NONNEG, default=0, help="training seed of every model the run trains (HBEONet, "
                   "the 3-D CNN); data, renderings and test views keep seed 0, so seeds score the same images (0)")
    p.add_argument("--only", nargs="*", help="notebook name prefixes to run (default: all)")
    p.add_argument("--fresh", action="store_true", help="first remove the run's models, baselines, metrics, "
                   "notebooks, tables, figures and report (make reproduce does; without it, what the folder holds is "
                   "read and an interrupted run goes on: make reproduce RESUME=1)")
    p = _command(sub, cmd_report, "report", help="write RUN/REPRODUCTION.md (reported vs. reproduced) from a finished run")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--run", help="run folder, e.g. results/cpu-modelnet10-vox30")
    g.add_argument("--seeds", nargs="+", metavar="RUN", help="instead: the spread over training seeds of these runs "
                   "(one profile and dataset, one run per seed, at least 2) -> seeds_table.csv/.md and seeds_claims.csv/.md "
                   "in --out")
    g.add_argument("--completion-decomposition", metavar="RUN", help="instead: the completion error of RUN's HBEO "
                   "taken apart (validation threshold scan, ceilings, coefficients, elevation) -> "
                   "RUN/06_completion_decomposition.csv/.md")
    p.add_argument("--out", help="output file (default: RUN/REPRODUCTION.md; the committed one: paper/REPRODUCTION.md); "
                                 "with --seeds: a folder (default: the first RUN)")
    p.add_argument("--model-table", action="store_true",
                   help="instead: the model table (validation / test) from the run's models.json -> model_table.md")
    p.add_argument("--readme", help="also replace the generated block (summary, or with --model-table the tables) in "
                                    "this Markdown file (README.md, or docs/experiments.md for the model table)")
    p = _command(sub, cmd_book, "book", help="render a run folder's executed notebooks, tables and figures to a static "
                                    "HTML site that opens offline")
    p.add_argument("run", help="run folder (results/<profile>-<dataset>)")
    p.add_argument("out", nargs="?", help="where the book goes (default: RUN/book)")
    _experiment_parser(sub)
    return ap


def main(argv=None) -> int:
    """Parse ``argv`` and run the subcommand. The one error boundary: hbeo's errors, ValueErrors and
    operating-system errors (``PATH: what happened``) are one line ``error: ...`` and exit 2; anything
    else is a bug: its traceback, a line saying so, exit 1."""
    ap = build_parser()
    args = ap.parse_args(_join_list_values(list(sys.argv[1:] if argv is None else argv)))
    if not getattr(args, "func", None):
        ap.print_help()
        return 0
    try:
        return args.func(args)
    except (HBEOError, ValueError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:
        print(f"error: {os_error_line(err)}", file=sys.stderr)
        return 2
    except ModuleNotFoundError as err:
        if not err.name or err.name.split(".")[0] == "hbeo":
            return _bug(err)                # a module of hbeo's own missing is a bug
        print(f"error: {missing_package_line(err.name)}", file=sys.stderr)
        return 2
    except Exception as err:                # noqa: BLE001 - anything else is a bug, said so once
        return _bug(err)
