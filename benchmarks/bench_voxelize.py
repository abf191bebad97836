"""Voxelization throughput: meshes per second per core on ModelNet-sized meshes.

Target (issue "Foundation"): >= 20 meshes/s per core for 5k-50k-face meshes, i.e. all
4,899 ModelNet10 meshes in under 3 minutes on 2 cores.

Meshes: the five real ModelNet10 bathtubs (../shared/modelnet10_sample, 664-30,734 faces)
and the same meshes subdivided once (x4 faces) to cover the top of the size range. Each is
read from disk and voxelized (``hbeo.data.voxel.voxelize`` on the path: parsing included), in one
process. Prints per-mesh timings, the stage split and the rate.

Usage: python benchmarks/bench_voxelize.py [--repeat 5]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from hbeo import config
from hbeo.data.meshio import read_mesh
from hbeo.data.voxel import fill_solid, surface_grid, voxelize


def write_off(mesh, path):
    with open(path, "w") as f:
        f.write(f"OFF\n{len(mesh.vertices)} {len(mesh.faces)} 0\n")
        np.savetxt(f, mesh.vertices, fmt="%.6f")
        np.savetxt(f, np.hstack([np.full((len(mesh.faces), 1), 3), mesh.faces]), fmt="%d")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    sample = config.modelnet10_sample_dir()
    if sample is None:
        raise SystemExit("needs ../shared/modelnet10_sample")
    files = sorted((sample / "bathtub" / "train").glob("*.off"))
    tmp = Path(tempfile.mkdtemp())
    for f in list(files):
        m = read_mesh(f)
        if len(m.faces) < 15000:
            v, fa = trimesh.remesh.subdivide(m.vertices, m.faces)
            out = tmp / f"{f.stem}_x4.off"
            write_off(trimesh.Trimesh(v, fa, process=False), out)
            files.append(out)
    rows = []
    for f in files:
        n_faces = len(read_mesh(f).faces)
        voxelize(f)  # warm-up
        t = time.perf_counter()
        for _ in range(args.repeat):
            voxelize(f)
        total = (time.perf_counter() - t) / args.repeat
        t = time.perf_counter()
        for _ in range(args.repeat):
            m = read_mesh(f)
        t_read = (time.perf_counter() - t) / args.repeat
        v, fa = np.asarray(m.vertices), np.asarray(m.faces)
        t = time.perf_counter()
        for _ in range(args.repeat):
            s = surface_grid(v, fa)
        t_surf = (time.perf_counter() - t) / args.repeat
        t = time.perf_counter()
        for _ in range(args.repeat):
            fill_solid(s, close=1)
        t_fill = (time.perf_counter() - t) / args.repeat
        rows.append((f.name, n_faces, total, t_read, t_surf, t_fill))
    print(f"{'mesh':24s} {'faces':>7s} {'total ms':>9s} {'read':>6s} {'surface':>8s} {'fill':>6s}")
    for name, nf, tot, r, s, fl in rows:
        print(f"{name:24s} {nf:7d} {tot * 1e3:9.1f} {r * 1e3:6.1f} {s * 1e3:8.1f} {fl * 1e3:6.1f}")
    sized = [r for r in rows if 5000 <= r[1] <= 50000]
    rate = len(sized) / sum(r[2] for r in sized)
    print(f"\nModelNet-sized meshes (5k-50k faces): {len(sized)}, mean {1e3 / rate:.1f} ms/mesh "
          f"-> {rate:.1f} meshes/s per core (target >= 20; ratio {rate / 20:.2f})")
    print(f"all {4899} ModelNet10 meshes on 2 cores at this rate: {4899 / (2 * rate) / 60:.1f} min")


if __name__ == "__main__":
    main()
