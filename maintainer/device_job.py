"""The device job: train a run's model in the background, evaluate it with the paired protocol, and
leave what must come back under a lent GPU machine's transfer limits.

    python maintainer/device_job.py [--profile gpu-lease] [--dataset modelnet10-vox30] [--run DIR]
                                 [--out DIR] [--wait SECONDS] [--budget SECONDS] [--split test|val]
                                 [--data stream] [--backend torch] [--class-balance sampler] [--epochs N] [--seed S]
                                 [--render-ahead N] [--draw-workers N] [--loss-weights C,O,P] [--fc W1,W2,W3]
                                 [--batch-size N] [--lr LR] [--warmup-steps N] [--warmup-share F]

The training flags override the profile's recipe as ``python -m hbeo train``'s do (e.g. the ``cpu`` profile's
recipe with fresh views rendered on the GPU: ``--profile cpu --data stream --backend torch``); ``--split val``
evaluates on the validation objects instead of the test split, for choosing between recipes
(``eval_val_hbeo_3dof.json``). ``lease.json`` records both (``train_options``, ``split``).

One call does what is left, never more than ``--wait`` seconds in the foreground:

1. If the run's model is missing and no worker is alive, it starts one (a new process session, so it
   outlives the call on a machine that stays warm): ``Run.train`` with the profile's recipe and data
   source (checkpoints every ``--checkpoint-every`` steps; a worker started again resumes exactly from
   the last checkpoint), then the paired HBEO evaluation on the whole test split
   (:func:`hbeo.evaluation.protocol.evaluation`), then ``lease.json`` (device, wall time per stage,
   images seen, resumed step, the command).
   With ``--budget SECONDS`` the worker fits the whole job into that wall time: it makes the subspace, warms up,
   times ``--calibrate`` steps of the real training (a throw-away model, ``calibration.hbeo``), and trains the real
   model for the number of steps that fit (the schedule ends there, as with ``--max-steps``), keeping
   ``--eval-reserve`` seconds for the evaluation; ``lease.json``'s ``budget`` says what was measured and the
   steps chosen (its ``steps``: those trained, fewer when the profile plans fewer). A restarted worker keeps the step count it chose first. The
   evaluation runs HBEO's network on the GPU (``cuda`` when there is one; the metrics' ``device`` says so), a chunk
   of views per network call (``batched``: the same answers as one view at a time).
   With ``--first-minute SECONDS`` a fresh job first runs ``benchmarks/bench_gpu_first_minute.py`` in the
   foreground for at most that long (``--cpu-check`` where there is no GPU); its figures go into ``lease.json``'s
   ``first_minute``, the worker's ``--budget`` is what is left of the job's, and the marcher the worker trains
   with follows the benchmark's agreement stage (:func:`marcher_choice`, a rule fixed before any GPU result), and
   so does its batch (:func:`batch_choice`: 256, or 512, instead of the ``full`` profile's 128 only where
   validated, on the fused marcher and at least 1.3, or 1.8, times as fast).
2. It waits for the worker until it finishes or ``--wait`` (counted from the call's start) runs out; then it says
   so: call again, on the same warm machine, to go on waiting (a cut worker is restarted from its checkpoint).
3. It copies into ``--out`` (the device's ``$OUT``) what exists, every :data:`PACK_EVERY` seconds while it waits,
   when it is stopped by a signal (SIGTERM: the device tool's time limit) and at its end, each file whole (a
   temporary name, then renamed), so a call cut short still brings back the last pack: ``lease.json``, the metrics
   ``eval_hbeo_3dof.json``, the training curves ``train_log.csv``, ``provenance.json``, the worker's
   ``job.log``, and the model gzipped and split into parts of at most 15 MiB (``model.hbeo.gz.part00`` ...;
   join them with ``cat model.hbeo.gz.part* | gunzip > model.hbeo``; ``lease.json`` holds its SHA-256; packed
   once the worker records it final, with what trained, before it evaluates: ``model_final``):
   at most 8 files, under 64 MiB. The paper's network (61 MB of float32 weights, plus a 31 MB subspace)
   fits only because the worker first rounds the weights to bfloat16 values (still float32, the low 16 bits
   zero, so they compress by half; ``--no-round`` keeps them): the evaluation scores that rounded model, the
   one that comes back, and ``lease.json`` keeps the unrounded file's SHA-256.

Exit status 0 when the job is finished and packed, 3 while the worker is still running, 1 if it failed
(its ``job.log`` is packed either way). ``bash maintainer/device_job.sh`` wraps it for the device (carried
wheels installed first); ``maintainer/device_prepare.sh`` makes what must travel.
"""
from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

PART_BYTES = 15 * 2**20          # one file back from the device: at most 16 MiB
MAX_PARTS = 3                    # beside 5 other files: 8 files and under 64 MiB in all
PACK_EVERY = 10                  # seconds between the packs a waiting call makes (and one at its end)
WARMUP_STEPS = 5                 # --budget: untimed training steps before the timed calibration
STATE = "job_state.json"         # the worker's stages, written atomically by the worker
FIRST_MINUTE = "first_minute.json"   # --first-minute: the benchmark's figures, in the run folder
#: --first-minute's rule for training on the fused marcher (hbeo.render.fused) rather than the torch one, fixed
#: before any GPU result: the agreement stage ran without error on both marchers (and no render batch failed on
#: the fused one), at most this share of its
#: pixels are hit by one marcher and missed by the other (1e-5: under one pixel an image at 320x240), and no
#: depth that both hit differs by more than this (1 mm: below the float16 step the stored depth keeps, 2**-10 m
#: from 1 m on, and far below the sensor noise).
AGREE_MAX_FLIP_SHARE = 1e-5
AGREE_MAX_DEPTH_M = 1e-3
#: --first-minute's rule for the batch, fixed before any GPU result: a job whose profile trains at batch 128 and peak
#: learning rate 0.001 (:data:`LARGE_BATCH_FROM`, the ``full`` profile's) trains at the largest batch of
#: :data:`LARGE_BATCHES` whose experiment (experiments/cpu-modelnet10-vox30/) passed on the validation objects
#: (``validated``: batch B given ``min_speedup`` times the images of batch 128 fell at most 1 point of class mean and
#: 2 of poses within 30 degrees below it, over three training seeds a side) and whose ``both`` stage (the fused
#: march, then the loop's bfloat16 step) ran at least ``min_speedup`` times as many images a second at batch B as at
#: 128, when the worker trains on the fused marcher: then a lease of fixed length shows batch B at least the
#: images it was validated with. The warm-up is a share of the steps the budget chose (one epoch in the
#: validated epochs). ``validated`` is each experiment's outcome: None while pending, False when it missed.
LARGE_BATCH_FROM = {"batch_size": 128, "lr": 1e-3}
LARGE_BATCHES = (
    {"batch_size": 512, "lr": 8e-3, "warmup_share": 1 / 18, "min_speedup": 1.8, "experiment": "batch512-e18-seeds",
     "validated": True},         # passed (2026-12-06): class mean +0.1, within 30 deg +4.1 points over 3 seeds a side
    {"batch_size": 256, "lr": 4e-3, "warmup_share": 1 / 13, "min_speedup": 1.3, "experiment": "batch256-e13-seeds",
     "validated": True},         # passed (2026-12-06): class mean +1.1, within 30 deg +5.0 points over 3 seeds a side
)
LOG = "job.log"


def _write_json(path: Path, data: dict) -> None:
    from hbeo.storage import atomic_text
    atomic_text(path, json.dumps(data, indent=1))


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _alive(pid: int | None) -> bool:
    if not pid:
        return False
    try:
        os.kill(int(pid), 0)
    except (OSError, ValueError):
        return False
    try:                                 # a zombie (finished, not yet reaped) is not alive
        with open(f"/proc/{int(pid)}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


def marcher_choice(report: dict) -> dict:
    """The marcher the worker trains with, from the first-minute benchmark's JSON (``report``):
    ``{"gridcast": "auto" | "torch", "reason": ...}``. ``auto`` (GridCaster's default: the fused marcher on a
    GPU where triton imports) only when the agreement stage meets :data:`AGREE_MAX_FLIP_SHARE` and
    :data:`AGREE_MAX_DEPTH_M` and no batch of the render stage that a training march reaches
    (:data:`hbeo.render.gridcast.RENDER_AHEAD`) failed on the fused marcher; else ``torch``, the
    reference march, and the reason says why."""
    errors = report.get("errors") or {}
    for stage in ("setup", "compile", "agreement"):
        if stage in errors:
            return {"gridcast": "torch", "reason": f"the {stage} stage failed: {errors[stage]}"}
    from hbeo.render.gridcast import RENDER_AHEAD
    failed = [r for r in (report.get("render") or {}).get("triton", []) if "error" in r and r["batch"] <= RENDER_AHEAD]
    if failed:                                   # a batch the training's marches reach failed on the fused marcher
        return {"gridcast": "torch", "reason": f"the fused marcher failed at batch {failed[0]['batch']}: "
                                               f"{failed[0]['error']}"}
    a = report.get("agreement") or {}
    if not a.get("pixels"):
        return {"gridcast": "torch", "reason": "the agreement stage did not run (cut by its time limit?)"}
    flips = a["hit_torch_only"] + a["hit_triton_only"]
    share = flips / a["pixels"]
    said = (f"{flips} of {a['pixels']} pixels hit by one marcher only (share {share:.2g}, at most "
            f"{AGREE_MAX_FLIP_SHARE:g}), largest depth difference {a['max_abs_diff_m']:.3g} m (at most "
            f"{AGREE_MAX_DEPTH_M:g})")
    if share > AGREE_MAX_FLIP_SHARE or a["max_abs_diff_m"] > AGREE_MAX_DEPTH_M:
        return {"gridcast": "torch", "reason": "the marchers disagree: " + said}
    return {"gridcast": "auto", "reason": "the marchers agree: " + said}


def batch_choice(report: dict, gridcast: str, recipe, args) -> dict:
    """The batch the worker trains with, from the first-minute benchmark's JSON (``report``), the marcher
    :func:`marcher_choice` chose (``gridcast``), the profile's ``recipe`` and the job's flags (``args``):
    ``{"batch_size": None (the profile's) or one of LARGE_BATCHES', "lr", "warmup_share", "speedup" (measured, of
    the batch that decided), "reason"}`` by the rule of :data:`LARGE_BATCHES` (fixed before any GPU result)."""
    def keep(reason, speedup=None):
        return {"batch_size": None, "lr": None, "warmup_share": None, "speedup": speedup, "reason": reason}

    def unvalidated(tier) -> str:
        return tier["experiment"] + (" is pending" if tier["validated"] is None else
                                     " did not pass on the validation objects")
    if any(getattr(args, k, None) is not None for k in ("batch_size", "lr", "warmup_steps", "warmup_share")):
        return keep("the batch or learning rate was given on the command line")
    base = LARGE_BATCH_FROM["batch_size"]
    if {"batch_size": recipe.batch_size, "lr": recipe.lr} != LARGE_BATCH_FROM:
        return keep(f"the rule is for batch {base} at learning rate {LARGE_BATCH_FROM['lr']:g}; this profile "
                    f"trains at batch {recipe.batch_size}, {recipe.lr:g}")
    if not any(t["validated"] for t in LARGE_BATCHES):
        return keep("; ".join(unvalidated(t) for t in LARGE_BATCHES))
    if not args.budget:
        return keep("no --budget: the large batch's warm-up is a share of the steps a budget chooses")
    if gridcast != "auto":
        return keep("the worker trains on the torch march, whose speed the rule did not measure")
    rows = {r.get("batch"): r.get("images_per_s") for r in (report.get("both") or {}).get("rows", [])}
    small, passed_over, speedup = rows.get(base), [], None
    for tier in LARGE_BATCHES:                   # the largest first
        b = tier["batch_size"]
        if not tier["validated"]:
            passed_over.append(f"batch {b}: {unvalidated(tier)}")
            continue
        large = rows.get(b)
        if not (small and large):
            passed_over.append(f"batch {b}: the both stage did not measure batches {base} and {b} (cut by its "
                               "time limit?)")
            continue
        speedup = round(large / small, 3)
        said = (f"the fused march and the bfloat16 step ran {large:.0f} images/s at batch {b}, {small:.0f} at "
                f"{base}: {speedup:.2f} times (at least {tier['min_speedup']})")
        if speedup >= tier["min_speedup"]:
            return {"batch_size": b, "lr": tier["lr"], "warmup_share": tier["warmup_share"], "speedup": speedup,
                    "reason": "; ".join([said, *(f"passed over {p}" for p in passed_over)])}
        passed_over.append(f"batch {b}: too little faster: " + said)
    return keep("; ".join(passed_over), speedup)


def first_minute(args) -> dict:
    """Run the first-minute benchmark for at most ``args.first_minute`` seconds (its JSON is rewritten after
    every stage, so a cut run keeps what it measured) and choose the worker's marcher and batch from it."""
    import torch
    out = Path(args.run) / FIRST_MINUTE
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_gpu_first_minute.py"), "--out", str(out),
           "--profile", args.profile]
    if not torch.cuda.is_available():
        cmd.append("--cpu-check")
    t0 = time.perf_counter()
    print(f"[job] first minute: {' '.join(cmd[1:])} (at most {args.first_minute:.0f} s)", flush=True)
    with open(Path(args.run) / LOG, "ab") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, cwd=ROOT,
                                env={**os.environ, "PYTHONUNBUFFERED": "1"})
        try:
            code = proc.wait(timeout=args.first_minute)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            code = "timeout"
        except BaseException:                    # the job stopped by a signal: no benchmark left running
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
    report = _read_json(out)
    done = {"seconds": round(time.perf_counter() - t0, 1), "limit_s": args.first_minute, "exit": code,
            "command": " ".join(["python", *[str(Path(c).relative_to(ROOT)) if c.startswith(str(ROOT)) else c
                                             for c in cmd[1:]]]),
            **marcher_choice(report), "report": report}
    from hbeo.config import get_profile
    done["batch"] = batch_choice(report, done["gridcast"], get_profile(args.profile).recipe, args)
    batch = done["batch"]["batch_size"] or "the profile's"
    print(f"[job] first minute: {done['seconds']} s, stages {report.get('stages_done')}; marcher "
          f"{done['gridcast']}: {done['reason']}; batch {batch}: {done['batch']['reason']}", flush=True)
    return done


def source() -> dict:
    """The code the job runs: ``{"commit", "dirty"}`` from ``$HBEO_DEVICE_SOURCE`` (``source.json``, written by
    ``device_prepare.sh`` where the checkout is, since the device's copy has no ``.git``), else from git here
    (:func:`hbeo.report.provenance.git_state`, outside what ``device_tree.sh slim`` leaves behind), else
    ``{"commit": None}``."""
    path = os.environ.get("HBEO_DEVICE_SOURCE")
    if path and Path(path).exists():
        return {**_read_json(Path(path)), "from": "source.json"}
    from hbeo.report.provenance import git_state
    git = git_state(exclude=("results", "docs/history"))
    return {"commit": git["git_commit"], "dirty": git["git_dirty"], "from": "git" if git["git_commit"] else None}


def device_name() -> str:
    """The device the training loop picks (``auto``: CUDA where there is one), in words."""
    import torch
    if torch.cuda.is_available():
        return f"cuda: {torch.cuda.get_device_name(0)} (torch {torch.__version__}, CUDA {torch.version.cuda})"
    return f"cpu: {os.cpu_count()} cores (torch {torch.__version__})"


def summary(m: dict) -> dict:
    """The headline of an evaluation: n, accuracy, class-mean accuracy (the paper's Table I figure),
    median pose error, share within 30 degrees, mean IoU."""
    per = [c["accuracy"] for c in m.get("per_class", {}).values() if c.get("n")]
    return {"n_queries": m.get("n_queries"), "n_objects": m.get("n_objects"), "accuracy": m.get("accuracy"),
            "class_mean_accuracy": sum(per) / len(per) if per else None,
            "pose_median_deg": m.get("pose_error_deg", {}).get("median"),
            "pose_within_30": m.get("pose_error_deg", {}).get("within_30"),
            "iou": m.get("completion", {}).get("iou")}


def round_weights_bf16(path: Path) -> None:
    """Round the model file's float32 weights to the nearest bfloat16 values, in place (atomically), still
    stored as float32: the low 16 bits become zero, so the packed file compresses to about half and the
    paper's network (61 MB of weights) comes back inside the transfer limit. The evaluation then scores
    the rounded model, the one that comes back."""
    import torch
    from hbeo.model.inference import HBEO
    model = HBEO.load(path)
    with torch.no_grad():
        for t in list(model.net.parameters()) + list(model.net.buffers()):
            if t.dtype == torch.float32:
                t.copy_(t.to(torch.bfloat16).to(torch.float32))
    model.save(path)


#: ``python -m hbeo train`` options the device job passes on (TrainOptions' names; None: the profile's)
TRAIN_FLAGS = ("data", "backend", "class_balance", "epochs", "seed", "render_ahead", "draw_workers", "loss_weights",
               "fc", "batch_size", "lr", "warmup_steps")
VAL_EVAL = "eval_val_hbeo_3dof.json"     # --split val: the validation objects' metrics (the run's own test file
                                         # keeps its name, eval_hbeo_3dof.json)


def train_flags(args) -> dict:
    """The training flags (:data:`TRAIN_FLAGS`) the job was given, by TrainOptions' names."""
    return {k: getattr(args, k) for k in TRAIN_FLAGS if getattr(args, k, None) is not None}


def train_options(args, **kw):
    """The worker's TrainOptions: the job's training flags (:func:`train_flags`; ``--loss-weights`` and
    ``--fc`` as text, parsed here as ``python -m hbeo train`` parses them) and ``kw``."""
    from hbeo.model.fit import TrainOptions, parse_fc, parse_loss_weights
    flags = train_flags(args)
    if "loss_weights" in flags:
        flags["loss"] = parse_loss_weights(flags.pop("loss_weights"))
    if "fc" in flags:
        flags["fc"] = parse_fc(flags["fc"])
    return TrainOptions(**flags, **kw)


def fit_budget(run, args, t_start: float) -> dict:
    """How many training steps fit ``args.budget`` seconds of this worker (counted from ``t_start``): the
    subspace first (the real run reuses it), then :data:`WARMUP_STEPS` steps of the real training into a
    throw-away model, to warm this process up (on an H200 the first 40 steps ran at a quarter of the speed
    of the rest: lease of 2026-11-26), then ``args.calibrate`` steps into another; from the calibration's
    wall time and its in-loop images/s, the fixed cost of a training (data on the device, validation,
    saving) and the time per step; the calibration runs under :func:`hbeo.model.hostwaits.host_waits` (on a GPU
    the host's waits for it, counted by the line that led to each: ``host_waits``, ``host_wait_sites``, the
    twelve most). The steps are those left
    once the fixed cost, ``args.eval_reserve`` seconds for the evaluation and a 5 % margin are set aside
    (at least ``args.calibrate``: a budget too small still trains a little, and says so)."""
    from hbeo.model.loop import training_history
    t = time.perf_counter()
    run.subspace(progress=False)
    subspace_s = time.perf_counter() - t
    t = time.perf_counter()                  # warm-up first (CUDA context, cuDNN's autotuning, the caster's first
    run.train(train_options(args, name="calibration-warmup.hbeo", max_steps=WARMUP_STEPS), progress=False)  # batches)
    warmup_s = time.perf_counter() - t       # in this process: the real training after it is warm too
    from hbeo.model.hostwaits import host_waits
    from hbeo.model.loop import pick_device
    t = time.perf_counter()
    with host_waits(pick_device().type) as waits:   # where the host waits (a count)
        cal = run.train(train_options(args, name="calibration.hbeo", max_steps=args.calibrate), progress=False)
    calibration_s = time.perf_counter() - t
    row = training_history(run.dir.training(cal.path))[-1]
    batch = batch_size(args, run.profile)
    loop_s = row["step"] * batch / row["images_per_s"]
    step_s = loop_s / row["step"]
    fixed_s = max(calibration_s - loop_s, 0.0)
    left = args.budget - (time.perf_counter() - t_start) - args.eval_reserve - fixed_s
    steps = int(0.95 * left / step_s)
    out = {"seconds": args.budget, "subspace_s": round(subspace_s, 1), "warmup_steps": WARMUP_STEPS,
           "warmup_s": round(warmup_s, 1), "calibration_steps": int(row["step"]),
           "calibration_s": round(calibration_s, 1), "step_s": round(step_s, 4), "fixed_s": round(fixed_s, 1),
           "calibration_images_per_s": round(row["images_per_s"], 1), "eval_reserve_s": args.eval_reserve,
           "max_steps": max(steps, args.calibrate), "too_small": steps < args.calibrate,
           "host_waits": sum(waits.values()), "host_wait_sites": dict(waits.most_common(12))}
    if args.max_steps:
        out["max_steps"] = min(out["max_steps"], args.max_steps)
    print(f"[worker] budget {args.budget:.0f} s: {step_s * 1000:.0f} ms a step of {batch} images "
          f"({row['images_per_s']:.0f} images/s), fixed {fixed_s:.0f} s: training {out['max_steps']} steps", flush=True)
    return out


def worker(args) -> int:
    """The background process: train (resuming from the checkpoint), evaluate, write lease.json."""
    t_start = time.perf_counter()
    from hbeo.evaluation import protocol
    from hbeo.model.loop import load_checkpoint
    from hbeo.storage import sha256_file
    from hbeo.run import Run
    run = Run.open(args.profile, args.dataset, args.run)
    state_path = run.path / STATE
    state = _read_json(state_path)
    state.update(pid=os.getpid(), status="running", device=device_name(), source=source())
    state.setdefault("stages", {})
    _write_json(state_path, state)
    ckpt = run.dir.checkpoint(run.dir.model)
    resumed = int(load_checkpoint(ckpt)["step"]) if ckpt.exists() else None
    t0 = time.perf_counter()
    print(f"[worker] {state['device']}; profile {run.profile.name}, dataset {run.dataset.name}, run {run.path}"
          + (f"; resuming from step {resumed}" if resumed is not None else ""), flush=True)
    if not run.dir.model.exists():
        max_steps = args.max_steps
        if args.budget:
            if "budget" not in state:                   # chosen once: a restarted worker keeps the schedule
                state["budget"] = fit_budget(run, args, t_start)
                _write_json(state_path, state)
            max_steps = state["budget"]["max_steps"]
        extra = {}
        if args.warmup_share:                           # a share of the steps the budget chose (LARGE_BATCHES)
            extra["warmup_steps"] = state["warmup_steps"] = max(1, round(args.warmup_share * max_steps))
        opts = train_options(args, checkpoint_every=args.checkpoint_every, max_steps=max_steps, **extra)
        trained = run.train(opts, progress=False)
        state["stages"]["train_s"] = state["stages"].get("train_s", 0.0) + time.perf_counter() - t0
        state["resumed_from_step"] = resumed if state.get("resumed_from_step") is None else state["resumed_from_step"]
        log = _read_json(run.dir.training_provenance(trained.path))
        state["n_params"] = log.get("n_params")
        _write_json(state_path, state)
    if args.round_bf16 and not state.get("weights_rounded_to"):
        state["unrounded_model_sha256"] = sha256_file(run.dir.model)
        round_weights_bf16(run.dir.model)
        state["weights_rounded_to"] = "bfloat16"
        _write_json(state_path, state)
    if not state.get("model_final"):    # recorded before the evaluation: a lease cut during it still brings back
        state.update(trained_facts(run, args, ckpt), model_final=True)   # a model device_land.py can score here
        _write_json(state_path, state)
    t1 = time.perf_counter()
    print(f"[worker] trained: {run.dir.model}; evaluating on the {args.split} split", flush=True)
    from hbeo.model.loop import pick_device
    device = pick_device().type
    if args.split == "val":          # choosing between recipes: the validation objects, never the test split
        from hbeo.storage import atomic_text, json_text
        model = run.model(progress=False).to(device)
        metrics = protocol.evaluate_validation(model, run, progress=False)
        atomic_text(run.path / VAL_EVAL, json_text(metrics, indent=1))
    else:
        metrics = protocol.evaluation(run, "hbeo", "3dof", progress=False, device=device, batched=True)
    state["stages"]["evaluate_s"] = time.perf_counter() - t1
    state.update(status="done", metrics=summary(metrics))
    state["stages"]["wall_s"] = state["stages"].get("train_s", 0.0) + state["stages"]["evaluate_s"]
    _write_json(state_path, state)
    return 0


def batch_size(args, prof) -> int:
    """The job's batch: ``--batch-size`` (the first minute's choice, LARGE_BATCHES) or the profile's."""
    return args.batch_size or prof.recipe.batch_size


def trained_facts(run, args, ckpt: Path) -> dict:
    """What the worker trained, for ``lease.json``: profile, dataset, steps (the checkpoint's), batch, learning
    rate, image passes, image size, data source, the training flags, the evaluation's split, the training's
    provenance and the worker's command."""
    from hbeo.model.loop import load_checkpoint
    prof = run.profile
    steps = int(load_checkpoint(ckpt).get("step", 0)) if ckpt.exists() else 0
    batch, flags = batch_size(args, prof), train_flags(args)
    return {"profile": prof.name, "dataset": run.dataset.name, "steps": steps, "split": args.split,
            "train_options": flags, "batch_size": batch, "lr": args.lr or prof.recipe.lr,
            "images_seen": steps * batch, "image_size": list(prof.data.image_size),
            "train_data": flags.get("data", prof.data.train_data),
            "provenance": _read_json(run.dir.training_provenance(run.dir.model)),
            "command": " ".join(["python", str(Path(sys.argv[0]).resolve().relative_to(ROOT)), *sys.argv[1:]])}


def start_worker(args, state: dict) -> int:
    """The worker, in a new process session; with ``state``'s first minute, on the marcher it chose and with
    the budget that is left of the job's."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--profile", args.profile,
           "--dataset", args.dataset, "--run", str(args.run), *([] if args.round_bf16 else ["--no-round"]),
           "--checkpoint-every", str(args.checkpoint_every)]
    if args.max_steps:
        cmd += ["--max-steps", str(args.max_steps)]
    fm = state.get("first_minute") or {}
    if args.budget:
        left = max(args.budget - fm.get("seconds", 0.0), 1.0)
        cmd += ["--budget", f"{left:.1f}", "--calibrate", str(args.calibrate), "--eval-reserve", str(args.eval_reserve)]
    for k, v in train_flags(args).items():
        cmd += ["--" + k.replace("_", "-"), str(v)]
    large = fm.get("batch") or {}
    if large.get("batch_size"):                  # batch_choice's rule chose the large batch
        cmd += ["--batch-size", str(large["batch_size"]), "--lr", repr(large["lr"])]
    share = large.get("warmup_share") or args.warmup_share
    if share:
        cmd += ["--warmup-share", repr(share)]
    cmd += ["--split", args.split]
    log = open(Path(args.run) / LOG, "ab")
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    if fm.get("gridcast") == "torch":
        env["HBEO_GRIDCAST"] = "torch"
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, cwd=ROOT, env=env)
    return proc.pid


def pack(run_dir: Path, out: Path, state: dict, packed: dict | None = None) -> list[Path]:
    """Copy what must come back into ``out``: at most 8 files, none over :data:`PART_BYTES`, each written to a
    temporary name and renamed (:func:`hbeo.storage.atomic_bytes`), so a call cut by its time limit leaves whole
    files. The model goes once the worker says it is final (``model_final``: trained, rounded unless
    ``--no-round``), its SHA-256 and size into ``lease.json``; ``packed``, a dict one call keeps between its packs,
    remembers the model file already there, so packing again while the call waits gzips it only when it changed."""
    from hbeo.rundir import RunDir
    from hbeo.storage import atomic_bytes
    rd = RunDir(run_dir)
    out.mkdir(parents=True, exist_ok=True)
    packed = {} if packed is None else packed
    model = rd.model
    if state.get("model_final") and model.exists():
        st = model.stat()
        key = (st.st_size, st.st_mtime_ns)
        if packed.get("key") != key:
            data = model.read_bytes()
            gz = gzip.compress(data, compresslevel=6, mtime=0)
            parts = [gz[i:i + PART_BYTES] for i in range(0, len(gz), PART_BYTES)]
            if len(parts) > MAX_PARTS:
                raise SystemExit(f"{model}: {len(data)} bytes, {len(gz)} gzipped, need {len(parts)} parts of 15 MiB; "
                                 f"at most {MAX_PARTS} fit the transfer limit beside the other files")
            files = [out / f"{model.name}.gz.part{i:02d}" for i in range(len(parts))]
            for path, part in zip(files, parts):
                atomic_bytes(path, part)
            for stale in set(out.glob(f"{model.name}.gz.part*")) - set(files):    # an earlier, longer model
                stale.unlink()
            packed.update(key=key, files=files, model_sha256=hashlib.sha256(data).hexdigest(), model_bytes=len(data))
        state["model_sha256"], state["model_bytes"] = packed["model_sha256"], packed["model_bytes"]
    _write_json(out / "lease.json", state)
    written = [*packed.get("files", []), out / "lease.json"]
    for src in (rd.evaluation("hbeo", "3dof"), run_dir / VAL_EVAL, rd.train_log(model), rd.training_provenance(model),
                run_dir / LOG):
        if src.exists():
            atomic_bytes(out / src.name, src.read_bytes())
            written.append(out / src.name)
    return written


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--profile", default="gpu-lease")
    p.add_argument("--dataset", default="modelnet10-vox30")
    p.add_argument("--run", help="run folder (default: results/PROFILE-DATASET)")
    p.add_argument("--out", default=os.environ.get("OUT"), help="where the files to bring back go ($OUT)")
    p.add_argument("--wait", type=float, default=540, help="seconds to wait for the worker in this call (540)")
    p.add_argument("--checkpoint-every", type=int, default=500, metavar="STEPS")
    p.add_argument("--max-steps", type=int, help="stop training after this many steps (a smoke test)")
    p.add_argument("--budget", type=float, help="fit the worker's whole job (training and evaluation) into these "
                   "seconds: the training steps are chosen by timing a short calibration first")
    p.add_argument("--calibrate", type=int, default=40, metavar="STEPS", help="steps timed for --budget (40)")
    p.add_argument("--eval-reserve", type=float, default=120, metavar="SECONDS",
                   help="seconds of --budget kept for the evaluation (120)")
    p.add_argument("--no-round", dest="round_bf16", action="store_false",
                   help="keep the float32 weights unrounded (the paper's network then does not fit the way back)")
    p.add_argument("--split", choices=("test", "val"), default="test",
                   help="where the trained model is evaluated: the test split (the run's eval_hbeo_3dof.json) or, "
                        f"to choose between recipes, the validation objects ({VAL_EVAL})")
    g = p.add_argument_group("training (python -m hbeo train's options; default: the profile's)")
    g.add_argument("--data", choices=("memory", "shards", "stream"))
    g.add_argument("--backend", choices=("auto", "pyrender", "embree", "torch"))
    g.add_argument("--class-balance", choices=("none", "sampler", "loss"))
    g.add_argument("--epochs", type=int)
    g.add_argument("--seed", type=int)
    g.add_argument("--render-ahead", type=int, metavar="N",
                   help="stream/torch: images rendered in one march (default: up to 2048 on a GPU, as its free memory allows)")
    g.add_argument("--draw-workers", type=int, metavar="N",
                   help="stream/torch: processes that draw the next march's poses ahead (default: up to 8 on a GPU)")
    g.add_argument("--loss-weights", metavar="C,O,P", help="gamma_c,gamma_o,gamma_p of the loss (1,1,1)")
    g.add_argument("--fc", metavar="W1,W2,W3", help="widths of HBEONet's three shared layers (the profile's)")
    g.add_argument("--batch-size", type=int, help="images a step (the profile's; with --first-minute, chosen by "
                   "the rule of LARGE_BATCHES unless given)")
    g.add_argument("--lr", type=float, help="peak learning rate (the profile's)")
    g.add_argument("--warmup-steps", type=int, help="steps of the linear warm-up (100)")
    g.add_argument("--warmup-share", type=float, help="with --budget: a warm-up of this share of the steps the "
                   "budget chooses (what LARGE_BATCHES' rule passes on)")
    p.add_argument("--first-minute", type=float, default=0, metavar="SECONDS",
                   help="a fresh job first runs benchmarks/bench_gpu_first_minute.py for at most SECONDS, in the "
                        "foreground (figures in lease.json's first_minute; the worker's marcher chosen from its "
                        "agreement; --budget then counts it); 0: not (0)")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.budget is not None and not args.budget > 0:
        p.error(f"--budget must be a positive number of seconds, got {args.budget}")
    if not args.first_minute >= 0:
        p.error(f"--first-minute must be >= 0 seconds, got {args.first_minute}")
    if args.calibrate < 1 or not args.eval_reserve >= 0:
        p.error("--calibrate must be >= 1 and --eval-reserve >= 0")
    if (args.epochs is not None and args.epochs < 1) or (args.seed is not None and args.seed < 0):
        p.error("--epochs must be >= 1 and --seed >= 0")
    if args.warmup_share is not None and not (args.budget and 0 < args.warmup_share < 1
                                              and args.warmup_steps is None):
        p.error(f"--warmup-share must be between 0 and 1, needs --budget and excludes --warmup-steps, "
                f"got {args.warmup_share}")
    try:
        train_options(args)
    except ValueError as err:
        p.error(str(err))
    from hbeo.rundir import RunDir
    args.run = Path(args.run) if args.run else RunDir.for_run(args.profile, args.dataset).path
    args.run.mkdir(parents=True, exist_ok=True)
    if args.worker:
        try:
            return worker(args)
        except BaseException as err:          # the state says it failed; the log holds the traceback
            state = _read_json(args.run / STATE)
            _write_json(args.run / STATE, {**state, "status": "failed", "error": f"{type(err).__name__}: {err}"})
            raise
    t0 = time.monotonic()
    packed, stopped, last_pack = {}, False, -PACK_EVERY
    try:
        state = _read_json(args.run / STATE)
        if state.get("status") != "done" and not _alive(state.get("pid")):
            if state.get("status") == "running":
                print(f"[job] the worker {state.get('pid')} is gone: restarting it from its checkpoint", flush=True)
            elif args.first_minute and "first_minute" not in state and not RunDir(args.run).model.exists():
                state["first_minute"] = first_minute(args)
                _write_json(args.run / STATE, state)
            pid = start_worker(args, state)
            _write_json(args.run / STATE, {**state, "pid": pid, "status": "starting"})
            print(f"[job] worker {pid} started; log: {args.run / LOG}", flush=True)
        while True:
            state = _read_json(args.run / STATE)
            if state.get("status") in ("done", "failed") or not _alive(state.get("pid")):
                break
            if time.monotonic() - t0 > args.wait:
                break
            if args.out and time.monotonic() - last_pack >= PACK_EVERY:    # what exists so far, should the
                pack(args.run, Path(args.out), state, packed)              # call be cut by its time limit
                last_pack = time.monotonic()
            time.sleep(2)
    except KeyboardInterrupt:             # SIGTERM (a time limit) or ^C: pack what exists; the worker goes on
        stopped = True
        state = _read_json(args.run / STATE)
    status = state.get("status")
    if status in ("starting", "running") and not _alive(state.get("pid")):    # died, before or after it started
        status = "failed"
    if args.out:
        files = pack(args.run, Path(args.out), state, packed)
        print(f"[job] {status}: packed {', '.join(f.name for f in files)} into {args.out}", flush=True)
    if stopped and status not in ("done", "failed"):
        print(f"[job] stopped by a signal after {time.monotonic() - t0:.0f} s: call again to go on waiting",
              flush=True)
        return 3
    if status == "done":
        print(json.dumps(state.get("metrics", {}), indent=1))
        return 0
    if status == "failed":
        print(f"[job] failed: {state.get('error', 'see ' + str(args.run / LOG))}", file=sys.stderr)
        return 1
    print(f"[job] still running after {args.wait:.0f} s: call again to go on waiting", flush=True)
    return 3


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, signal.default_int_handler)
    sys.exit(main())
