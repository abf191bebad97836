"""BEO baseline speed (and, on the side, quality) per query.

Targets (issue "BEO baseline"), one query = one depth image, on a 2-core machine:
  * known pose <= 0.1 s;  * 1-DOF (36 yaw bins) <= 5 s;  * 3-DOF (fixed SO(3) grid) <= 60 s.

Data: the real ModelNet10 grids (``modelnet10-vox30``) when present, else the procedural
dataset; subspace ``ObjectSubspace(variance=0.6)`` and BEO densities fitted on the first
``--train`` training grids per class. Queries: upright views (elevation 10-50 degrees, 1.4-2 m) of
test objects (grids rendered through their smoothed surface), 160x120 Kinect-like depth,
rendered first (the renderer is closed before timing). Each mode prints ms/query (mean over the
queries, after one untimed call), the ratio to its target (<= 1 meets it), accuracy and
geodesic pose error (raw and modulo the class's up-axis symmetry). ``--compare-scores`` runs the
"paper" and "joint" scores side by side (known and 1-DOF: the class is searched too; the
1-DOF pose error is also reported with the true class given, as in the paper's pose experiment).

Usage: python benchmarks/bench_beo.py [--queries 20] [--queries-3dof 3] [--so3-grid N]
                                      [--modes known,1dof,3dof] [--compare-scores]
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from hbeo import config
from hbeo.data import datasets
from hbeo import conventions as C
from hbeo.baselines.beo import BEO, DEFAULT_SO3_GRID, grid_spacing, so3_grid
from hbeo.evaluation.evaluate import symmetric_pose_error
from hbeo.data.gridset import record_grid
from hbeo.render.poses import ViewSampler
from hbeo.render.renderer import Renderer, record_mesh
from hbeo.rotations import geodesic_deg
from hbeo.subspace.basis import ObjectSubspace

TARGET_S = {"known": 0.1, "1dof": 5.0, "3dof": 60.0}
K = C.Intrinsics.kinect(160, 120)


def load(n_train: int):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p = config.vox30_path()
        name = "modelnet10-vox30" if p is not None and p.is_file() else "procedural"
        ds = datasets.get_dataset(name, profile="cpu") if name == "procedural" else datasets.get_dataset(name)
    train = ds.records("train", per_class=n_train)
    G = np.stack([record_grid(r) for r in train])
    L = np.array([ds.classes.index(r.cls) for r in train])
    return name, ds, G, L


def make_views(ds, n: int, seed: int = 0):
    """n views of test objects, spread over the classes: (label, R, t, depth)."""
    test = ds.records("test")
    rng = np.random.default_rng(seed)
    pick = rng.permutation(len(test))[:n]
    vs = ViewSampler("upright")
    out = []
    with Renderer(K, backend="auto") as r:
        for i in pick:
            R, t = vs.sample(1, rng)
            out.append((ds.classes.index(test[i].cls), R[0], t[0], r.render(record_mesh(test[i], 1.0), R[0], t[0])))
    return out


def run(beo: BEO, views, pose: str, given: bool):
    beo.predict_view(views[0][3], K, views[0][1], views[0][2], pose=pose, rng=0)      # warm-up
    hit, raw, sym, ms = [], [], [], []
    for q, (label, R, t, depth) in enumerate(views):
        t0 = time.perf_counter()
        out = beo.predict_view(depth, K, R, t, pose=pose, rng=1000 + q, label_true=label if given else None)
        ms.append((time.perf_counter() - t0) * 1e3)
        hit.append(out["label"] == label)
        raw.append(float(geodesic_deg(out["rotation"], R)))
        sym.append(float(symmetric_pose_error(out["rotation"], R, C.UP_SYMMETRY.get(beo.classes_[label], 1))))
    return {"ms": float(np.mean(ms)), "acc": float(np.mean(hit)), "raw_med": float(np.median(raw)),
            "raw_mean": float(np.mean(raw)), "sym_med": float(np.median(sym)), "sym_mean": float(np.mean(sym)),
            "n": len(views), "candidates": out["n_candidates"]}


def show(mode, score, given, r):
    ratio = r["ms"] / 1e3 / TARGET_S[mode]
    cls = "class given" if given else "class searched"
    print(f"{mode:5s} {score:5s} ({cls:14s}, {r['candidates']:5d} candidates, {r['n']:3d} queries): "
          f"{r['ms']:9.1f} ms/query  ratio {ratio:5.2f}  accuracy {r['acc']:.2f}  pose error median "
          f"{r['raw_med']:5.1f} deg (mean {r['raw_mean']:5.1f}), symmetry-aware median {r['sym_med']:5.1f} "
          f"(mean {r['sym_mean']:5.1f})", flush=True)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--train", type=int, default=60, help="training grids per class")
    ap.add_argument("--queries", type=int, default=20)
    ap.add_argument("--queries-3dof", type=int, default=3)
    ap.add_argument("--so3-grid", type=int, default=DEFAULT_SO3_GRID)
    ap.add_argument("--modes", default="known,1dof,3dof")
    ap.add_argument("--compare-scores", action="store_true")
    args = ap.parse_args()
    name, ds, G, L = load(args.train)
    t0 = time.perf_counter()
    sub = ObjectSubspace(variance=0.6).fit(G, L, ds.classes, progress=False)
    t1 = time.perf_counter()
    beos = {s: BEO(sub, score=s, so3_grid=args.so3_grid).fit(G, L) for s in ("joint", "paper")}
    t2 = time.perf_counter()
    print(f"{name}: {len(G)} training grids, subspace dim {sub.dim_} (fit {t1 - t0:.1f} s), "
          f"BEO densities fit {(t2 - t1) / 2:.2f} s, voxel noise variance {beos['joint'].noise_var_:.4f}")
    views = make_views(ds, max(args.queries, args.queries_3dof))
    modes = args.modes.split(",")
    scores = ("joint", "paper") if args.compare_scores else ("joint",)
    for mode in modes:
        if mode == "3dof":
            sp = grid_spacing(so3_grid(args.so3_grid), n_probe=5000)
            print(f"3-DOF grid: {args.so3_grid} rotations (super-Fibonacci), nearest-neighbour spacing mean "
                  f"{sp['nn_mean']:.1f} / max {sp['nn_max']:.1f} deg, distance of a random rotation to the grid "
                  f"mean {sp['cover_mean']:.1f} / max {sp['cover_max']:.1f} deg")
        for score in scores:
            if mode == "3dof":
                show(mode, score, True, run(beos[score], views[:args.queries_3dof], mode, True))
                continue
            show(mode, score, False, run(beos[score], views[:args.queries], mode, False))
            if mode == "1dof":
                show(mode, score, True, run(beos[score], views[:args.queries], mode, True))


if __name__ == "__main__":
    main()
