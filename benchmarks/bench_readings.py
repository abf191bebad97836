"""HBEO under each reading of the view protocol (issue 29 item 3): the same model, the same test objects
and per-view random streams, views drawn by each sampler of :data:`hbeo.render.poses.SAMPLERS`.

    python benchmarks/bench_readings.py [--run results/cpu-modelnet10-vox30] [--profile cpu]
                                        [--dataset modelnet10-vox30] [--samplers so3,floor,upright,sphere]
                                        [--work /tmp/hbeo-readings] [--json benchmarks/logs/readings_hbeo.json]

The run's ``model.hbeo`` is copied into ``--work`` (the committed run folder gets no new files: its
evaluations are those ``make reproduce`` wrote) and scored there by
:func:`hbeo.evaluation.protocol.evaluation` with the profile's evaluation plan (the whole test split,
its views per object) under each sampler; a finished evaluation in ``--work`` is read, not recomputed.
Intervals: 95 % bootstrap over test objects, resampled within class and shared by every reading
(:class:`hbeo.evaluation.paired.PairedBootstrap`); a reading's difference from ``so3`` is paired by
object and view index (the images differ between readings: only the object and its random stream are
shared). HBEO only: the baselines under each reading are not measured yet.
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: (paired.STATISTICS name, label, scale, decimals)
STATS = (("accuracy", "accuracy %", 100, 1), ("class_accuracy", "class-mean accuracy %", 100, 1),
         ("within_30", "pose within 30 deg %", 100, 1), ("pose_median", "pose median deg", 1, 1),
         ("iou_mean", "completion IoU", 1, 3))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", default="results/cpu-modelnet10-vox30")
    p.add_argument("--profile", default="cpu")
    p.add_argument("--dataset", default="modelnet10-vox30")
    p.add_argument("--samplers", default="so3,floor,upright,sphere")
    p.add_argument("--work", default="/tmp/hbeo-readings")
    p.add_argument("--json", default=str(ROOT / "benchmarks/logs/readings_hbeo.json"))
    args = p.parse_args(argv)
    from hbeo.evaluation import protocol
    from hbeo.evaluation.paired import PairedBootstrap
    from hbeo.run import Run
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    shutil.copy2(Path(args.run) / "model.hbeo", work / "model.hbeo")
    run = Run.open(args.profile, args.dataset, work)
    samplers = args.samplers.split(",")
    evals, seconds = {}, {}
    for s in samplers:
        t0 = time.perf_counter()
        evals[s] = dict(protocol.evaluation(run, "hbeo", "3dof", sampler=s, progress=False))
        seconds[s] = round(time.perf_counter() - t0, 1)
        evals[s]["method"] = f"hbeo@{s}"               # one key per reading in the shared bootstrap
    boot = PairedBootstrap(list(evals.values()))
    rows = {}
    for s in samplers:
        key = (f"hbeo@{s}", "3dof")
        row = {"n_queries": evals[s]["n_queries"], "n_objects": evals[s]["n_objects"], "seconds": seconds[s]}
        for stat, _, scale, _ in STATS:
            e = boot.estimate(key, stat)
            row[stat] = [scale * e.value, scale * e.low, scale * e.high]
            if s != "so3" and "so3" in evals:
                d = boot.contrast(key, ("hbeo@so3", "3dof"), stat)
                row[stat + "_minus_so3"] = [scale * d.value, scale * d.low, scale * d.high]
        per = evals[s]["per_class"]
        row["lowest_class"] = min(((c, v["accuracy"]) for c, v in per.items()), key=lambda cv: cv[1])
        rows[s] = row
    print(f"HBEO ({args.run}/model.hbeo) on the {args.dataset} test split under each reading, 95 % CI over objects")
    for s, row in rows.items():
        print(f"{s:8s} n={row['n_queries']} ({row['n_objects']} objects)  " + "  ".join(
            f"{label} {row[stat][0]:.{k}f} [{row[stat][1]:.{k}f}, {row[stat][2]:.{k}f}]" for stat, label, _, k in STATS))
        for stat, label, _, k in STATS:
            if stat + "_minus_so3" in row:
                d = row[stat + "_minus_so3"]
                print(f"{'':8s}   {label} - so3: {d[0]:+.{k}f} [{d[1]:+.{k}f}, {d[2]:+.{k}f}]")
    out = {"model": f"{args.run}/model.hbeo", "dataset": args.dataset, "profile": args.profile,
           "views_per_object": evals[samplers[0]]["views"], "seed": evals[samplers[0]]["seed"], "readings": rows}
    Path(args.json).write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
