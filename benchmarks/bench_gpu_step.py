"""Where a streamed training step's time goes on one device: the grid renderer, the network, both.

The first GPU lease (2026-11-26, one H200; ``docs/history/gpu-lease-modelnet10-vox30/lease-2026-11-26``) trained
the ``gpu-lease`` profile at 574 images/s, too slow for the paper's budget, without saying where the time went.
This script says it, in a few seconds of device time, before the next job:

    python benchmarks/bench_gpu_step.py [--profile gpu-lease] [--device auto] [--objects 20] [--seconds 5]
                                        [--batch N] [--json FILE]

Set-up: ``--objects`` training grids per ModelNet10 class (``HBEO_VOX30``), the profile's image size, batch,
network (conv channels, kernel, fully connected sizes; the profile's rotation head, 10 classes, 344 coefficients)
and view sampler. Each figure is images/s over ``--seconds`` after two untimed batches, the device synchronised
before the clock is read:

- ``render``: :meth:`hbeo.render.gridcast.GridCaster.render` of a batch at random objects and poses (the torch
  backend's stream renders a training batch this way);
- ``network``: forward, a stand-in loss (the mean square of every output), backward and an AdamW step of
  HBEONet on a batch of random depth, channels-last, with AMP and a GradScaler on CUDA (the loop's settings;
  the loop's optimizer, :func:`hbeo.model.loop.optimizer`: fused on CUDA since 2026-11-27, the figures of the
  leases before then were taken with torch's default AdamW);
- ``both``: the two in sequence on the same batch, what a streamed step costs less the data path and the
  real loss's parts.

The shares ``render/both`` and ``network/both`` (time per image) say which to work on. On a CPU the figures
are a smoke test (``--profile ci``).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from bench_gridcast import sample


def timed(fn, device, seconds: float, batch: int) -> float:
    """Images/s of ``fn()`` (one batch a call), after two untimed calls."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    for _ in range(2):
        fn()
    sync()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        fn()
        n += batch
    sync()
    return n / (time.perf_counter() - t0)


def main() -> None:
    from hbeo import config
    from hbeo.model.loop import TrainConfig, optimizer, pick_device
    from hbeo.model.network import HBEONet, NetConfig
    from hbeo.render.gridcast import GridCaster
    from hbeo.render.views import RenderSettings
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--profile", default="gpu-lease")
    ap.add_argument("--device", default="auto", help="auto (cuda where there is one), cpu or cuda")
    ap.add_argument("--objects", type=int, default=20, help="training grids per class (20)")
    ap.add_argument("--seconds", type=float, default=5.0, help="timing per figure (5 s)")
    ap.add_argument("--batch", type=int, help="images per batch (default: the profile's)")
    ap.add_argument("--json", help="also write the figures to this JSON file")
    args = ap.parse_args()
    prof = config.get_profile(args.profile)
    device = pick_device(args.device)
    batch = args.batch or prof.recipe.batch_size
    settings = RenderSettings.from_profile(prof, backend="torch")
    grids, _ = sample(args.objects)
    caster = GridCaster(grids, settings.intrinsics, settings.object_size, device=device)
    rng = np.random.default_rng(0)
    cfg = NetConfig(image_size=tuple(settings.image_size), conv_channels=tuple(prof.network.conv_channels),
                    fc=tuple(prof.network.fc), kernel=prof.network.kernel, rotation=prof.recipe.rotation)
    net = HBEONet(cfg).to(device).to(memory_format=torch.channels_last).train()
    opt = optimizer(net.parameters(), TrainConfig(lr=1e-4), device)      # the loop's (fused on CUDA)
    amp = device.type == "cuda"
    scaler = torch.amp.GradScaler("cuda", enabled=amp)

    def render():
        R, t = settings.view_sampler.sample(batch, rng)
        return caster.render(rng.integers(0, len(grids), batch), R, t)

    def step(depth):
        x = depth[:, None].contiguous(memory_format=torch.channels_last)
        with torch.autocast(device.type, enabled=amp):
            loss = sum(v.float().pow(2).mean() for v in net(x).values())
        opt.zero_grad(set_to_none=True)
        scaler.scale(loss).backward()
        scaler.step(opt)
        scaler.update()

    w, h = settings.image_size
    noise = torch.rand((batch, h, w), device=device) + 1.0
    fig = {"render": timed(render, device, args.seconds, batch),
           "network": timed(lambda: step(noise), device, args.seconds, batch),
           "both": timed(lambda: step(render()), device, args.seconds, batch)}
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"cpu ({torch.get_num_threads()} threads)"
    print(f"{name}; torch {torch.__version__}; profile {prof.name}: {w}x{h}, batch {batch}, "
          f"{len(grids)} grids, network {sum(p.numel() for p in net.parameters()) / 1e6:.1f} M parameters")
    for k, v in fig.items():
        print(f"  {k:8s} {v:9.0f} images/s   {1e3 / v:7.3f} ms an image")
    share = {k: fig["both"] / fig[k] for k in ("render", "network")}
    print(f"  of a step's time: render {share['render']:.0%}, network {share['network']:.0%}")
    if args.json:
        Path(args.json).write_text(json.dumps({"device": name, "torch": torch.__version__, "profile": prof.name,
                                               "batch": batch, "image_size": [w, h], "grids": len(grids),
                                               "images_per_s": fig, "share_of_step": share}, indent=1))


if __name__ == "__main__":
    main()
