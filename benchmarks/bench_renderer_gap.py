"""Domain gap between the renderers: one model scored on the same (object, pose) queries rendered by
embree (on ``grid_mesh``, what the model was trained on) and by the torch grid renderer
(:mod:`hbeo.render.gridcast`), so a model trained on one can be judged on the other.

    python benchmarks/bench_renderer_gap.py [--run results/cpu-modelnet10-vox30] [--split val] [--views 3]

Prints, per renderer, accuracy, class-mean accuracy, median pose error, share within 30 degrees and mean
IoU on the validation objects (never the test split: this is a check, not a result), the paired
difference per query (torch - embree) with a 95 % bootstrap interval over objects, and writes
``benchmarks/logs/renderer_gap.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def headline(m: dict) -> dict:
    per = [c["accuracy"] for c in m["per_class"].values() if c.get("n")]
    return {"n_queries": m["n_queries"], "accuracy": m["accuracy"], "class_mean_accuracy": float(np.mean(per)),
            "pose_median_deg": m["pose_error_deg"]["median"], "pose_within_30": m["pose_error_deg"]["within_30"],
            "iou": m["completion"]["iou"]}


def paired(a: dict, b: dict, key: str, seed: int = 0, n_boot: int = 2000) -> dict:
    """Mean of b - a over the queries both answered, with a bootstrap interval over objects."""
    qa, qb = a["per_query"], b["per_query"]
    ia = {(o, v): i for i, (o, v) in enumerate(zip(qa["object"], qa["view"]))}
    pairs = [(ia[(o, v)], j) for j, (o, v) in enumerate(zip(qb["object"], qb["view"])) if (o, v) in ia]
    objs = np.array([qa["object"][i] for i, _ in pairs])
    def value(q, i):
        return float(q["pred"][i] == q["class"][i]) if key == "correct" else float(q[key][i])
    d = np.array([value(qb, j) - value(qa, i) for i, j in pairs])
    uniq, inv = np.unique(objs, return_inverse=True)
    rng = np.random.default_rng(seed)
    sums, counts = np.bincount(inv, d), np.bincount(inv)
    boots = []
    for _ in range(n_boot):
        pick = rng.integers(0, len(uniq), len(uniq))
        boots.append(sums[pick].sum() / counts[pick].sum())
    lo, hi = np.percentile(boots, [2.5, 97.5])
    return {"n_pairs": len(d), "mean": float(d.mean()), "ci95": [float(lo), float(hi)]}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", default=str(ROOT / "results" / "cpu-modelnet10-vox30"))
    p.add_argument("--dataset", default="modelnet10-vox30")
    p.add_argument("--split", choices=("val", "train"), default="val")
    p.add_argument("--views", type=int, default=3)
    p.add_argument("--per-class", type=int)
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "logs" / "renderer_gap.json"))
    args = p.parse_args(argv)
    from hbeo.data.datasets import get_dataset
    from hbeo.evaluation.evaluate import EvaluationSetup, evaluate_method
    from hbeo.evaluation.method import HBEOMethod
    from hbeo.model.inference import HBEO
    from hbeo.rundir import RunDir
    model = HBEO.load(RunDir(args.run).model)
    ds = get_dataset(args.dataset, profile=model.settings.profile)
    setup = EvaluationSetup.of_model(model)
    out, evals = {"run": str(Path(args.run).resolve().relative_to(ROOT)), "split": args.split,
                  "views": args.views, "seed": 0, "image_size": setup.render.get("image_size")}, {}
    for backend in ("embree", "torch"):
        t0 = time.perf_counter()
        s = replace(setup, render={**setup.render, "backend": backend})
        evals[backend] = evaluate_method(HBEOMethod(model), ds, s, split=args.split, views=args.views, seed=0,
                                         per_class=args.per_class, progress=False)
        out[backend] = {**headline(evals[backend]), "wall_s": round(time.perf_counter() - t0, 1)}
        print(backend, json.dumps(out[backend]))
    out["torch_minus_embree"] = {k: paired(evals["embree"], evals["torch"], k) for k in ("correct", "pose_deg", "iou")}
    print("torch - embree (paired, 95 % CI over objects):", json.dumps(out["torch_minus_embree"]))
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")
    print(f"-> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
