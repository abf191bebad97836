"""Subspace speed on the real ModelNet10 grids (../shared/modelnet10_vox30).

Targets (issue "object subspace"), on a 2-core machine:
  * fit VBPCA for all ten classes and the shared basis on the full training split in <= 60 s;
  * known-mask partial projection (least squares) <= 20 ms per query at 344 dimensions, batched.

Prints the fit time, then ms/query for masks hiding a random half of the voxels (each
independently: the hardest case, every known voxel touches A) and hiding a spatial half
(y >= 15), at the 60 %-variance basis and at the paper's 344 dimensions.

Usage: python benchmarks/bench_subspace.py [--queries 64]
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from hbeo.subspace import completion
from hbeo.data import datasets
from hbeo.data.gridset import build_gridset
from hbeo.subspace.basis import ObjectSubspace


def per_query_ms(sub, grids, known, method="lstsq"):
    sub.partial_project(grids[:2], known[:2], method=method)   # warm-up
    t = time.perf_counter()
    sub.partial_project(grids, known, method=method)
    return (time.perf_counter() - t) / len(grids) * 1e3


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--queries", type=int, default=64)
    args = ap.parse_args()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = datasets.get_dataset("modelnet10-vox30")
    tr = build_gridset(ds, ds.records("train"), "train", progress=False)
    te = build_gridset(ds, ds.records("test"), "test", progress=False)
    q = te.grids[: args.queries]
    rand = completion.random_mask(q.shape, 0.5, seed=0)
    half = np.zeros_like(q)
    half[:, :, :15] = True
    for name, kw in (("variance=0.6", {"variance": 0.6}), ("shared_dim=344", {"shared_dim": 344})):
        t = time.perf_counter()
        sub = ObjectSubspace(**kw).fit(tr.grids, tr.labels, tr.classes, progress=False)
        fit = time.perf_counter() - t
        print(f"{name}: fit {len(tr)} grids, 10 classes in {fit:.1f} s (target <= 60 s; ratio {fit / 60:.2f}); "
              f"dim {sub.dim_}")
        for mname, mask in (("random half", rand), ("spatial half", half)):
            ms = per_query_ms(sub, q, mask)
            print(f"   partial projection lstsq, {mname:12s} known: {ms:6.1f} ms/query "
                  f"(target <= 20 ms; ratio {ms / 20:.2f})")
        ms = per_query_ms(sub, q, rand, method="lasso")
        print(f"   partial projection lasso, random half known: {ms:6.1f} ms/query")


if __name__ == "__main__":
    main()
