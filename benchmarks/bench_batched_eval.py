"""Batched evaluation against the per-query loop: the same queries, wall time and agreement.

    python benchmarks/bench_batched_eval.py [--model results/cpu-modelnet10-vox30/model.hbeo]
                                            [--dataset modelnet10-vox30] [--split val] [--per-class 20]
                                            [--views 3] [--chunk 64] [--out FILE]

Runs :func:`hbeo.evaluation.evaluate.evaluate_model` twice on the same paired queries: one view at a time
through the network (the default), then each chunk's views in one network call (``batched=True``,
:meth:`hbeo.evaluation.method.HBEOMethod.predict_views`). Prints (and with ``--out`` writes) the wall time of
each, their ratio, and how far the answers agree: classes, empty completions and completions (e', IoU) equal
query by query, the largest pose difference in degrees. The rendering of the views is in both times; on a
GPU it is marched chunk by chunk in both.
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default="results/cpu-modelnet10-vox30/model.hbeo")
    ap.add_argument("--dataset", default="modelnet10-vox30")
    ap.add_argument("--split", default="val")
    ap.add_argument("--per-class", type=int, default=20)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--chunk", type=int, default=64)
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    import torch
    from hbeo.evaluation.evaluate import evaluate_model
    from hbeo.model.inference import HBEO
    from hbeo.run import load_dataset
    model = HBEO.load(args.model)
    ds = load_dataset(args.dataset, model.settings.profile or "cpu")
    kw = dict(split=args.split, views=args.views, seed=0, per_class=args.per_class, chunk=args.chunk, progress=False)
    walls, res = {}, {}
    for name, batched in (("per_query", False), ("batched", True)):
        t0 = time.perf_counter()
        res[name] = evaluate_model(model, ds, batched=batched, **kw)
        walls[name] = time.perf_counter() - t0
    a, b = res["per_query"]["per_query"], res["batched"]["per_query"]
    out = {"model": args.model, "dataset": args.dataset, "split": args.split, "queries": len(a["pred"]),
           "chunk": args.chunk, "torch_threads": torch.get_num_threads(),
           "wall_s": {k: round(v, 2) for k, v in walls.items()},
           "speedup": round(walls["per_query"] / walls["batched"], 2),
           "ms_per_query": {k: round(r["runtime_ms"]["mean_per_query"], 3) for k, r in res.items()},
           "same_class": int(sum(x == y for x, y in zip(a["pred"], b["pred"]))),
           "same_empty": int(sum(x == y for x, y in zip(a["empty"], b["empty"]))),
           "same_edt": int(np.sum(np.isclose(a["edt"], b["edt"], rtol=1e-6, atol=0))),
           "same_iou": int(np.sum(np.isclose(a["iou"], b["iou"], rtol=0, atol=1e-6))),
           "max_pose_diff_deg": float(np.max(np.abs(np.subtract(a["pose_deg"], b["pose_deg"]))))}
    print(json.dumps(out, indent=1))
    if args.out:
        from hbeo.storage import atomic_text, json_text
        atomic_text(args.out, json_text(out, indent=1))
    return out


if __name__ == "__main__":
    main()
