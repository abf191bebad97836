"""The torch grid ray marcher (:mod:`hbeo.render.gridcast`): agreement with embree on ``grid_mesh``, and speed.

Agreement target (issue 28): against the embree renderer on ``grid_mesh`` of the same grid, same (object,
pose), 320x240, 1 m object: silhouette IoU >= 0.98 and median |depth difference| <= 3 mm over pixels both
renderers hit. Sample: ``--objects`` training grids of each ModelNet10 class (``modelnet10-vox30``, first
non-empty ones) x ``--poses`` views from the default sampler (uniform SO(3), 1.4-2.0 m), seed 0.

Speed: images/s of :meth:`GridCaster.render` in batches (64 at 80x60, 16 at 320x240) of random objects of
the sample's grids and random default-sampler poses, for ``--seconds`` each, at torch's default thread
count and at one thread; embree on ``grid_mesh`` (one mesh per call, as a rendered set does) for reference.

Usage: python benchmarks/bench_gridcast.py [--objects 3] [--poses 3] [--seconds 3] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np
import torch


def sample(objects: int):
    from hbeo import config
    with np.load(config.vox30_path()) as z:
        X, y, classes = z["X_train"], z["y_train"], [str(c) for c in z["classes"]]
    grids, names = [], []
    for c, name in enumerate(classes):
        idx = [i for i in np.flatnonzero(y == c) if X[i].any()][:objects]
        grids += [X[i].astype(bool) for i in idx]
        names += [name] * len(idx)
    return grids, names


def agreement(grids, names, poses: int) -> dict:
    from hbeo.conventions import Intrinsics
    from hbeo.render.gridcast import embree_agreement
    m = embree_agreement(grids, Intrinsics.kinect(320, 240), poses, seed=0)
    ious, classes = m["iou"], [n for n in names for _ in range(poses)]
    d = m["depth_diff"] * 1000
    worst = {c: float(min(x for x, n in zip(ious, classes) if n == c)) for c in dict.fromkeys(classes)}
    return {"images": len(ious), "iou_pooled": m["iou_pooled"], "iou_min": float(ious.min()),
            "iou_p10": float(np.percentile(ious, 10)), "iou_median": float(np.median(ious)),
            "images_below_0.98": int((ious < 0.98).sum()), "iou_min_per_class": worst,
            "depth_mm_median": float(np.median(d)), "depth_mm_p90": float(np.percentile(d, 90)),
            "depth_mm_p99": float(np.percentile(d, 99))}


def speed(grids, size, batch: int, seconds: float, threads: int | None) -> float:
    from hbeo.render.gridcast import GridCaster
    from hbeo.render.views import RenderSettings
    s = RenderSettings(image_size=size)
    caster = GridCaster(grids, s.intrinsics)
    rng = np.random.default_rng(1)
    before = torch.get_num_threads()
    if threads:
        torch.set_num_threads(threads)
    try:
        caster.render(rng.integers(0, len(grids), batch), *s.view_sampler.sample(batch, rng))   # warm-up
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            caster.render(rng.integers(0, len(grids), batch), *s.view_sampler.sample(batch, rng))
            n += batch
        return n / (time.perf_counter() - t0)
    finally:
        torch.set_num_threads(before)


def embree_speed(grids, size, views: int, seconds: float) -> float:
    from hbeo.render.renderer import Renderer, grid_mesh
    from hbeo.render.views import RenderSettings
    s = RenderSettings(image_size=size)
    meshes = [grid_mesh(g) for g in grids]
    rng = np.random.default_rng(1)
    with Renderer(s.intrinsics, "embree") as ren:
        n, t0, i = 0, time.perf_counter(), 0
        while time.perf_counter() - t0 < seconds:
            ren.render_many(meshes[i % len(meshes)], *s.view_sampler.sample(views, rng))
            n, i = n + views, i + 1
    return n / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--objects", type=int, default=3, help="grids per class (3)")
    ap.add_argument("--poses", type=int, default=3, help="views per grid (3)")
    ap.add_argument("--seconds", type=float, default=3.0, help="timing per speed figure (3 s)")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    grids, names = sample(args.objects)
    agree = agreement(grids, names, args.poses)
    print(f"agreement with embree on grid_mesh, 320x240, 1 m objects: {agree['images']} images "
          f"({len(grids)} grids x {args.poses} poses)")
    print(f"  silhouette IoU: pooled {agree['iou_pooled']:.4f}, min {agree['iou_min']:.4f}, "
          f"p10 {agree['iou_p10']:.4f}, median {agree['iou_median']:.4f}; "
          f"{agree['images_below_0.98']} images below 0.98")
    print("  lowest IoU per class: " + ", ".join(f"{c} {v:.3f}" for c, v in agree["iou_min_per_class"].items()))
    print(f"  |depth difference| over pixels both hit: median {agree['depth_mm_median']:.3f} mm, "
          f"p90 {agree['depth_mm_p90']:.3f} mm, p99 {agree['depth_mm_p99']:.3f} mm")
    rows = []
    print(f"\nspeed (images/s, {len(grids)} grids, random objects and poses; torch default "
          f"{torch.get_num_threads()} threads):")
    for size, batch in (((80, 60), 64), ((320, 240), 16)):
        row = {"size": f"{size[0]}x{size[1]}", "batch": batch,
               "torch_default_threads": speed(grids, size, batch, args.seconds, None),
               "torch_1_thread": speed(grids, size, batch, args.seconds, 1),
               "embree_grid_mesh": embree_speed(grids, size, 16, args.seconds)}
        rows.append(row)
        print(f"  {row['size']:>8s} batch {batch:3d}: gridcast {row['torch_default_threads']:7.0f} "
              f"({row['torch_1_thread']:.0f} on 1 thread); embree on grid_mesh {row['embree_grid_mesh']:7.0f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"agreement": agree, "speed": rows, "args": vars(args)}, indent=2))


if __name__ == "__main__":
    main()
