"""The streamed training loop's own speed on one device: what a device job's steps cost, apart from the
renderer and the network alone (``bench_gpu_step.py``).

    python benchmarks/bench_stream_loop.py [--profile gpu-lease] [--dataset modelnet10-vox30] [--steps 40]
                                           [--run DIR] [--json FILE]

In a fresh run folder (default: a temporary one) of the profile and dataset: the subspace, then

- ``caster_s``: the training objects' :class:`hbeo.render.gridcast.GridCaster` built on the training device
  (:meth:`hbeo.render.torch_datasets.FreshPoses.caster`; the grids smoothed in worker processes where the
  machine has the CPUs), which the trainings below then share (:func:`hbeo.render.torch_datasets.shared_caster`);
- ``ahead_N`` (``--render-ahead N ...``): one more training each, N images rendered in one march
  (:meth:`hbeo.model.trainingdata.ModelView.plan_reads`; the same images whatever N);
- ``first`` and ``second``: two trainings of ``--steps`` steps each (``Run.train`` with ``max_steps``, as the
  device job's warm-up and calibration), each with its wall time and the loop's images/s from its training
  log (validation and saving are outside the loop); the first pays the process's warm-up (CUDA, cuDNN).

Before the shared caster and the projected coefficients (second lease, 2026-11-26, one H200), the device job's
40 calibration steps ran at 116 images/s, with the caster built inside them; ``bench_gpu_step.py`` put the
renderer and the network together at 1,126 images/s at the same batch.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--profile", default="gpu-lease")
    ap.add_argument("--dataset", default="modelnet10-vox30")
    ap.add_argument("--steps", type=int, default=40, help="steps of each training (40)")
    ap.add_argument("--run", help="run folder (default: a temporary one)")
    ap.add_argument("--render-ahead", type=int, nargs="*", default=[], metavar="N",
                    help="then one training of --steps steps per N: images rendered in one march (0: a batch; "
                         "the default of the trainings above: up to 2048 on a GPU), e.g. --render-ahead 0 512 2048 8192")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args(argv)
    import torch
    from hbeo.model.fit import TrainOptions
    from hbeo.model.loop import training_history
    from hbeo.model.trainingdata import ViewOptions, training_data
    from hbeo.render.views import RenderSettings
    from hbeo.run import Run
    tmp = None if args.run else tempfile.TemporaryDirectory()
    run = Run.open(args.profile, args.dataset, args.run or tmp.name)
    dev = torch.cuda.get_device_name() if torch.cuda.is_available() else f"cpu ({torch.get_num_threads()} threads)"
    out = {"device": dev, "torch": torch.__version__, "profile": args.profile, "dataset": args.dataset,
           "batch": run.profile.recipe.batch_size, "steps": args.steps}
    t = time.perf_counter()
    run.subspace(progress=False)
    out["subspace_s"] = round(time.perf_counter() - t, 2)
    settings = RenderSettings.from_profile(run.profile, backend="torch")
    data = training_data(run.dir, ViewOptions(), source="stream", dataset=run.dataset, profile=run.profile,
                         settings=settings, progress=False)
    fresh = data.train.base
    t = time.perf_counter()
    caster = fresh.caster()
    if torch.cuda.is_available():
        torch.cuda.synchronize()
    out["caster_s"] = round(time.perf_counter() - t, 2)
    out["objects"] = caster.n_objects
    print(f"{dev}; {args.profile} on {args.dataset}: subspace {out['subspace_s']} s, caster of "
          f"{caster.n_objects} objects {out['caster_s']} s", flush=True)
    for name, ahead in [("first", None), ("second", None), *((f"ahead_{n}", n) for n in args.render_ahead)]:
        t = time.perf_counter()
        model = run.train(TrainOptions(name=f"bench-{name}.hbeo", max_steps=args.steps, render_ahead=ahead,
                                       data="stream", backend="torch"),
                          progress=False)
        wall = time.perf_counter() - t
        row = training_history(run.dir.training(model.path))[-1]
        out[name] = {"wall_s": round(wall, 2), "steps": int(row["step"]),
                     "loop_images_per_s": round(float(row["images_per_s"]), 1)}
        print(f"  {name}: {int(row['step'])} steps in {wall:.1f} s; the loop {row['images_per_s']:.0f} images/s",
              flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1))
    if tmp is not None:
        tmp.cleanup()
    return out


if __name__ == "__main__":
    main()
