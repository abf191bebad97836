"""Host time of a streamed march's poses: drawn in this process against drawn ahead in worker processes.

    python benchmarks/bench_draw_ahead.py [--images 2048] [--workers 2,8] [--rounds 3] [--out FILE]

A march of ``--images`` rolled training views (:class:`hbeo.render.posedraws.PoseDraws` with the default render
settings, 3,586 objects, 20 passes an epoch; every image has two generators, its pose's and its roll's):

- ``here_ms``: :meth:`PoseDraws.draw` of the march in this process, what the training loop pays before each march
  without workers;
- per worker count: ``wall_ms``, submit to joined result with nothing to overlap (the workers' throughput plus the
  transfer, ``images_per_s``); ``main_ms``, the time this process spends in submit and take when the march's device
  work (``--overlap`` seconds, slept here) runs meanwhile: what the loop pays with them;
- ``identical``: every array joined from the workers equal to this process's, bit for bit.

The first submit starts the pool (spawned processes importing numpy and hbeo.render.views, not torch): untimed.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def measure(images: int = 2048, workers=(2, 8), rounds: int = 3, overlap: float = 0.5) -> dict:
    from hbeo.render.posedraws import DrawAhead, PoseDraws
    from hbeo.render.views import RenderSettings
    draws = PoseDraws(RenderSettings(views_per_object=1), "train", 3586, 20)
    rng = np.random.default_rng(0)
    marches = [(rng.integers(0, 3586 * 20, images), np.arange(images) + r * images) for r in range(rounds)]
    t0 = time.perf_counter()
    here = [draws.draw(idx, 5, keys) for idx, keys in marches]
    out = {"images": images, "rounds": rounds, "here_ms": round((time.perf_counter() - t0) / rounds * 1e3, 2),
           "workers": []}
    for w in workers:
        drawer = DrawAhead(draws, w)
        try:
            drawer.submit("warm", marches[0][0][:w], 5)          # spawn the pool: untimed
            drawer.take("warm")
            same, walls, mains = True, [], []
            for r, (idx, keys) in enumerate(marches):
                t0 = time.perf_counter()
                drawer.submit(r, idx, 5, keys)
                got = drawer.take(r)
                walls.append(time.perf_counter() - t0)
                t0 = time.perf_counter()
                drawer.submit(r, idx, 5, keys)
                t1 = time.perf_counter()
                time.sleep(overlap)                              # the device's work on the march before
                t2 = time.perf_counter()
                drawer.take(r)
                mains.append((t1 - t0) + (time.perf_counter() - t2))
                same &= all(np.array_equal(got[k], here[r][k]) for k in ("pos", "R", "t"))
        finally:
            drawer.close()
        wall = float(np.mean(walls))
        out["workers"].append({"workers": w, "wall_ms": round(wall * 1e3, 2),
                               "images_per_s": round(images / wall, 1),
                               "main_ms": round(float(np.mean(mains)) * 1e3, 2), "identical": bool(same)})
    return out


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--images", type=int, default=2048)
    ap.add_argument("--workers", default="2,8", help="worker counts, comma-separated (2,8)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--overlap", type=float, default=0.5, help="seconds of device work to overlap (0.5)")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    out = measure(args.images, [int(w) for w in args.workers.split(",")], args.rounds, args.overlap)
    print(json.dumps(out, indent=1))
    if args.out:
        from hbeo.storage import atomic_text, json_text
        atomic_text(args.out, json_text(out, indent=1))
    return out


if __name__ == "__main__":
    main()
