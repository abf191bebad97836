"""The first minute on a GPU: set-up, the fused grid marcher against the torch one, renderer and network speed.

    python benchmarks/bench_gpu_first_minute.py --out FILE [--profile gpu-lease] [--grids auto] [--objects 5]
                                                [--seconds 1.5] [--batches 512,2048,8192]
                                                [--net-batches 128,256,512,2048] [--cpu-check]

Stages, in order; ``--out`` (JSON) is rewritten after every stage and every figure, so a run cut short by its
time limit still returns what it measured. A stage that fails records its error and the next one runs.

- ``setup``: device, torch, CUDA, triton, CPU count, the profile's image size and network, the grids
  (``vox30``: ``--objects`` training grids a class from ``modelnet10-vox30`` where ``HBEO_VOX30`` or
  ``shared/`` has it; ``procedural``: ``--objects`` procedural objects a class, voxelized here; ``auto``: the
  first that exists) and the time to build the caster (smoothing every grid).
- ``compile``: the fused kernel's first call (Triton's compilation, or the interpreter's first run).
- ``agreement``: the same images (``--agree`` random objects and default-sampler poses) rendered by both
  marchers on the device: pixels, pixels whose depth differs (any bit), the largest and median |depth
  difference| over them (metres), hit/miss flips each way and the images with a flip.
- ``both``: the fused marcher's batch then the loop's ``amp-bfloat16`` step on it, per network batch (batches 128,
  256 and 512 decide the device job's batch: ``maintainer/device_job.py``'s ``batch_choice``; hence this stage
  comes first after the agreement, so that a first minute cut by its time limit still has them). The training
  loop end to end and the batched evaluation are what the device job then measures itself (``lease.json``:
  ``budget``'s calibration, ``stages``; ``train_log.csv``'s images/s).
- ``render``: images/s of :meth:`GridCaster.render` per marcher and batch (``--batches``): one untimed call,
  then calls for ``--seconds`` (at least one), the device synchronised before the clock is read. A torch
  batch whose march would need more than half the free device memory (~128 bytes a ray) is skipped.
- ``tiles``: the fused marcher's images/s at the second batch for a few tile shapes (TW, TH, G).
- ``network``: images/s of HBEONet's training step (forward, the mean square of every output, backward,
  the loop's AdamW) per precision (``float32``; ``amp-float16`` with a GradScaler; ``amp-bfloat16``, the loop's:
  no scaler, :class:`hbeo.model.loop.TrainConfig`'s ``amp_dtype``)
  and batch (``--net-batches``), channels-last, on random depth; code of ``bench_gpu_step.py``.
- ``poses``: the host's time for a march's poses (``--pose-images``), drawn in this process and ahead in worker
  processes (``--pose-workers``), what the training loop pays before each march (``bench_draw_ahead.py``).

On the lent GPU machine (Python 3.12, torch 2.11 + CUDA with its triton 3.6, no trimesh; hbeo not installed),
with ``.device/`` made here by ``bash maintainer/device_prepare.sh`` (the grid file and the missing wheels) carried
beside the tree (sized for about two minutes; not yet run on a GPU)::

    python3 -m pip install -q --no-index --no-deps --target /tmp/site .device/whl/*.whl
    PYTHONPATH=/tmp/site HBEO_VOX30=.device/modelnet10_vox30.npz timeout 420 \
        python3 benchmarks/bench_gpu_first_minute.py --out "$OUT/first_minute.json"

``HBEO_GRIDCAST=torch`` keeps training on the torch march should the fused one disagree there. In a lease the
device job runs this script first (``maintainer/device_job.py --first-minute SECONDS``: its JSON comes back
inside ``lease.json``, and the job sets ``HBEO_GRIDCAST=torch`` itself when the agreement stage fails its rule).

``--cpu-check``: the same stages on a CPU, about 20 s on a loaded 2-core VM (the ``ci`` profile's 80x60
images and network, one grid a class, batch 4, the fused kernel under Triton's interpreter,
``TRITON_INTERPRET=1`` set here before triton is imported); the JSON has the same keys.
``tests/test_fused_bench.py`` runs it.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

STAGES = ("setup", "compile", "agreement", "both", "render", "tiles", "network", "poses")
PRECISIONS = ("float32", "amp-float16", "amp-bfloat16")
LOOP_PRECISION = "amp-bfloat16"         # the training loop's (hbeo.model.loop.TrainConfig.amp_dtype; tested)
TILES = [(16, 8, 1), (8, 8, 1), (32, 4, 1), (16, 16, 1), (32, 8, 1)]
BYTES_PER_RAY = 128                     # the torch march's peak memory per ray (its state and intermediates)


def parse(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", required=True, help="JSON file, rewritten after every stage")
    ap.add_argument("--profile", default="gpu-lease", help="image size and network (gpu-lease: 320x240)")
    ap.add_argument("--grids", default="auto", choices=("auto", "vox30", "procedural"))
    ap.add_argument("--objects", type=int, default=5, help="grids a class (5)")
    ap.add_argument("--seconds", type=float, default=1.5, help="timing per figure (1.5 s)")
    ap.add_argument("--batches", default="512,2048,8192", help="renderer batches")
    ap.add_argument("--net-batches", default="128,256,512,2048",
                    help="network batches (128, 256 and 512 first: the device job's batch rule reads them)")
    ap.add_argument("--agree", type=int, default=256, help="images of the agreement stage (256)")
    ap.add_argument("--pose-images", type=int, default=2048, help="images of a march in the poses stage (2048)")
    ap.add_argument("--pose-workers", default="4,8", help="worker processes of the poses stage (4,8)")
    ap.add_argument("--cpu-check", action="store_true", help="the same stages on a CPU in seconds (interpreter)")
    args = ap.parse_args(argv)
    if args.cpu_check:
        args.profile, args.objects, args.seconds, args.agree = "ci", 1, 0.2, 4
        args.batches, args.net_batches, args.pose_images, args.pose_workers = "4", "4", 64, "1"
    args.batches = [int(b) for b in str(args.batches).split(",")]
    args.net_batches = [int(b) for b in str(args.net_batches).split(",")]
    return args


class Report:
    """The JSON figures, written to ``path`` after every change."""

    def __init__(self, path):
        self.path = Path(path)
        self.data = {"stages_done": [], "errors": {}, **{s: {} for s in STAGES}}
        self.write()

    def write(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.data, indent=1, default=str))
        tmp.replace(self.path)

    def stage(self, name, fn):
        t0 = time.perf_counter()
        try:
            fn(self.data[name])
        except Exception as err:                    # record it and go on to the next stage
            import traceback
            self.data["errors"][name] = f"{type(err).__name__}: {err}"
            print(traceback.format_exc(), file=sys.stderr)
        self.data[name]["stage_s"] = round(time.perf_counter() - t0, 3)
        self.data["stages_done"].append(name)
        self.write()
        print(f"[{name}] {self.data[name]}", flush=True)


def grids_for(source: str, objects: int):
    """(grids, source used): vox30's first ``objects`` training grids a class, or procedural objects voxelized."""
    from hbeo import config
    if source in ("auto", "vox30") and config.vox30_path() is not None:
        from bench_gridcast import sample
        return sample(objects)[0], "vox30"
    if source == "vox30":
        raise FileNotFoundError("modelnet10-vox30 not found (HBEO_VOX30)")
    from hbeo.conventions import CLASSES
    from hbeo.data import procedural
    from hbeo.data.voxel import voxelize
    return [voxelize(procedural.generate(c, "train", i)) for c in CLASSES for i in range(objects)], "procedural"


def main(argv=None) -> None:
    args = parse(argv)
    if args.cpu_check:                               # before anything imports triton
        os.environ["TRITON_INTERPRET"] = "1"
    here = Path(__file__).resolve().parent
    sys.path[:0] = [str(here), str(here.parent)]          # bench_gpu_step, bench_gridcast; hbeo where not installed
    import numpy as np
    import torch
    from bench_gpu_step import timed
    from hbeo import config
    from hbeo.render import fused
    from hbeo.render.gridcast import GridCaster
    from hbeo.render.views import RenderSettings

    rep = Report(args.out)
    device = torch.device("cpu" if args.cpu_check or not torch.cuda.is_available() else "cuda")
    cuda = device.type == "cuda"
    sync = torch.cuda.synchronize if cuda else (lambda: None)
    prof = config.get_profile(args.profile)
    settings = RenderSettings.from_profile(prof, backend="torch")
    W, H = settings.image_size
    rng = np.random.default_rng(0)
    st = {}

    def setup(d):
        d.update(device=torch.cuda.get_device_name(device) if cuda else f"cpu ({torch.get_num_threads()} threads)",
                 torch=torch.__version__, cuda=torch.version.cuda, python=platform.python_version(),
                 cpus=os.cpu_count(), profile=prof.name, image_size=[W, H], cpu_check=args.cpu_check,
                 triton=None, interpreter=fused.interpreting())
        if fused.available():
            import triton
            d["triton"] = triton.__version__
        t0 = time.perf_counter()
        grids, source = grids_for(args.grids, args.objects)
        d.update(grids=len(grids), grid_source=source, grids_s=round(time.perf_counter() - t0, 3))
        t0 = time.perf_counter()
        st["caster"] = caster = GridCaster(grids, settings.intrinsics, settings.object_size, device=device,
                                           backend="torch")
        caster._auto = False                         # the stages switch caster.backend themselves
        d.update(caster_s=round(time.perf_counter() - t0, 3), caster_mb=round(caster.nbytes / 2 ** 20, 1))

    def draw(n):
        R, t = settings.view_sampler.sample(n, rng)
        return rng.integers(0, st["caster"].n_objects, n), R, t

    def render(backend, obj, R, t):
        caster = st["caster"]
        caster.backend = backend
        return caster.render(obj, R, t)

    def compile_(d):
        obj, R, t = draw(2)
        t0 = time.perf_counter()
        render("triton", obj, R, t)
        sync()
        d["first_call_s"] = round(time.perf_counter() - t0, 3)
        t0 = time.perf_counter()
        render("triton", obj, R, t)
        sync()
        d["second_call_s"] = round(time.perf_counter() - t0, 4)

    def agreement(d):
        obj, R, t = draw(args.agree)
        a, b = render("torch", obj, R, t), render("triton", obj, R, t)
        ha, hb = a > 0, b > 0
        differ = a.view(torch.int32) != b.view(torch.int32)
        both = ha & hb
        dd = (a - b).abs()[differ & both]
        d.update(images=int(a.shape[0]), pixels=int(a.numel()), hits_torch=int(ha.sum()), hits_triton=int(hb.sum()),
                 pixels_differ=int(differ.sum()), share_differ=float(differ.float().mean()),
                 max_abs_diff_m=float(dd.max()) if dd.numel() else 0.0,
                 median_abs_diff_m=float(dd.median()) if dd.numel() else 0.0,
                 hit_torch_only=int((ha & ~hb).sum()), hit_triton_only=int((hb & ~ha).sum()),
                 images_with_flip=int((ha != hb).flatten(1).any(1).sum()))

    def speed(backend, batch, tile=None):
        obj, R, t = draw(batch)
        if tile is None:
            fn = lambda: render(backend, obj, R, t)          # noqa: E731
        else:
            caster = st["caster"]
            o, Rs, ts = torch.as_tensor(obj, device=device), torch.as_tensor(R, device=device), \
                torch.as_tensor(t, device=device)
            fn = lambda: fused.march(caster, o, *caster._rays(o, Rs, ts), tile=tile)   # noqa: E731
        n, wall = timed_calls(fn, args.seconds, warmup=0 if args.cpu_check else 1)
        return {"batch": batch, "images_per_s": round(n * batch / wall, 1), "calls": n, "seconds": round(wall, 3)}

    def timed_calls(fn, seconds, warmup):
        for _ in range(warmup):
            fn()
        sync()
        n, t0 = 0, time.perf_counter()
        while n == 0 or time.perf_counter() - t0 < seconds:
            fn()
            n += 1
            sync()
        return n, time.perf_counter() - t0

    def render_stage(d):
        for backend in ("triton", "torch"):
            rows = d.setdefault(backend, [])
            for batch in args.batches:
                need = BYTES_PER_RAY * batch * W * H
                free = torch.cuda.mem_get_info(device)[0] if cuda else None
                if backend == "torch" and free is not None and need > free / 2:
                    rows.append({"batch": batch, "skipped": f"memory: ~{need / 2 ** 30:.0f} GiB of "
                                                            f"{free / 2 ** 30:.0f} GiB free"})
                else:
                    try:
                        rows.append(speed(backend, batch))
                    except Exception as err:
                        rows.append({"batch": batch, "error": f"{type(err).__name__}: {err}"})
                    if cuda:
                        torch.cuda.empty_cache()
                rep.write()

    def tiles(d):
        batch = args.batches[min(1, len(args.batches) - 1)]
        shapes = [fused.tiling(W, H, batch, True)] if args.cpu_check else TILES
        d["rows"] = []
        for tile in shapes:
            d["rows"].append({"tile": list(tile), **speed("triton", batch, tile)})
            rep.write()

    def steps() -> dict:
        """HBEONet's training step per precision (one network and optimizer, made on first use)."""
        if "step" in st:
            return st["step"]
        from hbeo.model.loop import TrainConfig, optimizer
        from hbeo.model.network import HBEONet, NetConfig
        cfg = NetConfig(image_size=(W, H), conv_channels=tuple(prof.network.conv_channels),
                        fc=tuple(prof.network.fc), kernel=prof.network.kernel, rotation=prof.recipe.rotation)
        net = HBEONet(cfg).to(device).to(memory_format=torch.channels_last).train()
        opt = optimizer(net.parameters(), TrainConfig(lr=1e-4), device)
        st["parameters_m"] = round(sum(p.numel() for p in net.parameters()) / 1e6, 2)
        st["step"] = {}
        for precision in PRECISIONS:
            amp = precision.startswith("amp")
            dtype = torch.float16 if precision == "amp-float16" else torch.bfloat16
            scaler = torch.amp.GradScaler(device.type, enabled=precision == "amp-float16")

            def step(depth, amp=amp, dtype=dtype, scaler=scaler):
                x = depth[:, None].contiguous(memory_format=torch.channels_last)
                with torch.autocast(device.type, dtype=dtype, enabled=amp):
                    loss = sum(v.float().pow(2).mean() for v in net(x).values())
                opt.zero_grad(set_to_none=True)
                scaler.scale(loss).backward()
                scaler.step(opt)
                scaler.update()
            st["step"][precision] = step
        return st["step"]

    def network(d):
        step_of = steps()
        d.update(parameters_m=st["parameters_m"], rows=[])
        for precision, step in step_of.items():
            for batch in args.net_batches:
                row = {"precision": precision, "batch": batch}
                try:
                    depth = torch.rand((batch, H, W), device=device) + 1.0
                    row["images_per_s"] = round(timed(lambda: step(depth), device, args.seconds, batch), 1)
                except Exception as err:
                    row["error"] = f"{type(err).__name__}: {err}"
                d["rows"].append(row)
                rep.write()

    def both(d):
        d["rows"] = []
        step = steps()[LOOP_PRECISION]
        for batch in args.net_batches:
            obj, R, t = draw(batch)
            n, wall = timed_calls(lambda: step(render("triton", obj, R, t)), args.seconds,
                                  warmup=0 if args.cpu_check else 1)
            d["rows"].append({"marcher": "triton", "precision": LOOP_PRECISION, "batch": batch,
                              "images_per_s": round(n * batch / wall, 1)})
            rep.write()

    def poses(d):
        from bench_draw_ahead import measure
        d.update(measure(args.pose_images, [int(w) for w in str(args.pose_workers).split(",")], rounds=2,
                         overlap=0.05 if args.cpu_check else 0.3))

    rep.stage("setup", setup)
    for name, fn in (("compile", compile_), ("agreement", agreement), ("both", both), ("render", render_stage),
                     ("tiles", tiles), ("network", network)):
        if "caster" not in st and name != "network":
            rep.data["errors"][name] = "no caster (the setup stage failed)"
            rep.data["stages_done"].append(name)
            rep.write()
            continue
        rep.stage(name, fn)
    rep.stage("poses", poses)                      # the host alone: whatever the device stages did
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
