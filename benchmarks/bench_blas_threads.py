"""Per-query time of HBEO's one pass with numpy's BLAS on one thread (as ``HBEO.predict`` now runs) and on
its default threads (as it ran before), on the same views, in one process, rounds alternating.

    python benchmarks/bench_blas_threads.py [--model results/cpu-modelnet10-vox30/model.hbeo]
        [--dataset modelnet10-vox30] [--split test] [--per-class 20] [--views 3] [--seed 0] [--repeat 2]
        [--out benchmarks/logs/blas_threads.json]

``HBEO.predict`` runs the network (torch's OpenMP threads) and small BLAS products (numpy/scipy's OpenBLAS)
in turn; a BLAS product on several threads leaves its threads spinning after it returns, and on a machine
with few cores they slow the next network pass down. Mode ``default`` calls the inference without the limit
(``HBEO._predict``, the code before the fix), mode ``one`` calls ``HBEO.predict`` (under
:func:`hbeo.limits.one_blas_thread`). The views are the evaluation protocol's (paired: the same for both
modes, rendered once, first). Prints, per round and mode, the mean / median / 95th / 99th percentile /
maximum of the model's own per-query time (``timing_ms["total"]``) and of its network stage, the number of
queries over 20 ms, and the ratio of the means (one / default); answers must be identical between the modes
(checked: class, rotation and completed grid of every query). Run it with nothing else on the machine.
``--out`` writes the figures as JSON (temporary name, then rename).
"""
from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402
import torch  # noqa: E402

from hbeo.storage import atomic_text  # noqa: E402


def _stats(ms) -> dict:
    a = np.asarray(ms, np.float64)
    p95, p99 = np.percentile(a, [95, 99])
    return {"mean": float(a.mean()), "median": float(np.median(a)), "p95": float(p95), "p99": float(p99),
            "max": float(a.max()), "over_20ms": int((a > 20).sum())}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, default=ROOT / "results/cpu-modelnet10-vox30/model.hbeo")
    ap.add_argument("--dataset", default="modelnet10-vox30")
    ap.add_argument("--split", default="test")
    ap.add_argument("--per-class", type=int, default=20)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    if not args.model.is_file():
        ap.error(f"{args.model}: no such model file")
    from tqdm import tqdm
    from threadpoolctl import threadpool_info
    from hbeo.evaluation.evaluate import EvaluationSetup, rendered_chunks, split_records
    from hbeo.model.inference import HBEO
    from hbeo.render.views import RenderSettings
    from hbeo.run import load_dataset

    model = HBEO.load(args.model)
    setup = EvaluationSetup.of_model(model, class_means=False)
    ds = load_dataset(args.dataset, model.settings.profile or "cpu")
    rs = RenderSettings.from_dict({**setup.render, "views_per_object": args.views, "seed": args.seed, "noise": False})
    records = split_records(ds, args.split, args.per_class, setup.profile)
    bar = tqdm(total=len(records), desc="render views")
    depths = [v["depth"][j].astype(np.float32) for batch in rendered_chunks(rs, records, args.split, 64, [], bar)
              for _, _, v, _ in batch for j in range(args.views)]
    bar.close()
    depths = [d for d in depths if (d > 0).any()]
    K = model.intrinsics

    def run(mode: str):
        total, net, answers = [], [], []
        with torch.inference_mode():
            for d in tqdm(depths, desc=f"mode {mode}", leave=False):
                p = model.predict(d, K) if mode == "one" else model._predict(d, K, None, 1, time.perf_counter())
                total.append(p.timing_ms["total"])
                net.append(p.timing_ms["network"])
                answers.append((int(p.labels[0]), p.rotation[0].copy(), p.grids[0].copy()))
        return total, net, answers

    model.predict(depths[0], K)                               # first-call set-up is not a per-query cost
    rounds, ref = [], None
    for r in range(args.repeat):
        out = {}
        for mode in ("default", "one"):
            total, net, answers = run(mode)
            if ref is None:
                ref = answers
            same = all(a[0] == b[0] and np.array_equal(a[1], b[1]) and np.array_equal(a[2], b[2])
                       for a, b in zip(answers, ref))
            out[mode] = {"total_ms": _stats(total), "network_ms": _stats(net), "answers_identical": bool(same)}
        out["ratio_of_means"] = out["one"]["total_ms"]["mean"] / out["default"]["total_ms"]["mean"]
        rounds.append(out)
        for mode in ("default", "one"):
            t, n = out[mode]["total_ms"], out[mode]["network_ms"]
            print(f"round {r} {mode:7s}: total mean {t['mean']:.2f} median {t['median']:.2f} p95 {t['p95']:.1f} "
                  f"p99 {t['p99']:.1f} max {t['max']:.1f} ms, over 20 ms {t['over_20ms']}; network mean "
                  f"{n['mean']:.2f} median {n['median']:.2f} ms; answers identical {out[mode]['answers_identical']}")
        print(f"round {r} ratio of means (one / default): {out['ratio_of_means']:.2f}")
    if args.out:
        result = {"model": str(args.model), "dataset": args.dataset, "split": args.split,
                  "per_class": args.per_class, "views": args.views, "seed": args.seed, "n_queries": len(depths),
                  "torch_threads": torch.get_num_threads(), "machine": platform.platform(),
                  "libraries": [(i["internal_api"], i["prefix"], i["num_threads"]) for i in threadpool_info()],
                  "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "rounds": rounds}
        atomic_text(args.out, json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
