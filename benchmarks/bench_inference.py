"""Inference speed of HBEO: one depth image -> class, pose, coefficients and the 30^3 grid.

Target (issue "HBEONet"): <= 10 ms per query at 320x240, batch 1, on a 2-core CPU, including
back-projection to the grid (the paper: 10 ms on a GTX 1070). Speed does not depend on the
weights, so the network is untrained; its size is the profile's (``full``: the paper's 15.7 M
parameters). The subspace is the paper-sized 344-dimensional basis fitted on the real ModelNet10
grids when ../shared is present, else a procedural one. Also prints batch throughput.

Usage: python benchmarks/bench_inference.py [--profile full] [--repeat 50] [--rotation bins] [--threads N]
       [--precision bfloat16] [--rolls 4]
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import torch

from hbeo import config
from hbeo.data import datasets
from hbeo.data.gridset import build_gridset
from hbeo.model.inference import HBEO
from hbeo.model.network import HBEONet, NetConfig
from hbeo.render.renderer import Renderer, record_mesh
from hbeo.render.views import RenderSettings
from hbeo.subspace.basis import ObjectSubspace


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--profile", default="full")
    ap.add_argument("--repeat", type=int, default=50)
    ap.add_argument("--recenter", action="store_true", help="turn every view to the object (resampling path)")
    ap.add_argument("--rotation", default="axis_angle", help="pose head: axis_angle (paper), 6d or bins")
    ap.add_argument("--threads", type=int, help="torch threads (default: torch's choice)")
    ap.add_argument("--precision", default="float32", help="float32 or bfloat16 (HBEO.set_precision)")
    ap.add_argument("--rolls", type=int, default=1, help="test-time roll averaging (needs --rotation bins)")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    prof = config.get_profile(args.profile)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        name = "modelnet10-vox30" if config.vox30_path() else "procedural"
        ds = datasets.get_dataset(name, profile="cpu")
    tr = build_gridset(ds, datasets.select(ds, "train", "full" if name != "procedural" else "cpu"), "train",
                       progress=False)
    sub = ObjectSubspace(shared_dim=344 if name != "procedural" else None).fit(tr.grids, tr.labels, tr.classes,
                                                                              progress=False)
    rs = RenderSettings.from_profile(prof)
    K = rs.intrinsics
    net = HBEONet(NetConfig(image_size=rs.image_size, n_coeffs=sub.dim_, conv_channels=tuple(prof.network.conv_channels),
                            fc=tuple(prof.network.fc), kernel=prof.network.kernel, rotation=args.rotation))
    # as fit_model writes it: the model's own camera, no re-centring (--recenter is an option)
    model = HBEO(net, sub, K, tr.classes, {"render": rs.to_dict(), "recenter": args.recenter}, args.precision)
    Rs, ts = rs.view_sampler.sample(32, np.random.default_rng(0))
    with Renderer(K) as r:
        depth = r.render_many(record_mesh(ds.records("test")[0]), Rs, ts)
    for _ in range(5):
        model.predict(depth[0], K, rolls=args.rolls)
    stages = []
    for i in range(args.repeat):
        stages.append(model.predict(depth[i % 32], K, rolls=args.rolls).timing_ms)
    med = {k: float(np.median([s[k] for s in stages])) for k in stages[0]}
    print(f"{prof.name} network, {net.n_params():,} parameters, {prof.network.kernel}x{prof.network.kernel} kernels, "
          f"{K.width}x{K.height}, subspace dim {sub.dim_} ({name}), recenter {args.recenter}, pose {args.rotation}, "
          f"{args.precision}, rolls {args.rolls}, "
          f"torch threads {torch.get_num_threads()}")
    print("batch 1, median ms: " + ", ".join(f"{k} {v:.2f}" for k, v in med.items())
          + f"  (target <= 10 ms; ratio {med['total'] / 10:.2f})")
    t = time.perf_counter()
    for _ in range(3):
        model.predict(depth, K, rolls=args.rolls)
    per = (time.perf_counter() - t) / (3 * len(depth)) * 1e3
    print(f"batch {len(depth)}: {per:.2f} ms per query, {1000 / per:.0f} queries/s")


if __name__ == "__main__":
    main()
