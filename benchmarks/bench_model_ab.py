"""Per-query time of two (or more) model files measured back to back on the same machine (issue 29).

    python benchmarks/bench_model_ab.py MODEL_A MODEL_B [...] [--dataset modelnet10-vox30] [--split test]
                                        [--views 3] [--seed 0] [--repeat 2] [--out benchmarks/logs/model_ab.json]

Per-query times of a 2-core VM drift from day to day, so a model's ms/query measured on one day cannot be set
beside another model's measured on another. This runs ``python -m hbeo evaluate`` (one network pass, the same
paired views) on each model in turn, ``--repeat`` rounds of A, B, ..., and prints each run's mean and median
ms/query, each model's class-mean accuracy (which must not change between rounds: the evaluation is
deterministic), and every model's median time as a ratio to the first model's, round by round. Run it with
nothing else on the machine. ``--out`` writes the figures as JSON (temporary name, then rename).
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from hbeo.storage import atomic_text  # noqa: E402


def evaluate_once(model: Path, args, out: Path) -> dict:
    cmd = [sys.executable, "-m", "hbeo", "evaluate", "--model", str(model), "--dataset", args.dataset,
           "--split", args.split, "--views", str(args.views), "--seed", str(args.seed), "--quiet",
           "--out", str(out)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True)
    if done.returncode != 0:
        sys.exit(f"bench_model_ab: evaluating {model} failed (exit {done.returncode}): "
                 f"{done.stderr.strip().splitlines()[-1] if done.stderr.strip() else 'no message'}")
    m = json.loads(out.read_text())
    return {"model": str(model), "mean_ms": m["runtime_ms"]["mean_per_query"],
            "median_ms": m["runtime_ms"]["median_per_query"], "class_mean_accuracy": m["class_mean_accuracy"],
            "accuracy": m["accuracy"], "n_queries": m["n_queries"]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+", type=Path)
    ap.add_argument("--dataset", default="modelnet10-vox30")
    ap.add_argument("--split", default="test")
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    if len(args.models) < 2:
        ap.error("give at least two model files to compare")
    for m in args.models:
        if not m.is_file():
            ap.error(f"{m}: no such model file")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.repeat):
            for i, model in enumerate(args.models):
                row = evaluate_once(model, args, Path(tmp) / f"m{i}.json")
                row["round"] = r
                runs.append(row)
                print(f"round {r}  {model}: mean {row['mean_ms']:.1f} ms, median {row['median_ms']:.1f} ms, "
                      f"class mean {100 * row['class_mean_accuracy']:.1f} % (n = {row['n_queries']})", flush=True)
    ratios = []
    for r in range(args.repeat):
        base = next(x for x in runs if x["round"] == r and x["model"] == str(args.models[0]))
        for x in runs:
            if x["round"] == r and x["model"] != base["model"]:
                ratios.append({"round": r, "model": x["model"], "median_ratio": x["median_ms"] / base["median_ms"],
                               "mean_ratio": x["mean_ms"] / base["mean_ms"]})
                print(f"round {r}  {x['model']} / {base['model']}: median {ratios[-1]['median_ratio']:.2f}x, "
                      f"mean {ratios[-1]['mean_ratio']:.2f}x")
    for m in args.models:
        cm = {x["class_mean_accuracy"] for x in runs if x["model"] == str(m)}
        if len(cm) != 1:
            print(f"warning: {m}: class-mean accuracy differs between rounds {sorted(cm)}: not deterministic")
    if args.out:
        atomic_text(args.out, json.dumps({"command": " ".join(sys.argv), "runs": runs, "ratios": ratios},
                                         indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
