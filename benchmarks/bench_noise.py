"""Sensor noise at a sensor's size: SensorNoise in the window around the object against the whole frame.

    python benchmarks/bench_noise.py [--dataset modelnet10-vox30] [--objects 12] [--scales 1,8]

``evaluate --noise --noise-scale 8`` and ``train --noise --noise-scale 8`` render every view at 640x480 and
apply :class:`hbeo.render.noise.SensorNoise` there. Renders ``--objects`` training objects' views (the `cpu`
profile's 20 per object, 80x60 times each scale, one thread), then times the noise on those clean frames two
ways: :meth:`SensorNoise.apply` (the window holding the object plus ``seg_px + 2`` pixels) and the same
arithmetic over the whole frame (``_apply_box`` given the frame); says whether every image is identical, and
the views per second of rendering and noise together.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main(argv=None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dataset", default="modelnet10-vox30")
    ap.add_argument("--objects", type=int, default=12)
    ap.add_argument("--scales", default="1,8", help="noise scales, comma-separated (1,8)")
    args = ap.parse_args(argv)
    import torch
    torch.set_num_threads(1)
    from hbeo.render.noise import SensorNoise
    from hbeo.render.views import ObjectViews, RenderSettings
    from hbeo.run import Run
    run = Run.open("cpu", args.dataset, tempfile.mkdtemp(prefix="bench-noise-"))
    records = run.records("train")
    records = records[::max(len(records) // args.objects, 1)][:args.objects]
    noise, rows = SensorNoise(), []
    for scale in (int(s) for s in args.scales.split(",")):
        frames = []

        class Keep:                      # stands in for the noise: keeps each clean frame
            def apply(self, depth, K, rng):
                frames.append((np.array(depth), K))
                return depth

        views = ObjectViews(RenderSettings.from_profile(run.profile, noise=True, noise_scale=scale)).open()
        views.noise = Keep()
        t0 = time.perf_counter()
        for i, r in enumerate(records):
            views.views(r, i, 0, "train")
        render_s = time.perf_counter() - t0
        views.close()
        n = sum(len(d) for d, _ in frames)
        times, same = {"window": 0.0, "whole frame": 0.0}, True
        for j, (d, K) in enumerate(frames):
            t0 = time.perf_counter()
            a = noise.apply(d, K, np.random.default_rng(j))
            times["window"] += time.perf_counter() - t0
            t0 = time.perf_counter()
            g = np.random.default_rng(j)                # one stream for the batch, as apply draws it
            b = np.stack([noise._apply_box(x, K, g, (0, K.height, 0, K.width)) if (x > 0).any() else x.copy()
                          for x in d])
            times["whole frame"] += time.perf_counter() - t0
            same &= bool(np.array_equal(a, b))
        K = frames[0][1]
        row = {"scale": scale, "frame": f"{K.width}x{K.height}", "views": n,
               "render ms/view": 1e3 * render_s / n, "noise ms/view (window)": 1e3 * times["window"] / n,
               "noise ms/view (whole frame)": 1e3 * times["whole frame"] / n,
               "ratio": times["whole frame"] / times["window"], "identical": same,
               "views/s rendered with noise": n / (render_s + times["window"])}
        rows.append(row)
        print(" | ".join(f"{k}: {v:.1f}" if isinstance(v, float) else f"{k}: {v}" for k, v in row.items()))
    return rows


if __name__ == "__main__":
    main()
