"""What notebook 03 shows about the run's rendered sets: a line per set, one training view per
class beside its grid, the pose distribution against uniform SO(3), storage per set, and a view
with the sensor-noise model applied.

Depth is in metres (0 = no object); rotations take the canonical object frame to the camera frame
(:mod:`hbeo.conventions`); sets are read through their :class:`~hbeo.render.renderset.Manifest`.

May import: foundation, data, render, and :mod:`hbeo.report.figures` (matplotlib lazily).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from hbeo.rotations import matrix_to_axis_angle
from hbeo.report import figures
from hbeo.render.torch_datasets import DepthShards
from hbeo.render.renderset import Manifest
from hbeo.rundir import RunDir


def print_summary(manifests: dict[str, Manifest]) -> None:
    """One line per rendered set: images, objects, shards, and this call's rendering speed."""
    for split, m in manifests.items():
        speed = f"{m.images_per_s:.0f} images/s" if m.images_per_s else "already rendered"
        print(f"{split}: {m.n_images} images of {len(m.object_ids)} objects, {len(m.shards)} shards ({speed})")


def view_gallery(run, train_grids):
    """The first training view of each class (depth, with its pose as angle about an axis) beside
    the object's grid in the canonical frame (``train_grids``: the run's training GridSet); the
    depth images share one colour scale in metres."""
    train = DepthShards(RunDir.of(run).renders("train"))
    ids = list(train_grids.ids)
    items = []
    for c in range(len(train.classes)):
        i = int(np.flatnonzero(train.labels == c)[0])
        x = train[i]
        aa = x["axis_angle"].numpy().astype(float)
        axis = ", ".join(f"{a:.1f}" for a in aa / max(np.linalg.norm(aa), 1e-9))
        obj = train.objects([i])[0]
        title = f"{train.classes[c]}: depth\n{np.degrees(np.linalg.norm(aa)):.0f}° about ({axis})"
        items.append((x["depth"][0].numpy(), train_grids.grids[ids.index(obj)], title))
    title = ("The first training view of each class: its depth image (posed by a rotation of the angle shown\n"
             "about the axis shown, object frame to camera) beside the object's grid in the canonical frame")
    return figures.depth_and_grid_gallery(items, title=title)


def pose_distribution(manifest: Manifest):
    """Histograms of a set's rotation angles and viewpoint elevations (sine), against the
    densities uniform SO(3) gives: (1 - cos θ) / π on [0, π] and uniform on [-1, 1]."""
    import matplotlib.pyplot as plt
    rotations = []
    for path in manifest.shard_paths():
        with np.load(path, allow_pickle=False) as z:
            rotations.append(z["rotation"])
    R = np.concatenate(rotations)
    theta = np.linalg.norm(matrix_to_axis_angle(R), axis=1)
    view_dir = -R[:, 2, :]                      # camera direction seen from the object, object frame
    fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
    ax[0].hist(theta, bins=30, range=(0, np.pi), density=True, alpha=0.7, label="rendered views")
    th = np.linspace(0, np.pi, 200)
    ax[0].plot(th, (1 - np.cos(th)) / np.pi, "k--", label="uniform SO(3): (1 − cos θ) / π")
    ax[0].set(xlabel="rotation angle θ (rad)", ylabel="density")
    ax[0].set_title("rotation angle of each view's pose", fontsize=9)
    ax[0].legend(fontsize=7, loc="upper left")
    n, _, _ = ax[1].hist(view_dir[:, 2], bins=20, range=(-1, 1), density=True, alpha=0.7, label="rendered views")
    ax[1].axhline(0.5, color="k", ls="--", label="uniform SO(3): 1/2")
    ax[1].set(xlabel="sin(elevation of the viewpoint)", ylabel="density", ylim=(0, 1.35 * max(n.max(), 0.5)))
    ax[1].set_title("elevation of the camera seen from the object", fontsize=9)
    ax[1].legend(fontsize=7, loc="upper center", ncol=2)
    split = {"train": "training"}.get(manifest.split, manifest.split)
    fig.suptitle(f"Poses of the {manifest.n_images} rendered {split} views against uniformly random "
                 f"rotations (SO(3))", fontsize=10)
    fig.tight_layout()
    return fig


def storage_table(manifests: dict[str, Manifest]) -> pd.DataFrame:
    """Per set: images, shards, megabytes, kilobytes per image and this call's images per second."""
    rows = []
    for split, m in manifests.items():
        nbytes = sum(s["bytes"] for s in m.shards)
        rows.append({"split": split, "images": m.n_images, "shards": len(m.shards), "MB": nbytes / 1e6,
                     "kB/image": nbytes / m.n_images / 1e3, "images/s (this run)": m.images_per_s})
    return pd.DataFrame(rows).set_index("split")


def sensor_noise_figure(run, settings, seed: int = 0):
    """The run's first training view, clean and with :class:`~hbeo.render.noise.SensorNoise`
    (``seed``), titled with the pixels the noise model lost, on one colour scale in metres."""
    import matplotlib.pyplot as plt
    from hbeo.render.noise import SensorNoise
    x = DepthShards(RunDir.of(run).renders("train"))[0]["depth"][0].numpy()
    noisy = SensorNoise().apply(x, settings.intrinsics, np.random.default_rng(seed))
    seen = np.concatenate([x[x > 0], noisy[noisy > 0]])
    lo, hi = (float(seen.min()), float(seen.max())) if len(seen) else (0.0, 1.0)
    fig, ax = plt.subplots(1, 2, figsize=(6.5, 3.0), layout="constrained")
    figures.show_depth(ax[0], x, "clean (rendered)", vmin=lo, vmax=hi)
    im = figures.show_depth(ax[1], noisy, f"with sensor noise\n({(x > 0).sum() - (noisy > 0).sum()} pixels lost)",
                            vmin=lo, vmax=hi)
    fig.colorbar(im, ax=list(ax), shrink=0.8).set_label("depth (m)", fontsize=8)
    fig.suptitle("The first training view's depth image, clean and with the Kinect-like noise model", fontsize=10)
    return fig
