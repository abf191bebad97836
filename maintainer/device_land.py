"""Land what a lease on a GPU machine brought back: check it, put it in its run folder, score its model again on
this CPU and write the run's REPRODUCTION.md.

    python maintainer/device_land.py FROM [--run DIR] [--per-class N] [--no-rescore] [--evaluate-here]

``FROM`` is the folder the device tool copied ``$OUT`` into (its ``files_at``): what ``maintainer/device_job.py``
packed (``lease.json``, ``eval_hbeo_3dof.json``, ``train_log.csv``, ``provenance.json``, ``job.log`` and
``model.hbeo.gz.part*``). Nothing lands unless every check passes; a failing one exits 1 naming the file and the
problem:

- ``lease.json`` says the job finished (``status`` done) on the test split;
- the model's parts join and gunzip to the SHA-256 and size ``lease.json`` gives, and the file loads as a model
  (:meth:`hbeo.model.inference.HBEO.load`: weights only, nothing unpickled) of the lease's profile;
- ``eval_hbeo_3dof.json`` scored that very file (its request's ``model_sha256``) on every test query.

``--evaluate-here``: a job whose last call ended before its evaluation came back (the machine then gone) lands
when ``lease.json`` says the worker had recorded its model final (``model_final``) and the model's parts check as
above; the model is then evaluated on the whole test split on this CPU, ``lease.json`` says so
(``evaluated_here``), and there is no GPU scoring to compare with (no ``rescore_cpu.json``).

Then, into the run folder (default ``results/<profile>-<dataset>``; files written to a temporary name, then
renamed): ``model.hbeo``, ``eval_hbeo_3dof.json`` (the GPU's scoring), ``lease.json``, ``job.log``,
``first_minute.json`` (the benchmark's figures, from ``lease.json``), the training log and provenance beside the
model (:class:`hbeo.rundir.RunDir`'s places), ``eval_hbeo_3dof_cpu.json`` (the CPU's answers, which
``tests/test_reference_run.py`` checks the model against), ``rescore_cpu.json`` and ``REPRODUCTION.md``.

``rescore_cpu.json``: the model evaluated again on this CPU, on the same paired views of the first ``--per-class``
test objects of each class (20; ``0``: every one), compared with the GPU's scoring query by query (:func:`agreement`:
the queries whose class differs, the largest pose, IoU and EDT differences). The GPU's convolutions may use TF32,
so small differences are expected and stated, not hidden. ``REPRODUCTION.md`` (:func:`reproduction_md`): what ran
(device, command, wall time per stage, image passes against the profile's plan), the headline figures with
their 95 % intervals beside the reference CPU run's and the paper's, and the agreement on this CPU.
"""
from __future__ import annotations

import argparse
import gzip
import hashlib
import json
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

RESCORE = "rescore_cpu.json"
CPU_EVAL = "eval_hbeo_3dof_cpu.json"     #: the CPU's answers (tests/test_reference_run.py scores the model again)
FIRST_MINUTE = "first_minute.json"
REFERENCE = "cpu-modelnet10-vox30"       #: the CPU reference run the REPRODUCTION.md sets the lease beside
#: The headline statistics (hbeo.evaluation.paired's names), in the order REPRODUCTION.md shows them.
HEADLINE = ("class_accuracy", "accuracy", "within_30", "pose_median", "iou_mean", "edt_mean", "edt_median")


class LandError(Exception):
    """A file that came back is missing or wrong: the message names it and the problem."""


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise LandError(f"{path}: missing") from None
    except (OSError, ValueError) as err:
        raise LandError(f"{path}: not readable JSON ({err})") from None


def joined_model(src: Path, lease: dict) -> bytes:
    """The model file from its gzipped parts in ``src``, checked against ``lease.json``'s size and SHA-256."""
    parts = sorted(src.glob("model.hbeo.gz.part*"))
    if not parts:
        raise LandError(f"{src}: no model.hbeo.gz.part* files (the job packs the model only once it has trained)")
    try:
        data = gzip.decompress(b"".join(p.read_bytes() for p in parts))
    except (OSError, EOFError) as err:
        raise LandError(f"{src}/model.hbeo.gz.part*: {len(parts)} parts do not gunzip ({err}); a part missing?") from None
    sha = hashlib.sha256(data).hexdigest()
    if sha != lease.get("model_sha256") or len(data) != lease.get("model_bytes"):
        raise LandError(f"{src}/model.hbeo.gz.part*: joined, {len(data)} bytes with SHA-256 {sha[:16]}…; lease.json "
                        f"says {lease.get('model_bytes')} bytes, {str(lease.get('model_sha256'))[:16]}…")
    return data


def check(src: Path, evaluate_here: bool = False) -> dict:
    """Every check of the module docstring; returns ``{"lease", "evaluation", "model_bytes"}``. With
    ``evaluate_here``, a job that did not finish lands without its evaluation (``evaluation`` None) when the worker
    had recorded its model final (``model_final``: trained, and rounded where the job rounds) and the model came
    back whole."""
    src = Path(src)
    if not src.is_dir():
        raise LandError(f"{src}: not a folder")
    lease = _read_json(src / "lease.json")
    unfinished = lease.get("status") != "done"
    if unfinished and not (evaluate_here and lease.get("model_final")):
        raise LandError(f"{src / 'lease.json'}: status {lease.get('status')!r}, not 'done' (the job had not finished "
                        "when the files were packed: call the device job again on the warm machine"
                        + ("; its model was not final either" if evaluate_here else
                           "; or, once the machine is gone, --evaluate-here if lease.json says model_final") + ")")
    if lease.get("split", "test") != "test":
        raise LandError(f"{src / 'lease.json'}: evaluated on the {lease['split']} split; only a test-split job lands "
                        "as a run (a validation job's metrics stay with its choice)")
    data = joined_model(src, lease)
    if unfinished:
        return {"lease": lease, "evaluation": None, "model_bytes": data}
    ev = _read_json(src / "eval_hbeo_3dof.json")
    if ev.get("request", {}).get("model_sha256") != lease["model_sha256"][:16]:
        raise LandError(f"{src / 'eval_hbeo_3dof.json'}: scored the model {ev.get('request', {}).get('model_sha256')}, "
                        f"not the one that came back ({lease['model_sha256'][:16]})")
    q = ev.get("per_query") or {}
    if not q.get("pred") or len(q["pred"]) != ev.get("n_queries"):
        raise LandError(f"{src / 'eval_hbeo_3dof.json'}: no per-query answers for its {ev.get('n_queries')} queries")
    return {"lease": lease, "evaluation": ev, "model_bytes": data}


def agreement(gpu: dict, cpu: dict) -> dict:
    """The CPU's answers against the GPU's on the queries both scored (keyed by class, object and view): how many,
    how many predicted another class, and the largest absolute pose (degrees) and IoU differences and the largest
    relative EDT difference."""
    import numpy as np
    g, c = gpu["per_query"], cpu["per_query"]
    index = {k: i for i, k in enumerate(zip(g["class"], g["object"], g["view"]))}
    keys = list(zip(c["class"], c["object"], c["view"]))
    missing = [k for k in keys if k not in index]
    if missing:
        raise LandError(f"the GPU's evaluation lacks {len(missing)} of the CPU's queries (e.g. {missing[0]}): "
                        "not the same paired views")
    at = [index[k] for k in keys]
    col = lambda q, name, rows=None: np.asarray(q[name] if rows is None else [q[name][i] for i in rows], np.float64)
    pred_g = [g["pred"][i] for i in at]
    edt_g, edt_c = col(g, "edt", at), col(c, "edt")
    return {"n_queries": len(keys), "n_objects": len({k[:2] for k in keys}),
            "class_differs": int(sum(a != b for a, b in zip(pred_g, c["pred"]))),
            "pose_max_abs_diff_deg": float(np.max(np.abs(col(g, "pose_deg", at) - col(c, "pose_deg")))),
            "iou_max_abs_diff": float(np.max(np.abs(col(g, "iou", at) - col(c, "iou")))),
            "edt_max_rel_diff": float(np.max(np.abs(edt_g - edt_c) / np.maximum(np.abs(edt_g), 1e-9)))}


def rescore(run_dir: Path, lease: dict, gpu_eval: dict, per_class: int | None) -> dict:
    """The landed model scored again on this CPU on the GPU evaluation's paired views (the first ``per_class``
    test objects of each class, or all): (:func:`agreement` with the GPU's answers, the CPU's metrics)."""
    from hbeo.evaluation.evaluate import evaluate_model
    from hbeo.evaluation.protocol import eval_plan
    from hbeo.run import Run
    import torch
    run = Run.open(lease["profile"], lease["dataset"], run_dir)
    model = run.model(progress=False)
    plan_per_class, views = eval_plan(run.profile, "hbeo", "3dof")
    req = gpu_eval["request"]
    if (req["views"], req["per_class"]) != (views, plan_per_class):
        raise LandError(f"eval_hbeo_3dof.json: {req['views']} views of {req['per_class']} objects a class; the "
                        f"{run.profile.name} profile's plan is {views} of {plan_per_class}")
    t0 = time.perf_counter()
    cpu = evaluate_model(model, run.dataset, split="test", views=views, seed=req["seed"], per_class=per_class or None,
                         progress=True, batched=True)
    cpu["request"] = {**gpu_eval["request"], "per_class": per_class or None, "device": "cpu"}
    out = {"per_class": per_class or None, "device": f"cpu: {torch.get_num_threads()} threads "
                                                       f"(torch {torch.__version__})",
           "wall_s": round(time.perf_counter() - t0, 1), "model_sha256": lease["model_sha256"],
           **agreement(gpu_eval, cpu),
           "cpu_class_mean_accuracy": cpu.get("class_mean_accuracy"), "cpu_accuracy": cpu.get("accuracy")}
    return out, cpu


def reproduction_md(run_dir: Path, lease: dict, gpu_eval: dict, rescored: dict | None) -> str:
    """The lease run's REPRODUCTION.md (Markdown), every figure read from the files beside it."""
    import pandas as pd
    from hbeo import config
    from hbeo.evaluation import paired
    prof = config.get_profile(lease["profile"])
    st = lease.get("stages", {})
    b = lease.get("budget") or {}
    cpu_eval = lease.get("evaluated_here")
    lines = [f"# `{run_dir.name}`: HBEO trained "
             f"{'on one lent GPU, evaluated here' if cpu_eval else 'and evaluated on one lent GPU'}",
             "",
             "Generated by `python maintainer/device_land.py` from the files the lease brought back (beside this "
             "file); nothing typed by hand.", "",
             "## What ran", "",
             f"- Device: {lease.get('device')}.",
             f"- Command (the worker's): `{lease.get('command')}`.",
             "- Code: " + (f"commit `{lease['source']['commit'][:10]}`"
                           + (", with uncommitted changes" if lease["source"].get("dirty") else ", clean")
                           if (lease.get("source") or {}).get("commit") else "commit not recorded") + ".",
             f"- Profile `{prof.name}`: {lease['image_size'][0]}×{lease['image_size'][1]} images, "
             f"{lease.get('train_data')} data, batch {lease['batch_size']}"
             + (f", peak learning rate {lease['lr']:g}" if lease.get("lr") else "")
             + (f", warm-up {lease['warmup_steps']:,} steps" if lease.get("warmup_steps") else "") + "; "
             f"{lease['steps']:,} steps = {lease['images_seen']:,} image passes.",
             f"- Wall time: training {st.get('train_s', 0):.0f} s, "
             + (f"evaluation {st.get('evaluate_s', 0):.0f} s" if not cpu_eval else "no evaluation came back")
             + (f"; the budget of {b['seconds']:.0f} s chose {b['max_steps']:,} steps from {b['calibration_steps']} "
                f"timed ones ({b['calibration_images_per_s']:,.0f} images/s)" if b else "") + ".",
             f"- Model: SHA-256 `{lease['model_sha256'][:16]}…`, {lease['model_bytes']:,} bytes"
             + (f" (weights rounded to {lease['weights_rounded_to']} values; unrounded `"
                f"{lease['unrounded_model_sha256'][:16]}…`)" if lease.get("weights_rounded_to") else "") + "."]
    if cpu_eval:
        lines += [f"- Evaluation: on {cpu_eval}: the model came back final (`model_final`), its evaluation on the "
                  "GPU did not; the same paired test views, batched as the job's."]
    fm = lease.get("first_minute")
    if fm:
        lines += [f"- First minute (`{FIRST_MINUTE}`): {fm['seconds']:.0f} s (limit {fm['limit_s']:.0f} s, exit "
                  f"{fm['exit']}), stages {', '.join(fm['report'].get('stages_done', []))}; marcher "
                  f"`{fm['gridcast']}`: {fm['reason']}."]
        if fm.get("batch"):
            chosen = fm["batch"]["batch_size"] or "the profile's"
            lines += [f"- Batch by the first minute's rule: {chosen}: {fm['batch']['reason']}."]
    lines += ["", "## Headline on the test split", "",
              f"n = test objects / queries; 95 % intervals over test objects. The reference run is the `cpu` profile "
              f"on 2 CPU cores (`results/{REFERENCE}/`).", ""]
    from hbeo.report.readme import _estimate, _paper_class_mean, estimates_of
    here = estimates_of(gpu_eval, HEADLINE).set_index("statistic")
    ref_path = config.REPO_ROOT / "results" / REFERENCE / "eval_hbeo_3dof.json"
    ref = estimates_of(json.loads(ref_path.read_text()), HEADLINE).set_index("statistic") if ref_path.exists() else None
    rep = pd.read_csv(config.REPO_ROOT / "paper" / "reported" / "table1_classification.csv")
    total = rep[(rep["setting"] == "unknown_pose_3dof") & (rep["method"] == "HBEO")].iloc[0]["total"]
    paper = {"class_accuracy": _paper_class_mean(rep, "unknown_pose_3dof", "HBEO"), "accuracy": f"{total:.1f} %"}
    lines += ["| measure | n | this run | reference `cpu` run | paper |", "| --- | --- | --- | --- | --- |"]
    for stat in HEADLINE:
        r = here.loc[stat]
        lines.append(f"| {paired.NAMES[stat]} | {int(r['n_objects'])} / {int(r['n_queries'])} | "
                     f"{_estimate(r.to_dict() | {'statistic': stat})} | "
                     f"{_estimate(ref.loc[stat].to_dict() | {'statistic': stat}) if ref is not None else '–'} | "
                     f"{paper.get(stat, '–')} |")
    lines += ["", "*paper*: its Table I HBEO row (3-DOF), as a class mean and as its total; –: not given."]
    if rescored:
        lines += ["", "## The same model on this CPU", "",
                  f"`{RESCORE}`: {rescored['n_queries']} queries ({rescored['n_objects']} objects, the first "
                  f"{rescored['per_class'] or 'all'} of each class) scored again on {rescored['device']} in "
                  f"{rescored['wall_s']:.0f} s: {rescored['class_differs']} predict another class; the largest "
                  f"differences are {rescored['pose_max_abs_diff_deg']:.3g}° of pose error, "
                  f"{rescored['iou_max_abs_diff']:.3g} of IoU and {100 * rescored['edt_max_rel_diff']:.3g} % of EDT "
                  + ("(the GPU's float32 convolutions may run in TF32)." if str(lease.get("device", "")).startswith("cuda")
                     else "(the job itself ran on a CPU).")]
    return "\n".join(lines) + "\n"


def evaluate_here(run_dir: Path, lease: dict) -> dict:
    """The landed model's paired HBEO evaluation on the whole test split, on this CPU (the run's
    ``eval_hbeo_3dof.json``, written by :func:`hbeo.evaluation.protocol.evaluation`, batched as the job's)."""
    from hbeo.evaluation import protocol
    from hbeo.run import Run
    run = Run.open(lease["profile"], lease["dataset"], run_dir)
    return protocol.evaluation(run, "hbeo", "3dof", progress=True, batched=True)


def land(src: Path, run_dir: Path | None = None, per_class: int | None = 20, rescore_it: bool = True,
         evaluate: bool = False) -> Path:
    """Check ``src`` (:func:`check`), write the run folder, score again on this CPU; returns the run folder.
    ``evaluate`` (``--evaluate-here``): a job whose model came back final but not its evaluation is evaluated on
    this CPU instead (:func:`evaluate_here`; then there is nothing to score again)."""
    from hbeo.rundir import RunDir
    from hbeo.storage import atomic_bytes, atomic_text, json_text
    got = check(src, evaluate)
    lease, ev = got["lease"], got["evaluation"]
    rd = RunDir(run_dir or RunDir.for_run(lease["profile"], lease["dataset"]).path).create()
    atomic_bytes(rd.model, got["model_bytes"])
    brought = [("job.log", rd.path / "job.log"), ("train_log.csv", rd.train_log(rd.model)),
               ("provenance.json", rd.training_provenance(rd.model))]
    if ev is not None:               # an unfinished job's evaluation file, if any, is not the checked one
        brought.append(("eval_hbeo_3dof.json", rd.evaluation("hbeo", "3dof")))
    for name, dest in brought:
        if (Path(src) / name).exists():
            atomic_bytes(dest, (Path(src) / name).read_bytes())
    if ev is None:
        rd.evaluation("hbeo", "3dof").unlink(missing_ok=True)
        lease = {**lease, "evaluated_here": f"cpu: {os.cpu_count()} cores (device_land.py --evaluate-here; the "
                                            f"lease's status was {lease.get('status')!r})"}
        ev = evaluate_here(rd.path, lease)
        rescore_it = False
    atomic_text(rd.path / "lease.json", json_text(lease, indent=1))
    if lease.get("first_minute"):
        atomic_text(rd.path / FIRST_MINUTE, json_text(lease["first_minute"]["report"], indent=1))
    rescored = None
    if rescore_it:
        rescored, cpu = rescore(rd.path, lease, ev, per_class)
        atomic_text(rd.path / CPU_EVAL, json_text(cpu, indent=1))
        atomic_text(rd.path / RESCORE, json_text(rescored, indent=1))
    atomic_text(rd.reproduction, reproduction_md(rd.path, lease, ev, rescored))
    return rd.path


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("src", metavar="FROM", help="the folder the device tool copied $OUT into")
    p.add_argument("--run", help="run folder (default: results/<profile>-<dataset> of lease.json)")
    p.add_argument("--per-class", type=int, default=20, metavar="N",
                   help="test objects a class scored again on this CPU (20; 0: every one)")
    p.add_argument("--no-rescore", dest="rescore", action="store_false", help="skip the CPU scoring")
    p.add_argument("--evaluate-here", action="store_true",
                   help="a job that did not finish (the machine gone before its evaluation came back) lands when its "
                        "model came back final (lease.json's model_final): evaluated on this CPU, the whole test split")
    args = p.parse_args(argv)
    if args.per_class < 0:
        p.error(f"--per-class must be >= 0, got {args.per_class}")
    try:
        out = land(Path(args.src), Path(args.run) if args.run else None, args.per_class, args.rescore,
                   args.evaluate_here)
    except LandError as err:
        print(f"device_land: {err}", file=sys.stderr)
        return 1
    print(f"landed into {out}: {', '.join(sorted(p.name for p in out.iterdir()))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
