"""The device job: train a run's model in the background, evaluate it with the paired protocol, and
leave what must come back under a lent GPU machine's transfer limits.

    python scripts/device_job.py [--profile gpu-lease] [--dataset modelnet10-vox30] [--run DIR]
                                 [--out DIR] [--wait SECONDS]

One call does what is left, never more than ``--wait`` seconds in the foreground:

1. If the run's model is missing and no worker is alive, it starts one (a new process session, so it
   outlives the call on a machine that stays warm): ``Run.train`` with the profile's recipe and data
   source (checkpoints every ``--checkpoint-every`` steps; a worker started again resumes exactly from
   the last checkpoint), then the paired HBEO evaluation on the whole test split
   (:func:`hbeo.evaluation.protocol.evaluation`), then ``lease.json`` (device, wall time per stage,
   images seen, resumed step, the command).
2. It waits for the worker until it finishes or ``--wait`` runs out (then it says so: call again, on the
   same warm machine, to go on waiting; a cut worker is restarted from its checkpoint).
3. It copies into ``--out`` (the device's ``$OUT``) what exists: ``lease.json``, the metrics
   ``eval_hbeo_3dof.json``, the training curves ``train_log.csv``, ``provenance.json``, the worker's
   ``job.log``, and the model gzipped and split into parts of at most 15 MiB (``model.hbeo.gz.part00`` ...;
   join them with ``cat model.hbeo.gz.part* | gunzip > model.hbeo``; ``lease.json`` holds its SHA-256):
   at most 8 files, under 64 MiB. The paper's network (61 MB of float32 weights, plus a 31 MB subspace)
   fits only because the worker first rounds the weights to bfloat16 values (still float32, the low 16 bits
   zero, so they compress by half; ``--no-round`` keeps them): the evaluation scores that rounded model, the
   one that comes back, and ``lease.json`` keeps the unrounded file's SHA-256.

Exit status 0 when the job is finished and packed, 3 while the worker is still running, 1 if it failed
(its ``job.log`` is packed either way). ``bash scripts/device_job.sh`` wraps it for the device (carried
wheels installed first); ``scripts/device_prepare.sh`` makes what must travel.
"""
from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

PART_BYTES = 15 * 2**20          # one file back from the device: at most 16 MiB
MAX_PARTS = 3                    # beside 5 other files: 8 files and under 64 MiB in all
STATE = "job_state.json"         # the worker's stages, written atomically by the worker
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


def worker(args) -> int:
    """The background process: train (resuming from the checkpoint), evaluate, write lease.json."""
    from hbeo.evaluation import protocol
    from hbeo.model.fit import TrainOptions
    from hbeo.model.loop import load_checkpoint
    from hbeo.storage import sha256_file
    from hbeo.run import Run
    run = Run.open(args.profile, args.dataset, args.run)
    state_path = run.path / STATE
    state = _read_json(state_path)
    state.update(pid=os.getpid(), status="running", device=device_name())
    state.setdefault("stages", {})
    _write_json(state_path, state)
    ckpt = run.dir.checkpoint(run.dir.model)
    resumed = int(load_checkpoint(ckpt)["step"]) if ckpt.exists() else None
    t0 = time.perf_counter()
    print(f"[worker] {state['device']}; profile {run.profile.name}, dataset {run.dataset.name}, run {run.path}"
          + (f"; resuming from step {resumed}" if resumed is not None else ""), flush=True)
    if not run.dir.model.exists():
        opts = TrainOptions(checkpoint_every=args.checkpoint_every, max_steps=args.max_steps)
        trained = run.train(opts, progress=False)
        state["stages"]["train_s"] = state["stages"].get("train_s", 0.0) + time.perf_counter() - t0
        state["resumed_from_step"] = resumed if state.get("resumed_from_step") is None else state["resumed_from_step"]
        log = _read_json(run.dir.training_provenance(trained.path))
        state["n_params"] = log.get("n_params")
        _write_json(state_path, state)
    prov = run.dir.training_provenance(run.dir.model)
    if args.round_bf16 and not state.get("weights_rounded_to"):
        state["unrounded_model_sha256"] = sha256_file(run.dir.model)
        round_weights_bf16(run.dir.model)
        state["weights_rounded_to"] = "bfloat16"
        _write_json(state_path, state)
    t1 = time.perf_counter()
    print(f"[worker] trained: {run.dir.model}; evaluating on the test split", flush=True)
    metrics = protocol.evaluation(run, "hbeo", "3dof", progress=False)
    state["stages"]["evaluate_s"] = time.perf_counter() - t1
    ck = load_checkpoint(ckpt) if ckpt.exists() else {}
    prof = run.profile
    steps = int(ck.get("step", 0))
    state.update(status="done", profile=prof.name, dataset=run.dataset.name, steps=steps,
                 batch_size=prof.recipe.batch_size, images_seen=steps * prof.recipe.batch_size,
                 image_size=list(prof.data.image_size), train_data=prof.data.train_data,
                 provenance=_read_json(prov),
                 metrics=summary(metrics),
                 command=" ".join(["python", str(Path(sys.argv[0]).resolve().relative_to(ROOT)), *sys.argv[1:]]))
    state["stages"]["wall_s"] = state["stages"].get("train_s", 0.0) + state["stages"]["evaluate_s"]
    _write_json(state_path, state)
    return 0


def start_worker(args) -> int:
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--profile", args.profile,
           "--dataset", args.dataset, "--run", str(args.run), *([] if args.round_bf16 else ["--no-round"]),
           "--checkpoint-every", str(args.checkpoint_every)]
    if args.max_steps:
        cmd += ["--max-steps", str(args.max_steps)]
    log = open(Path(args.run) / LOG, "ab")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, start_new_session=True, cwd=ROOT,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    return proc.pid


def pack(run_dir: Path, out: Path, state: dict) -> list[Path]:
    """Copy what must come back into ``out``: at most 8 files, none over :data:`PART_BYTES`."""
    from hbeo.rundir import RunDir
    rd = RunDir(run_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    model = rd.model
    if model.exists():
        data = model.read_bytes()
        state["model_sha256"], state["model_bytes"] = hashlib.sha256(data).hexdigest(), len(data)
        packed = gzip.compress(data, compresslevel=6, mtime=0)
        parts = [packed[i:i + PART_BYTES] for i in range(0, len(packed), PART_BYTES)]
        if len(parts) > MAX_PARTS:
            raise SystemExit(f"{model}: {len(data)} bytes, {len(packed)} gzipped, need {len(parts)} parts of 15 MiB; "
                             f"at most {MAX_PARTS} fit the transfer limit beside the other files")
        for i, part in enumerate(parts):
            p = out / f"{model.name}.gz.part{i:02d}"
            p.write_bytes(part)
            written.append(p)
    _write_json(out / "lease.json", state)
    written.append(out / "lease.json")
    for src in (rd.evaluation("hbeo", "3dof"), rd.train_log(model), rd.training_provenance(model), run_dir / LOG):
        if src.exists():
            shutil.copyfile(src, out / src.name)
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
    p.add_argument("--no-round", dest="round_bf16", action="store_false",
                   help="keep the float32 weights unrounded (the paper's network then does not fit the way back)")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
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
    state = _read_json(args.run / STATE)
    t0 = time.monotonic()
    if state.get("status") != "done" and not _alive(state.get("pid")):
        if state.get("status") == "running":
            print(f"[job] the worker {state.get('pid')} is gone: restarting it from its checkpoint", flush=True)
        pid = start_worker(args)
        _write_json(args.run / STATE, {**state, "pid": pid, "status": "starting"})
        print(f"[job] worker {pid} started; log: {args.run / LOG}", flush=True)
    while True:
        state = _read_json(args.run / STATE)
        if state.get("status") in ("done", "failed") or not _alive(state.get("pid")):
            break
        if time.monotonic() - t0 > args.wait:
            break
        time.sleep(2)
    status = state.get("status")
    if status == "running" and not _alive(state.get("pid")):
        status = "failed"
    if args.out:
        files = pack(args.run, Path(args.out), state)
        print(f"[job] {status}: packed {', '.join(f.name for f in files)} into {args.out}", flush=True)
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
