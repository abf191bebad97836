"""Host time of a streamed batch's poses: one generator per image (``object_rng``), then either
``ViewSampler.sample(1, g)`` image by image (before 2026-11-27) or ``ViewSampler.sample_each`` (the arithmetic
once for the batch), microseconds an image; the two give the same poses bit for bit (checked here too).

    python benchmarks/bench_pose_draws.py [--images 2048] [--rounds 2] [--sampler so3]
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
    ap.add_argument("--images", type=int, default=2048)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--sampler", default="so3")
    args = ap.parse_args(argv)
    from hbeo.render.poses import ViewSampler
    from hbeo.render.views import object_rng
    vs, n = ViewSampler(args.sampler), args.images

    def gens():
        return [object_rng(0, "train", i % 3586, 5) for i in range(n)]
    rows = []
    for r in range(args.rounds):
        t = time.perf_counter(); gens(); t_gen = time.perf_counter() - t
        t = time.perf_counter(); one = [vs.sample(1, g) for g in gens()]; t_one = time.perf_counter() - t
        t = time.perf_counter(); R, tt = vs.sample_each(gens()); t_each = time.perf_counter() - t
        same = np.array_equal(R, np.concatenate([a for a, _ in one])) and \
            np.array_equal(tt, np.concatenate([b for _, b in one]))
        row = {"round": r, "images": n, "generators_us": t_gen / n * 1e6, "sample_one_by_one_us": t_one / n * 1e6,
               "sample_each_us": t_each / n * 1e6, "identical": bool(same)}
        rows.append(row)
        print(f"round {r}: {n} images, per image: generators alone {row['generators_us']:.1f} us; generators + "
              f"sample(1, g) each {row['sample_one_by_one_us']:.1f} us; generators + sample_each "
              f"{row['sample_each_us']:.1f} us ({row['sample_one_by_one_us'] / row['sample_each_us']:.2f}x); "
              f"identical: {same}")
    return rows


if __name__ == "__main__":
    main()
