"""Choose the verify step's settings on validation objects: every candidate on the same queries.

Usage: python scripts/tune_verify.py --model results/cpu-modelnet10-vox30/model.hbeo
           [--dataset modelnet10-vox30] [--per-class 10] [--views 1] [--seed 0] [--rolls 1]
           [CANDIDATE ...]
A candidate is ``hbeo`` (the network alone), ``default`` (VerifyConfig()) or ``key=value,...`` over
the defaults (``python -m hbeo evaluate --verify-set`` syntax). Each row is appended to the model
folder's ``verify_sweep.csv`` (hbeo.rundir.RunDir.verify_sweep; atomically, hbeo.storage.append_csv)
and printed. Never touches the test split.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--dataset", default="modelnet10-vox30")
    ap.add_argument("--per-class", type=int, default=10)
    ap.add_argument("--views", type=int, default=1)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--rolls", type=int, default=1)
    ap.add_argument("--thresholds", default="", help="comma-separated min_agreement values derived for each candidate")
    ap.add_argument("candidates", nargs="*", default=["hbeo", "default"])
    args = ap.parse_args(argv)
    from hbeo.data import datasets
    from hbeo import config
    from hbeo.model.inference import HBEO
    from hbeo.model.verify import VerifyConfig
    from hbeo.evaluation.sweep import sweep_rows, verify_sweep
    from hbeo.rundir import RunDir
    from hbeo.storage import append_csv, sha256_file
    model = HBEO.load(args.model)
    ds = datasets.get_dataset(args.dataset, profile=config.get_profile(model.settings.get("profile", "cpu")))
    configs = {c: (None if c == "hbeo" else VerifyConfig.parse("" if c == "default" else c)) for c in args.candidates}
    res = verify_sweep(model, ds, configs, views=args.views, seed=args.seed, per_class=args.per_class, rolls=args.rolls,
                       thresholds=tuple(float(x) for x in args.thresholds.split(",") if x))
    rows = sweep_rows(res, sha256_file(args.model)[:16])
    for r in rows:
        r["model"] = Path(args.model).name
    append_csv(RunDir(Path(args.model).parent).verify_sweep, rows)
    for r in rows:
        print(f"{r['name']:48s} acc {r['accuracy']:.3f}  pose med {r['pose_median_deg']:6.1f}  "
              f"w30 {r['within_30']:.3f}  IoU {r['iou']:.3f}  {r['ms_per_query']:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
