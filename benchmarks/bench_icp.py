"""ICP pose baseline speed (and, for orientation, accuracy) on rendered procedural views.

Target (issue "ICP baseline"): < 0.5 s per query with ~24-48 initial rotations, one process,
on this 2-core machine.

Fits the class means on the procedural train split of ``--profile`` (default ci), renders
``--views`` random views (uniform over SO(3), 1.4-2.0 m, Kinect-like camera ``--size``) of test
objects of every class with embree, closes the renderer, then times ``predict_view`` per query
for 3-DOF and 1-DOF, one query per call, after one untimed warm-up call (KD-tree building).
Prints ms/query (mean, median, max) with the ratio to the target, and the raw and
symmetry-aware pose errors (degrees).

Usage: python benchmarks/bench_icp.py [--views 40] [--size 160x120] [--n-init 48] [--metric plane|point]
       [--profile ci] [--seed 0]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from hbeo import conventions as C
from hbeo.data import datasets
from hbeo.data import gridset
from hbeo.render import poses
from hbeo.render import renderer as render
from hbeo.evaluation.evaluate import symmetric_pose_error
from hbeo.baselines.icp import ICPBaseline
from hbeo.rotations import geodesic_deg

TARGET_MS = 500.0


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=40)
    ap.add_argument("--size", default="160x120", help="depth image WIDTHxHEIGHT")
    ap.add_argument("--n-init", type=int, default=48)
    ap.add_argument("--metric", default="plane", choices=("plane", "point"), help="ICP error metric")
    ap.add_argument("--profile", default="ci")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.lower().split("x"))
    K = C.Intrinsics.kinect(w, h)

    ds = datasets.get_dataset("procedural", profile=args.profile)
    train, test = datasets.select(ds, "train", args.profile), datasets.select(ds, "test", args.profile)
    t0 = time.perf_counter()
    grids = np.stack([gridset.record_grid(r) for r in train])
    labels = np.array([C.class_index(r.cls) for r in train])
    t1 = time.perf_counter()
    icp = ICPBaseline(n_init=args.n_init, metric=args.metric).fit(grids, labels, C.CLASSES)
    t2 = time.perf_counter()
    print(f"{len(train)} training grids ({t1 - t0:.1f} s to voxelize); fit {len(C.CLASSES)} class means "
          f"and surfaces in {t2 - t1:.2f} s; {icp!r}")

    rng = np.random.default_rng(args.seed)
    sampler = poses.ViewSampler(sampler="so3")
    by_class = {}
    for r in test:
        by_class.setdefault(r.cls, []).append(r)
    groups = list(by_class.values())                                     # round robin over classes
    order = [groups[i % len(groups)][(i // len(groups)) % len(groups[i % len(groups)])] for i in range(args.views)]
    views = []
    with render.Renderer(K, backend="embree") as rend:     # closed before timing (its threads)
        for rec in order:
            R, t = sampler.sample(1, rng)
            d = rend.render_many(render.record_mesh(rec), R, t)[0]
            if (d > 0).sum() >= 3:
                views.append((rec, R[0], t[0], d))
    print(f"{len(views)} views of {len({v[0].id for v in views})} test objects, {w}x{h}, "
          f"{np.mean([(v[3] > 0).sum() for v in views]):.0f} object pixels on average")

    for pose in ("3dof", "1dof"):
        rec, R, t, d = views[0]
        icp.predict_view(d, K, R, t, pose=pose, label_true=rec.cls)          # warm-up
        ms, raw, sym = [], [], []
        for rec, R, t, d in views:
            s = time.perf_counter()
            out = icp.predict_view(d, K, R, t, pose=pose, label_true=rec.cls)
            ms.append((time.perf_counter() - s) * 1e3)
            raw.append(geodesic_deg(out["rotation"], R))
            sym.append(symmetric_pose_error(out["rotation"], R, C.UP_SYMMETRY.get(rec.cls, 1)))
        ms, raw, sym = np.array(ms), np.array(raw), np.array(sym)
        n = icp.n_init if pose == "3dof" else icp.n_yaw
        print(f"{pose} ({n} initializations): {ms.mean():6.1f} ms/query mean, {np.median(ms):6.1f} median, "
              f"{ms.max():6.1f} max (target < {TARGET_MS:.0f} ms; ratio {ms.mean() / TARGET_MS:.2f}); "
              f"pose error raw median {np.median(raw):5.1f} mean {raw.mean():5.1f}, symmetry-aware median "
              f"{np.median(sym):5.1f}, within 30 deg {np.mean(raw < 30):.0%}")


if __name__ == "__main__":
    main()
