"""What notebook 04 shows about training HBEONet on a run: the learning curves, a one-line test
summary, a few predictions next to the truth, and the options beyond the paper (6-D rotation
output, distance-insensitive input) trained and evaluated on the same data.

Depth in metres, pose errors in degrees (geodesic), grids bool (30, 30, 30) in the canonical frame.

May import: foundation, data, render, model, and the other reproduction modules (matplotlib lazily).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from hbeo.report import figures
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
    ax[0].set_title("loss (lower is better)", fontsize=9)
    ax[1].set_title("class accuracy (higher is better)", fontsize=9)
    ax[2].set_title("pose error (lower is better)", fontsize=9)
    fig.suptitle(f"HBEONet training, {Path(str(model_file)).name}, per epoch (validation: held-out training objects)")
    fig.tight_layout()
    return fig


def summary(metrics: dict) -> str:
    """One line: accuracy against chance, median pose error (raw and modulo symmetry), IoU against
    the class mean shape's (and, under a completion rule other than the paper's, the IoU under the paper's
    rule, back-projection >= 0.5, on the same queries), and milliseconds per query."""
    chance = 1 / len(metrics["classes"])
    pe, comp = metrics["pose_error_deg"], metrics["completion"]
    rule, paper = metrics.get("completion_rule") or {}, metrics.get("completion_paper")
    how = [f"the class's mean shape: {metrics['completion_baseline']['predicted_class']['iou']:.3f}"]
    if paper and rule.get("name", "paper") != "paper":
        how = [f"{rule['name']} rule at {rule['threshold']:g}",
               f"the paper's rule, >= 0.5: {paper['iou']:.3f} with {paper['empty']} empty"] + how
    return (f"accuracy {metrics['accuracy']:.3f} (chance {chance:.3f}); median pose error "
            f"{pe['median']:.1f}° (modulo symmetries {pe['median_sym']:.1f}°); "
            f"IoU {comp['iou']:.3f} ({'; '.join(how)}); "
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
    fig, ax = plt.subplots(len(panels), 3, figsize=(6, 2 * len(panels) + 0.5))
    fig.suptitle("Test views: depth image (true -> predicted class, pose error), completion, true grid", fontsize=9)
    for row, (d, g, truth, title) in zip(np.atleast_2d(ax), panels):
        figures.show_depth(row[0], d, title)
        for a, grid, name in ((row[1], g, "completed"), (row[2], truth, "truth")):
            a.imshow(figures.render_voxels(grid, size=100))
            a.set_title(name, fontsize=8)
            a.axis("off")
    fig.tight_layout()
    return fig


#: The paper's training recipe (:meth:`hbeo.config.RecipeConfig.fit_kwargs`'s keys).
PAPER_RECIPE = {"rotation": "axis_angle", "augment_roll": False, "shape_loss": "coeffs", "class_balance": "none"}
#: The variants notebook 04 can train (a profile's ``options`` picks them): the paper's recipe, the 6-D
#: rotation output, 6-D with the distance-insensitive input, and the profile's own recipe.
OPTIONS = ("paper", "6d", "6d_dist", "recipe")


def option_variants(run, epochs: int | None = None, progress: bool = True) -> pd.DataFrame:
    """Train the paper's recipe, the options beyond it and the run's own recipe on the run's data, all
    for the same epochs (``epochs``, else the profile's ``option_epochs``, else its ``epochs``), and
    score each on the validation objects (:func:`hbeo.evaluation.protocol.evaluate_validation`; the
    test split is not used to compare options): class-mean accuracy (the paper's metric), accuracy, median
    pose error (raw and modulo symmetry), share within 30 degrees, IoU and the share of empty completions."""
    from hbeo.model.fit import TrainOptions
    from hbeo.model.trainingdata import ViewOptions
    from hbeo.evaluation.protocol import evaluate_validation
    prof = run.profile
    n = epochs or prof.recipe.option_epochs or prof.recipe.epochs
    specs = {"paper": ("paper: axis-angle, coefficient loss", PAPER_RECIPE),
             "6d": ("6-D rotation", {**PAPER_RECIPE, "rotation": "6d"}),
             "6d_dist": ("6-D + distance-insensitive", {**PAPER_RECIPE, "rotation": "6d", "view": ViewOptions(True, 1.7)}),
             "recipe": (f"this profile's recipe: {prof.recipe.rotation}, roll {'on' if prof.recipe.augment_roll else 'off'}, "
                        f"{prof.recipe.shape_loss} loss"
                        + (f", class balance {prof.recipe.class_balance}" if prof.recipe.class_balance != "none" else ""),
                        prof.recipe.fit_kwargs())}
    unknown = set(prof.recipe.options) - set(OPTIONS)
    if unknown:
        raise ValueError(f"profile {prof.name}: unknown options {sorted(unknown)}; expected some of {OPTIONS}")
    chosen = [o for o in prof.recipe.options if not (o == "recipe" and prof.recipe.fit_kwargs() == PAPER_RECIPE)]
    rows = {}
    for key in chosen:
        name, kw = specs[key]
        opts = TrainOptions(epochs=n, name=run.dir.model_file(f"model_opt_{key}").name, **kw)
        model = run.train(opts, progress=progress).model
        v = evaluate_validation(model, run, progress=progress)
        rows[f"{name} ({n} epochs)"] = {
            "class mean": v["class_mean_accuracy"], "accuracy": v["accuracy"], "pose median (°)": v["pose_error_deg"]["median"],
            "pose median sym (°)": v["pose_error_deg"]["median_sym"], "within 30°": v["pose_error_deg"]["within_30"],
            "IoU": v["completion"]["iou"], "empty completions": v["completion"]["empty_fraction"],
            "n queries": v["n_queries"]}
    return pd.DataFrame.from_dict(rows, orient="index")
