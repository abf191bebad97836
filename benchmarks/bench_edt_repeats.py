"""EDT error e' of repeated grids: one distance field a pair against one a distinct grid, same numbers.

    python benchmarks/bench_edt_repeats.py [--objects 100] [--views 3] [--classes 10] [--threads 1]

An evaluation scores every query's completion against its object's grid, and the same queries again against
the predicted and the true class's mean shape (``completion_baseline``) and under the paper's rule
(``completion_paper``): an object's grid recurs once a view, a class's mean shape once a query of that class.
:func:`hbeo.subspace.metrics.edt_error` computes a recurring grid's distance field once. Random 30^3 grids
(8 % filled): ``--objects`` targets of ``--views`` views each, against distinct predictions and against
``--classes`` mean shapes; milliseconds a pair, both ways, and whether the figures are identical.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--objects", type=int, default=100)
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--classes", type=int, default=10)
    ap.add_argument("--threads", type=int, default=1, help="threads of edt_error (1; 0: the usable cores)")
    args = ap.parse_args(argv)
    from hbeo.subspace.metrics import distance_field, edt_error
    rng = np.random.default_rng(0)
    truth = np.repeat(rng.random((args.objects, 30, 30, 30)) < 0.08, args.views, axis=0)
    n = len(truth)
    means = rng.random((args.classes, 30, 30, 30)) < 0.1
    rows = []
    for name, pred in (("distinct predictions", rng.random((n, 30, 30, 30)) < 0.08),
                       ("class mean shapes", means[rng.integers(0, args.classes, n)])):
        t0 = time.perf_counter()
        want = np.array([np.linalg.norm(distance_field(a) - distance_field(b)) for a, b in zip(truth, pred)])
        t1 = time.perf_counter()
        got = edt_error(truth, pred, threads=args.threads or None)
        t2 = time.perf_counter()
        row = {"against": name, "pairs": n, "threads": args.threads, "one_field_a_pair_ms": (t1 - t0) / n * 1e3,
               "once_a_grid_ms": (t2 - t1) / n * 1e3, "identical": bool(np.array_equal(got, want))}
        rows.append(row)
        print(f"{name}: {n} pairs, one field a pair {row['one_field_a_pair_ms']:.2f} ms, once a grid "
              f"{row['once_a_grid_ms']:.2f} ms ({(t1 - t0) / (t2 - t1):.2f}x); identical: {row['identical']}")
    return rows


if __name__ == "__main__":
    main()
