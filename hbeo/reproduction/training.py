"""What notebook 04 shows about training HBEONet on a run: the learning curves, a one-line test
summary, a few predictions next to the truth, and the options beyond the paper (6-D rotation
output, distance-insensitive input) trained and evaluated on the same data.

Depth in metres, pose errors in degrees (geodesic), grids bool (30, 30, 30) in the canonical frame.

May import: foundation, data, render, model, and the other reproduction modules (matplotlib lazily).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from hbeo.reproduction import figures
from hbeo.reproduction.protocol import evaluate_unsaved
from hbeo.rundir import RunDir


def curves_figure(run, model_file):
    """Loss (training and validation), validation accuracy and validation median pose error per
    epoch, from the training log of ``model_file`` (:meth:`hbeo.rundir.RunDir.train_log`)."""
    import matplotlib.pyplot as plt
    log = pd.read_csv(RunDir.of(run).train_log(model_file))
    fig, ax = plt.subplots(1, 3, figsize=(11, 3))
    ax[0].plot(log.epoch, log.train_loss, label="train")
    ax[0].plot(log.epoch, log.val_loss, label="validation")
    ax[0].set(xlabel="epoch", ylabel="loss")
    ax[0].legend()
    ax[1].plot(log.epoch, log.val_accuracy)
    ax[1].set(xlabel="epoch", ylabel="validation accuracy")
    ax[2].plot(log.epoch, log.val_pose_median_deg)
    ax[2].set(xlabel="epoch", ylabel="median pose error (°)")
    fig.tight_layout()
    return fig


def summary(metrics: dict) -> str:
    """One line: accuracy against chance, median pose error (raw and modulo symmetry), IoU against
    the class mean shape's, and milliseconds per query."""
    chance = 1 / len(metrics["classes"])
    pe, comp = metrics["pose_error_deg"], metrics["completion"]
    return (f"accuracy {metrics['accuracy']:.3f} (chance {chance:.3f}); median pose error "
            f"{pe['median']:.1f}° (modulo symmetries {pe['median_sym']:.1f}°); "
            f"IoU {comp['iou']:.3f} (the class's mean shape: "
            f"{metrics['completion_baseline']['predicted_class']['iou']:.3f}); "
            f"{metrics['runtime_ms']['median_per_query']:.1f} ms per query")


def predictions_figure(model, ds, view_sampler, n: int = 5, seed: int = 1):
    """Rows for the first test object of the first ``n`` classes, seen from a view of
    ``view_sampler`` (seeded by ``[seed, row]``): the depth image (titled true -> predicted class and
    pose error), the completed grid, the true grid."""
    import matplotlib.pyplot as plt
    from hbeo.rotations import geodesic_deg
    from hbeo.data.gridset import record_grid
    from hbeo.render.renderer import Renderer, record_mesh
    panels = []
    with Renderer(model.intrinsics) as r:
        for i, rec in enumerate(ds.records("test", per_class=1)[:n]):
            Rs, ts = view_sampler.sample(1, np.random.default_rng([seed, i]))
            depth = r.render(record_mesh(rec), Rs[0], ts[0])
            p = model.predict(depth, model.intrinsics)
            err = geodesic_deg(p.rotation[0], Rs[0])
            panels.append((depth, p.grids[0], record_grid(rec), f"{rec.cls} -> {p.class_names[0]}, {err:.0f}°"))
    fig, ax = plt.subplots(len(panels), 3, figsize=(6, 2 * len(panels)))
    for row, (d, g, truth, title) in zip(np.atleast_2d(ax), panels):
        figures.show_depth(row[0], d, title)
        for a, grid, name in ((row[1], g, "completed"), (row[2], truth, "truth")):
            a.imshow(figures.render_voxels(grid, size=100))
            a.set_title(name, fontsize=8)
            a.axis("off")
    fig.tight_layout()
    return fig


def option_variants(run, dataset: str, profile, epochs: int | None, paper_metrics: dict) -> pd.DataFrame:
    """Train the options beyond the paper on the run's data (same epochs), evaluate each on the
    protocol's test views, and table them beside ``paper_metrics`` (the paper's settings):
    accuracy, median pose error (raw and modulo symmetry), IoU and the share of empty completions."""
    from hbeo.model.fit import ViewOptions, fit_model
    run = RunDir.of(run)
    variants = {"paper (axis-angle)": paper_metrics}
    for name, stem, kw in [("6-D rotation", "model_6d", dict(rotation="6d")),
                           ("6-D + distance-insensitive", "model_6d_dist",
                            dict(rotation="6d", view=ViewOptions(True, 1.7)))]:
        model, _ = fit_model(run, profile, epochs=epochs, out_name=run.model_file(stem).name, **kw)
        variants[name] = evaluate_unsaved(model, dataset, profile)
    return pd.DataFrame({n: {"accuracy": v["accuracy"], "pose median (°)": v["pose_error_deg"]["median"],
                             "pose median sym (°)": v["pose_error_deg"]["median_sym"],
                             "IoU": v["completion"]["iou"], "empty completions": v["completion"]["empty_fraction"]}
                         for n, v in variants.items()}).T
