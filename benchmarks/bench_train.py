"""Training throughput and memory of HBEONet's data sources: samples/s and peak RSS per mode.

Goal (issue "Training engine"): >= 1.5x the samples/s of the in-memory loop as it stood before the
engine work (``memory``, torch's default threads, no loader workers; its weights are bit-identical
to the parent commit's, so it stands for "today's loop") on the same machine, in the best mode; and
peak resident memory that does not grow with the number of images for ``shards`` and ``stream``.

Set-up: the ``cpu`` profile's network and images (80x60, batch 64, conv 32-64-128-128) on the
procedural dataset with ``--objects`` training objects per class (default 24: 240 objects), rendered
once into ``--work`` with ``--views`` views each (default 20: 4,800 images). Each mode trains
``--epochs`` epochs in a fresh child process (``python -m hbeo``'s own ``fit_model``; under
``torchrun`` for the data-parallel modes) and reports the median over epochs 2.. of the train log's
images/s (all processes; the steps only: loading, validation and checkpoints are outside it; the
first epoch, with its warm-up, is left out) and its peak resident memory: ``VmHWM`` of the
training process (for data-parallel runs the largest rank, and the sum over ranks) and, sampled,
of the process with its loader workers ("+workers", summed over ranks).

The ``torch grid renderer`` modes stream with render backend ``torch`` (:mod:`hbeo.render.gridcast`: every
batch rendered at once in the training process) from the same objects' voxel grids (the run's grid sets, written
as a ``modelnet10_vox30``-layout file): the procedural meshes themselves cannot be ray-marched.

``--scaling`` adds the memory part: peak RSS of ``memory``, ``shards`` and ``stream`` at ``--views``
and at 10x ``--views`` (a rendered set ten times larger; ``stream`` renders ten times more views
per epoch), ``--scaling-steps`` steps each.

Usage: python benchmarks/bench_train.py [--epochs 4] [--modes 1,2] [--repeat N] [--scaling] [--work DIR] [--json FILE]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: name -> (data source, torch threads (None: torch's default), loader workers, processes[, render backend])
MODES = {
    "memory (before: the baseline)": ("memory", None, 0, 1),
    "memory, 1 thread": ("memory", 1, 0, 1),
    "shards": ("shards", None, 0, 1),
    "shards, 1 loader worker": ("shards", None, 1, 1),
    "stream": ("stream", None, 0, 1),
    "stream, 2 loader workers": ("stream", None, 2, 1),
    "DDP 2x1 thread, memory": ("memory", 1, 0, 2),
    "DDP 2x1 thread, shards": ("shards", 1, 0, 2),
    "DDP 2x1 thread, stream, 1 loader worker each": ("stream", 1, 1, 2),
    "stream, torch grid renderer (batches)": ("stream", None, 0, 1, "torch"),
    "stream, torch grid renderer, 1 thread": ("stream", 1, 0, 1, "torch"),
}
BASELINE = "memory (before: the baseline)"


def _profile(objects: int, views: int):
    from hbeo import config
    return config.get_profile("cpu", procedural_train_per_class=objects, views_per_object=views)


def _run_dir(work: Path, objects: int, views: int) -> Path:
    return work / f"cpu-procedural-{objects}x{views}"


def prepare(work: Path, objects: int, views: int) -> Path:
    """Grids, subspace and the rendered training set of the bench run (once; reused after)."""
    from hbeo.run import Run
    run = _run_dir(work, objects, views)
    Run.open(_profile(objects, views), "procedural", run).renders("train")
    return run


def grid_file(work: Path, run: Path, objects: int, views: int) -> Path:
    """The bench run's own voxel grids (both splits) in the ``modelnet10_vox30.npz`` layout: the dataset of
    the ``torch`` renderer modes, which renders grids (the same objects, as grids; the run's subspace fits)."""
    from hbeo.data import datasets
    from hbeo.data.gridset import run_gridsets
    path = work / f"grids-{objects}x{views}.npz"
    if not path.exists():
        prof = _profile(objects, views)
        sets = run_gridsets(run, datasets.get_dataset("procedural", profile=prof), prof, progress=False)
        arrays = {"classes": np.array(sets["train"].classes)}
        for split, gs in sets.items():
            arrays.update({f"X_{split}": gs.grids, f"y_{split}": gs.labels, f"names_{split}": gs.ids})
        np.savez(path, **arrays)
    return path


def vm_hwm_mib() -> float:
    """This process's peak resident memory (``VmHWM``, MiB). Not ``ru_maxrss``: Linux carries that
    over from the image a process had before ``exec`` (here: the benchmark's own, large, process)."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmHWM in /proc/self/status")


class TreePeak:
    """The peak of this process's resident memory plus its children's (loader workers), sampled
    every 50 ms in a thread (shared pages count once per process, so this is an upper bound)."""

    def __init__(self):
        import threading
        import psutil
        self.peak, self._stop = 0, threading.Event()
        me = psutil.Process()

        def sample():
            while not self._stop.is_set():
                total = 0
                for p in [me, *me.children(recursive=True)]:
                    try:
                        total += p.memory_info().rss
                    except psutil.Error:
                        pass
                self.peak = max(self.peak, total)
                self._stop.wait(0.05)
        self._thread = threading.Thread(target=sample, daemon=True)
        self._thread.start()

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return self.peak / 2**20


def child(spec: dict) -> None:
    """One mode, in this process (or this rank): train, then report speed and peak RSS as JSON."""
    import torch
    from hbeo.model import distributed
    from hbeo.data import datasets
    from hbeo.model.fit import TrainOptions, fit_model
    from hbeo.rundir import RunDir
    if spec["threads"]:
        torch.set_num_threads(spec["threads"])
    w = distributed.setup()
    tree = TreePeak()
    run = RunDir(spec["run"])
    name = f"bench_{spec['tag']}"
    t0 = time.perf_counter()
    prof = _profile(spec["objects"], spec["views"])
    backend = spec.get("backend", "auto")
    ds = None
    if spec["data"] == "stream":
        ds = datasets.get_dataset("procedural", profile=prof) if backend != "torch" else \
            datasets.get_dataset("modelnet10-vox30", path=spec["grids"])
    from hbeo.render.views import RenderSettings
    fit_model(run, prof, TrainOptions(epochs=spec["epochs"], max_steps=spec["steps"], data=spec["data"], name=name,
                                      loader_workers=spec["workers"], backend=backend), dataset=ds, progress=False,
              settings=RenderSettings.from_profile(prof, backend=backend))
    wall = time.perf_counter() - t0
    import pandas as pd
    log = pd.read_csv(run.train_log(run.model_file(name))) if w.main else None
    out = {"rank": w.rank, "wall_s": wall, "threads": torch.get_num_threads(), "rss_mib": vm_hwm_mib(),
           "tree_rss_mib": tree.stop(),
           "images_per_s": float(np.median(log.images_per_s.iloc[1:] if len(log) > 1 else log.images_per_s))
           if log is not None else None}
    Path(f"{spec['report']}.{w.rank}").write_text(json.dumps(out))
    distributed.finish()


def run_mode(name: str, run: Path, objects: int, views: int, work: Path, epochs: int = 1,
             steps: int | None = None) -> dict:
    """Train mode ``name`` in a fresh child process (or torchrun's processes); its row of the table."""
    import shutil
    from hbeo.rundir import RunDir
    data, threads, workers, procs, *backend = MODES[name]
    tag = f"{list(MODES).index(name)}_{views}"
    report = work / f"report_{tag}"
    for f in work.glob(f"report_{tag}.*"):
        f.unlink()
    shutil.rmtree(RunDir(run).training(f"bench_{tag}.hbeo"), ignore_errors=True)
    spec = {"run": str(run), "objects": objects, "views": views, "epochs": epochs, "steps": steps, "data": data,
            "workers": workers, "tag": tag, "report": str(report), "threads": threads or 0,
            "backend": backend[0] if backend else "auto",
            "grids": str(grid_file(work, run, objects, views)) if backend else None}
    env = dict(os.environ, HBEO_BENCH_CHILD=json.dumps(spec))
    if procs > 1:
        cmd = [str(Path(sys.executable).with_name("torchrun")), "--standalone", "--nproc_per_node", str(procs),
               __file__]
        env["OMP_NUM_THREADS"] = str(threads or 1)
    else:
        cmd = [sys.executable, __file__]
    t0 = time.perf_counter()
    p = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{name}: failed\n{p.stderr[-4000:]}")
    reps = [json.loads(f.read_text()) for f in sorted(work.glob(f"report_{tag}.*"))]
    main = next(r for r in reps if r["rank"] == 0)
    return {"mode": name, "data": data, "procs": procs, "threads": main["threads"], "loader_workers": workers,
            "images_per_s": main["images_per_s"], "rss_mib": max(r["rss_mib"] for r in reps),
            "rss_sum_mib": sum(r["rss_mib"] for r in reps), "tree_rss_mib": sum(r["tree_rss_mib"] for r in reps),
            "wall_s": time.perf_counter() - t0}


def step_options(steps: int = 20) -> dict[str, float]:
    """Images/s of one training step alone (forward, the paper's loss, backward, AdamW; batch 64 of
    the cpu network, torch's default threads, no data loading): the compute ceiling of the loop,
    and the arithmetic options the issue names, each measured here (kept only if faster)."""
    import torch
    from hbeo.model.fit import HBEONetTask
    from hbeo.model.network import NetConfig, hbeo_loss
    from hbeo.rotations import matrix_to_axis_angle, uniform_so3
    p = _profile(24, 20)
    cfg = NetConfig(image_size=tuple(p.data.image_size), n_classes=10, n_coeffs=60, conv_channels=tuple(p.network.conv_channels),
                    fc=tuple(p.network.fc), kernel=p.network.kernel)
    R = torch.from_numpy(uniform_so3(64, np.random.default_rng(0)).astype(np.float32))
    batch = {"depth": torch.rand(64, 1, p.data.image_size[1], p.data.image_size[0]) * 2, "label": torch.randint(0, 10, (64,)),
             "rotation": R, "axis_angle": torch.from_numpy(matrix_to_axis_angle(R.numpy()).astype(np.float32)),
             "coeffs": torch.randn(64, 60)}
    out = {}
    for name in ("float32, contiguous", "float32, channels-last (the loop's)", "bfloat16 autocast, channels-last",
                 "torch.compile, channels-last"):
        task = HBEONetTask(cfg)
        torch.manual_seed(0)
        net = task.build()
        step_loss = task.loss
        if "contiguous" in name:
            net = net.to(memory_format=torch.contiguous_format)
            step_loss = lambda n, b: hbeo_loss(n(b["depth"]), b, cfg, task.weights, 1.0, None)  # noqa: E731
        if "compile" in name:
            net = torch.compile(net)
        opt = torch.optim.AdamW(net.parameters(), lr=1e-3)
        t_start = time.perf_counter()
        for i in range(steps + 3):
            if i == 3:                                    # after warm-up (and compilation)
                t0 = time.perf_counter()
                out[f"{name}: warm-up s"] = t0 - t_start
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled="bfloat16" in name):
                loss, _ = step_loss(net, batch)
            opt.zero_grad()
            loss.backward()
            opt.step()
        out[name] = 64 * steps / (time.perf_counter() - t0)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--epochs", type=int, default=4, help="epochs per mode (the first is left out of the speed)")
    ap.add_argument("--objects", type=int, default=24, help="procedural training objects per class")
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--repeat", type=int, default=1, help="run every mode this many times, alternating; medians")
    ap.add_argument("--skip-options", action="store_true", help="leave out the one-step arithmetic options")
    ap.add_argument("--options-only", action="store_true", help="only the one-step arithmetic options")
    ap.add_argument("--modes", help="comma-separated mode numbers (1-based, in the table's order); default all")
    ap.add_argument("--scaling", action="store_true", help="also peak RSS at --views and 10x --views")
    ap.add_argument("--scaling-steps", type=int, default=20)
    ap.add_argument("--work", default=os.path.join(tempfile.gettempdir(), "hbeo_bench_train"))
    ap.add_argument("--json", help="also write the rows to this JSON file")
    if "HBEO_BENCH_CHILD" in os.environ:          # a mode's child process (see run_mode)
        return child(json.loads(os.environ["HBEO_BENCH_CHILD"]))
    args = ap.parse_args()
    if args.options_only:
        for k, v in step_options().items():
            print(f"  {k:48s} {v:7.1f}")
        return
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    run = prepare(work, args.objects, args.views)
    names = list(MODES)
    if args.modes:
        names = [names[int(i) - 1] for i in args.modes.split(",")]
        if BASELINE not in names:
            names.insert(0, BASELINE)
    rows = []
    print(f"cpu profile network, procedural, {args.objects * 10} objects x {args.views} views, {args.epochs} epochs; "
          f"{os.cpu_count()} cores")
    print(f"{'mode':48s} {'images/s':>9s} {'ratio':>6s} {'peak RSS MiB':>13s} {'(sum)':>7s} {'+workers':>9s}")
    runs: dict[str, list[dict]] = {n: [] for n in names}
    for rep in range(args.repeat):                    # modes alternate, so a slow spell of the machine hits all
        for name in names:
            runs[name].append(run_mode(name, run, args.objects, args.views, work, epochs=args.epochs))
            if args.repeat > 1:
                print(f"  repeat {rep + 1}: {name}: {runs[name][-1]['images_per_s']:.0f} images/s", flush=True)
    base = float(np.median([x["images_per_s"] for x in runs[BASELINE]]))
    for name in names:
        speeds = [x["images_per_s"] for x in runs[name]]
        r = {**runs[name][-1], "images_per_s": float(np.median(speeds)), "images_per_s_runs": speeds,
             "ratio": float(np.median(speeds)) / base, "ratios_per_repeat":
             [a / b["images_per_s"] for a, b in zip(speeds, runs[BASELINE])]}
        rows.append(r)
        spread = f"  ({min(speeds):.0f}-{max(speeds):.0f})" if len(speeds) > 1 else ""
        print(f"{name:48s} {r['images_per_s']:9.0f} {r['ratio']:6.2f} {r['rss_mib']:13.0f} {r['rss_sum_mib']:7.0f} "
              f"{r['tree_rss_mib']:9.0f}{spread}", flush=True)
    options = {} if args.skip_options else step_options()
    if options:
        print("\none training step alone (no data loading), images/s:")
    for k, v in options.items():
        print(f"  {k:48s} {v:7.1f}")
    scaling = []
    if args.scaling:
        big = prepare(work, args.objects, args.views * 10)
        print(f"\npeak RSS (MiB) at {args.objects * 10 * args.views} and {args.objects * 10 * args.views * 10} "
              f"training images, {args.scaling_steps} steps")
        for name in ("memory (before: the baseline)", "shards", "stream"):
            small_r = run_mode(name, run, args.objects, args.views, work, steps=args.scaling_steps)
            big_r = run_mode(name, big, args.objects, args.views * 10, work, steps=args.scaling_steps)
            scaling.append({"mode": name, "rss_small_mib": small_r["rss_mib"], "rss_large_mib": big_r["rss_mib"],
                            "tree_small_mib": small_r["tree_rss_mib"], "tree_large_mib": big_r["tree_rss_mib"]})
            print(f"{name:32s} {small_r['rss_mib']:8.0f} {big_r['rss_mib']:8.0f}  "
                  f"(x{big_r['rss_mib'] / small_r['rss_mib']:.2f})", flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps({"rows": rows, "step_options": options, "scaling": scaling,
                                               "args": vars(args)},
                                              indent=2, default=float))


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
