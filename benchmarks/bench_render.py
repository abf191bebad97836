"""Depth rendering throughput: images per second per backend, one process and two.

Targets (issue "Rendering"): >= 300 img/s at 320x240 and >= 1000 img/s at 64x64 across both
cores of a 2-core machine. Mesh: the real ModelNet10 bathtub_0005 (30,734 faces) from
../shared/modelnet10_sample when present, else a procedural chair subdivided to ~20k faces.
Poses: ``ViewSampler()`` defaults (uniform SO(3), 1.4-2 m). Each process times
``Renderer.render_many`` over its share of the views, ``--batch`` views per call as when rendering
one object's views, after a warm-up (mesh upload / BVH build excluded: they are paid once per mesh and printed
as "mesh setup"); the two-process rate is all images over the slowest process's
time; each figure is the best of ``--repeat`` runs. (One call for hundreds of 320x240 views returns >100 MB: first-touch page faults then cost
more than the ray casting, and parallel processes contend for them.) Note that OpenGL on a CPU (llvmpipe) already uses several threads in one process.

Usage: python benchmarks/bench_render.py [--views 400] [--backends embree,pyrender] [--procs 2] [--batch 50] [--repeat 3]
"""
from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time

import numpy as np
import trimesh

from hbeo import config
from hbeo.data import procedural
from hbeo import conventions as C
from hbeo.data.meshio import read_mesh
from hbeo.render.poses import ViewSampler
from hbeo.render.renderer import Renderer, embree_available, gl_platform, prepare_mesh

TARGETS = {(320, 240): 300.0, (64, 64): 1000.0}


def bench_mesh() -> trimesh.Trimesh:
    sample = config.modelnet10_sample_dir()
    f = sample / "bathtub" / "train" / "bathtub_0005.off" if sample else None
    if f is not None and f.is_file():
        return read_mesh(f)
    m = procedural.generate("chair", "train", 0)
    v, fa = m.vertices, m.faces
    while len(fa) < 20000:
        v, fa = trimesh.remesh.subdivide(v, fa)
    return trimesh.Trimesh(v, fa, process=False, metadata={"name": "procedural chair, subdivided"})


def _worker(args):
    backend, size, n, seed, barrier, batch = args
    mesh = prepare_mesh(bench_mesh())
    Rs, ts = ViewSampler().sample(n, np.random.default_rng(seed))
    with Renderer(C.Intrinsics.kinect(*size), backend) as r:
        r.render_many(mesh.copy(), Rs[:8], ts[:8])           # warm-up: GL context, shaders
        t0 = time.perf_counter()
        r.render_many(mesh, Rs[:1], ts[:1])                  # per-mesh setup: BVH / GL buffers
        setup = time.perf_counter() - t0
        r.render_many(mesh, Rs[:8], ts[:8])
        if barrier is not None:
            barrier.wait()
        fill = []
        t0 = time.perf_counter()
        for k in range(0, n, batch):
            depth = r.render_many(mesh, Rs[k:k + batch], ts[k:k + batch])
            fill.append((depth > 0).mean())
        dt = time.perf_counter() - t0
    return dt, float(np.mean(fill)), setup


def run(backend, size, n, procs, batch):
    if procs == 1:
        dt, fill, setup = _worker((backend, size, n, 0, None, batch))
        return n / dt, fill, setup
    ctx = mp.get_context("spawn")                            # no GL context inherited by fork
    barrier = ctx.Manager().Barrier(procs)
    share = n // procs
    with ctx.Pool(procs) as pool:
        res = pool.map(_worker, [(backend, size, share, 1 + i, barrier, batch) for i in range(procs)])
    return share * procs / max(r[0] for r in res), float(np.mean([r[1] for r in res])), res[0][2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=400, help="views per measurement at 320x240 (x4 at 64x64)")
    ap.add_argument("--backends", default="embree,pyrender")
    ap.add_argument("--procs", type=int, default=2)
    ap.add_argument("--batch", type=int, default=50, help="views per render_many call (one object's views)")
    ap.add_argument("--repeat", type=int, default=3, help="best of this many runs (shared VMs are noisy)")
    args = ap.parse_args()
    backends = [b for b in args.backends.split(",") if b and (b != "embree" or embree_available())]
    mesh = bench_mesh()
    print(f"mesh: {mesh.metadata.get('file') or mesh.metadata.get('name')} ({len(mesh.faces):,} faces); "
          f"{os.cpu_count()} CPUs")
    if "pyrender" in backends:
        print(f"OpenGL platform: {gl_platform()}")
    print(f"{'backend':9s} {'size':>8s} {'1 proc img/s':>13s} {f'{args.procs} procs img/s':>14s} "
          f"{'target':>7s} {'ratio':>6s}  fill  mesh setup")
    for backend in backends:
        for size, target in TARGETS.items():
            n = args.views * (4 if size == (64, 64) else 1)
            runs = [run(backend, size, n, 1, args.batch) for _ in range(args.repeat)]
            one, fill, setup = max(runs[i][0] for i in range(len(runs))), runs[0][1], min(r[2] for r in runs)
            many = max(run(backend, size, n, args.procs, args.batch)[0]
                       for _ in range(args.repeat)) if args.procs > 1 else one
            print(f"{backend:9s} {size[0]:>4d}x{size[1]:<3d} {one:13.0f} {many:14.0f} {target:7.0f} "
                  f"{many / target:6.2f}  {fill:.1%}  {setup * 1e3:.0f} ms", flush=True)


if __name__ == "__main__":
    main()
