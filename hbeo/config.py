"""Run profiles and path settings: the one place that sizes a run and finds data.

Profiles
    ``ci``
        6 training objects per class, 80x60 images, a tiny network trained 8 epochs: the
        notebooks under nbval and the tests (minutes).
    ``quick``
        the default run (``make reproduce``, procedural data): the ``cpu`` recipe, fewer epochs and
        test queries, within 45 minutes on 2 cores.
    ``cpu``
        a scaled-down reproduction that finishes on a 2-core machine (the ModelNet10 reference run).
    ``full``
        the paper's scale (GPU): all objects, 320x240 images, 1,800 streamed views per object, 2 epochs
        (12.9 M image passes, the paper's ~7 M images x ~2 epochs).
    ``gpu-lease``
        the paper's network and images, one epoch of 100 streamed views per training object (359 k
        image passes), sized before any GPU measurement for 30 minutes of one GPU; it has no time budget
        of its own (for a shorter rental, the device job's ``--budget`` trains the steps that fit).

Paths (environment variables override the defaults)
    ``HBEO_VOX30``
        the ModelNet10 30^3 grids (``modelnet10_vox30.npz``); default: the
        first ``shared/modelnet10_vox30/modelnet10_vox30.npz`` found beside
        the repository or the working directory or any of their parents.
    ``HBEO_DATA``
        where downloads go (default ``~/.cache/hbeo``).
    ``HBEO_CACHE``
        voxelization cache (default ``<HBEO_DATA>/cache``).
    ``HBEO_RESULTS``
        where runs write (default ``<repo>/results``).
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


@dataclass(frozen=True)
class DataConfig:
    """How much data a run uses and how its training images are made. ``None`` means "all there is"."""

    n_train_per_class: int | None   #: objects per class from the training split (procedural: generated)
    n_test_per_class: int | None    #: objects per class from the test split
    views_per_object: int           #: rendered depth images per training object
    image_size: tuple[int, int]     #: (width, height) of depth images, pixels
    workers: int                    #: worker processes for voxelization and rendering
    procedural_train_per_class: int = 400   #: procedural objects per class when n_train_per_class is None
    #: Where HBEONet's training images come from (``python -m hbeo train --data``): ``memory`` (the rendered
    #: set, all in memory), ``shards`` (the rendered set read shard by shard) or ``stream`` (rendered on the
    #: fly, a fresh pose per object per pass; nothing rendered first); and, in ``stream``, the views rendered
    #: once per validation object (a fixed set).
    train_data: str = "memory"
    stream_val_views: int = 2
    #: The renderer of the run's training views (:class:`hbeo.render.views.RenderSettings` ``backend``):
    #: ``auto`` (embree, else pyrender) or ``torch`` (:mod:`hbeo.render.gridcast`: grid datasets, on the
    #: training device, the stream rendered a batch at a time).
    render_backend: str = "auto"
    #: How training holds out its validation objects (:func:`hbeo.data.datasets.validation_mask`):
    #: ``object`` (objects drawn at random per class; every committed result used it) or ``grouped``
    #: (whole groups of same-class near-duplicates, grid IoU >= ``twin_iou``: :mod:`hbeo.data.dedup`).
    #: 0.95 was chosen on ModelNet10's training split alone (``benchmarks/bench_duplicates.py``): its
    #: nearest-neighbour IoU histogram falls smoothly to ~30 objects per 0.01 bin over 0.95-0.99, then
    #: spikes (358 objects in [0.99, 1]: the near-duplicates); 0.95 takes the spike with a margin while
    #: groups stay small (largest 11 objects; 47 at 0.9, 297 at 0.8, where groups chain).
    val_split: str = "object"
    twin_iou: float = 0.95


@dataclass(frozen=True)
class NetworkConfig:
    """HBEONet's size (:class:`hbeo.model.network.NetConfig` takes these)."""

    conv_channels: tuple[int, int, int, int] = (32, 64, 128, 128)   #: HBEONet's four convolutions
    fc: tuple[int, int, int] = (384, 256, 256)                       #: HBEONet's shared FC layers
    kernel: int = 3                 #: convolution kernel size (the paper does not state it; 3 keeps ~15 M parameters)


@dataclass(frozen=True)
class RecipeConfig:
    """How the run's model is trained (notebook 04, and ``python -m hbeo train`` unless told otherwise)."""

    epochs: int                     #: HBEONet training epochs
    batch_size: int
    lr: float = 1e-3                #: peak learning rate (AdamW)
    #: HBEONet's pose output, roll augmentation and shape loss (``hbeo.model.fit``). The default is the
    #: paper's; ``cpu`` uses the recipe chosen on the validation objects.
    rotation: str = "axis_angle"
    augment_roll: bool = False
    shape_loss: str = "coeffs"
    #: How training counters the class imbalance (``hbeo.model.trainingdata.CLASS_BALANCE``): ``none`` (the paper's),
    #: ``sampler`` (classes drawn uniformly) or ``loss`` (inverse-frequency weighted cross-entropy).
    class_balance: str = "none"
    #: Epochs of each option compared in notebook 04 (None: ``epochs``); every variant, the run's recipe
    #: included, is trained that long, so the comparison is fair (and short).
    option_epochs: int | None = None
    #: Which of notebook 04's variants to train (``hbeo.lessons.training.OPTIONS``).
    options: tuple[str, ...] = ("paper", "6d", "6d_dist", "recipe")

    def fit_kwargs(self) -> dict:
        """The run's model's recipe, as :class:`hbeo.model.fit.TrainOptions` fields (pose output, roll
        augmentation, shape loss, class balance)."""
        return {"rotation": self.rotation, "augment_roll": self.augment_roll, "shape_loss": self.shape_loss,
                "class_balance": self.class_balance}


@dataclass(frozen=True)
class BaselinesConfig:
    """The baselines' sizes: BEO's pose search and the 3-D CNN (:mod:`hbeo.baselines.voxcnn`)."""

    #: Rotations in BEO's 3-DOF search grid (super-Fibonacci; 400 / 2,048 / 8,192 have a mean nearest-neighbour
    #: spacing of 27, 15 and 10 degrees): the search costs ~5 ms per candidate at ~80 subspace dimensions on 2 cores.
    beo_so3_grid: int = 2048
    #: The 3-D CNN baseline: its three encoder widths, bottleneck width, training epochs, batch size, peak
    #: learning rate, rendered views per training object made into partial grids (None = all the rendered
    #: set has) and BCE weight of filled voxels.
    voxcnn_channels: tuple[int, int, int] = (32, 64, 128)
    voxcnn_bottleneck: int = 512
    voxcnn_epochs: int = 20
    voxcnn_batch_size: int = 64
    voxcnn_lr: float = 1e-3
    voxcnn_views_per_object: int | None = 32
    voxcnn_pos_weight: float = 1.5


@dataclass(frozen=True)
class EvaluationConfig:
    """The paired test protocol (:mod:`hbeo.evaluation.protocol`): query views per test object, the same
    (object, view) pairs for every method (the searches of ``beo_3dof_test_per_class`` and
    ``icp_test_per_class`` score the first view only)."""

    eval_views: int = 1
    #: Test objects per class in BEO's 1-DOF and 3-DOF evaluations (its pose search costs up to a minute per
    #: 3-DOF query on 2 cores); None: the same objects as every other method (``data.n_test_per_class``).
    beo_1dof_test_per_class: int | None = None
    beo_3dof_test_per_class: int | None = 1
    icp_test_per_class: int | None = None   #: ICP's test objects per class (None: all)


#: Each profile group and its config class, in the order of :meth:`Profile.to_dict`.
GROUPS = {"data": DataConfig, "network": NetworkConfig, "recipe": RecipeConfig, "baselines": BaselinesConfig,
          "evaluation": EvaluationConfig}
#: Which group holds each field (``prof.<group>.<field>``); :func:`get_profile` routes overrides by it.
FIELD_GROUP = {f.name: g for g, cls in GROUPS.items() for f in fields(cls)}
#: The flat field order of :meth:`Profile.to_dict` (the order the run manifests have always written).
_FLAT_ORDER = ("name", "n_train_per_class", "n_test_per_class", "views_per_object", "image_size", "epochs",
               "batch_size", "workers", "conv_channels", "fc", "kernel", "lr", "procedural_train_per_class",
               "beo_so3_grid", "beo_1dof_test_per_class", "beo_3dof_test_per_class", "needs_gpu",
               "voxcnn_channels", "voxcnn_bottleneck", "voxcnn_epochs", "voxcnn_batch_size", "voxcnn_lr",
               "voxcnn_views_per_object", "voxcnn_pos_weight", "train_data", "stream_val_views", "rotation",
               "augment_roll", "shape_loss", "option_epochs", "options", "eval_views", "icp_test_per_class",
               "render_backend", "val_split", "twin_iou", "class_balance")


@dataclass(frozen=True)
class Profile:
    """Sizes of one run, one small config per concern: ``prof.data``, ``prof.network``, ``prof.recipe``,
    ``prof.baselines``, ``prof.evaluation``."""

    name: str
    data: DataConfig
    recipe: RecipeConfig
    network: NetworkConfig = NetworkConfig()
    baselines: BaselinesConfig = BaselinesConfig()
    evaluation: EvaluationConfig = EvaluationConfig()
    needs_gpu: bool = False         #: the reproduction refuses to start without CUDA (unless HBEO_ALLOW_CPU=1)

    def to_dict(self) -> dict:
        """Every field by its own name, flat (the run manifest's ``profile_settings``)."""
        flat = {"name": self.name, "needs_gpu": self.needs_gpu}
        for g in GROUPS:
            flat.update(asdict(getattr(self, g)))
        return {k: flat[k] for k in _FLAT_ORDER}


# cpu: every training object (ModelNet10: 3,991), few views each: object variety matters more
# than views per object (40 views at the same steps gained nothing: experiments/cpu-modelnet10-vox30/26-v40.toml);
# small images keep an epoch of ~72k images near three minutes on 2 cores for the narrower network (~380 images/s; the wider
# layers run at ~450-650). The recipe (rotation bins, roll augmentation, voxel shape loss, classes drawn
# uniformly, shared layers (1024, 512, 512), 60 epochs) is the one chosen on the validation objects (the
# specs bal30, fc1024 and e60 in experiments/cpu-modelnet10-vox30/). Every test object, 3 paired
# views each; the slow searches (BEO 3-DOF, ICP) on the first view of 10 objects per class (100 queries, a
# subset of the same pairs).
_CPU = Profile(
    "cpu",
    data=DataConfig(n_train_per_class=None, n_test_per_class=None, views_per_object=20, image_size=(80, 60),
                    workers=2, procedural_train_per_class=200),
    recipe=RecipeConfig(epochs=60, batch_size=64, rotation="bins", augment_roll=True, shape_loss="voxels",
                        class_balance="sampler", option_epochs=2, options=("paper", "recipe")),
    network=NetworkConfig(conv_channels=(32, 64, 128, 128), fc=(1024, 512, 512)),
    baselines=BaselinesConfig(voxcnn_channels=(8, 16, 32), voxcnn_bottleneck=128, voxcnn_epochs=5,
                              voxcnn_batch_size=32, voxcnn_lr=2e-3, voxcnn_views_per_object=3),
    evaluation=EvaluationConfig(eval_views=3, beo_3dof_test_per_class=10, icp_test_per_class=10))

PROFILES: dict[str, Profile] = {
    "ci": Profile(
        "ci",
        data=DataConfig(n_train_per_class=6, n_test_per_class=3, views_per_object=8, image_size=(80, 60), workers=1),
        recipe=RecipeConfig(epochs=8, batch_size=32),
        network=NetworkConfig(conv_channels=(8, 16, 16, 16), fc=(64, 64, 64)),
        baselines=BaselinesConfig(beo_so3_grid=400, voxcnn_channels=(8, 16, 32), voxcnn_bottleneck=64,
                                  voxcnn_epochs=3, voxcnn_batch_size=16, voxcnn_lr=3e-3,
                                  voxcnn_views_per_object=None)),
    "cpu": _CPU,
    # quick: the default `make reproduce` (the embedded procedural data): the cpu profile's data, network and
    # recipe, sized to finish within 45 minutes alone on 2 cores. The cpu run of the procedural data took about
    # 100 minutes (60 epochs of ~51 s, then ~20 min of BEO's 1-DOF search over 3,000 queries and ~18 min of its
    # 3-DOF search at 2,048 rotations), so here: 15 epochs, one epoch per notebook-04 option, 50 test objects per
    # class (3 paired views: 1,500 queries), BEO's 3-DOF search over 400 rotations (mean spacing 27 degrees) on 5
    # objects per class, the 3-D CNN 3 epochs. A budget, not a choice on validation: the ModelNet10 reference
    # run keeps the cpu profile's recipe.
    "quick": replace(_CPU, name="quick", data=replace(_CPU.data, n_test_per_class=50),
                     recipe=replace(_CPU.recipe, epochs=15, option_epochs=1),
                     baselines=replace(_CPU.baselines, beo_so3_grid=400, voxcnn_epochs=3),
                     evaluation=replace(_CPU.evaluation, beo_3dof_test_per_class=5)),
    # full: the paper's budget. Its footnote: ~7 M 320x240 depth images, roughly 2 epochs (16 h on a GTX 1070).
    # Streamed, a fresh pose per image: 1,800 views x 3,586 training objects (ModelNet10's 3,984 usable
    # training grids less the 398 held out for validation) = 6.45 M images an epoch, 2 epochs = 12.9 M image
    # passes, the paper's network (NetworkConfig's default: 15.2 M parameters at 320x240 with 133 coefficients).
    "full": Profile(
        "full",
        data=DataConfig(n_train_per_class=None, n_test_per_class=None, views_per_object=1800,
                        image_size=(320, 240), workers=8, train_data="stream", render_backend="torch"),
        recipe=RecipeConfig(epochs=2, batch_size=128),
        baselines=BaselinesConfig(beo_so3_grid=8192),
        evaluation=EvaluationConfig(eval_views=3, beo_1dof_test_per_class=20, beo_3dof_test_per_class=5),
        needs_gpu=True),
    # gpu-lease: what fits one lent GPU's 30 minutes (maintainer/device_job.py): the paper's network and images,
    # streamed, 100 fresh views per training object in one epoch (359 k image passes, 2.8 % of full's), then
    # HBEO on the whole test split, 3 paired views. Sized before any GPU measurement: a lease measures its
    # images/s and says in lease.json how long it took.
    "gpu-lease": Profile(
        "gpu-lease",
        data=DataConfig(n_train_per_class=None, n_test_per_class=None, views_per_object=100,
                        image_size=(320, 240), workers=8, train_data="stream", render_backend="torch"),
        recipe=RecipeConfig(epochs=1, batch_size=128),
        evaluation=EvaluationConfig(eval_views=3, beo_3dof_test_per_class=10, icp_test_per_class=10),
        needs_gpu=True),
}

#: Procedural objects per class when a profile says "all" (the procedural source is unbounded).
PROCEDURAL_FULL = {"train": 400, "test": 100}


def get_profile(name: str | Profile, **overrides) -> Profile:
    """Profile by name (``ci``, ``cpu``, ``full``), with optional overrides: a field by its own name
    (``epochs=3`` goes to ``recipe``), or a whole group (``recipe=RecipeConfig(...)``)."""
    if isinstance(name, Profile):
        prof = name
    else:
        try:
            prof = PROFILES[name]
        except KeyError:
            raise ValueError(f"unknown profile {name!r}; expected one of {', '.join(PROFILES)}") from None
    top = {k: v for k, v in overrides.items() if k not in FIELD_GROUP}
    unknown = set(top) - {f.name for f in fields(Profile)}
    if unknown:
        raise ValueError(f"unknown profile field {sorted(unknown)}; expected one of "
                         f"{', '.join(sorted([*FIELD_GROUP, *GROUPS, 'name', 'needs_gpu']))}")
    for g in GROUPS:
        mine = {k: v for k, v in overrides.items() if FIELD_GROUP.get(k) == g}
        if mine:
            top[g] = replace(top.get(g, getattr(prof, g)), **mine)
    return replace(prof, **top) if top else prof


def _find_upwards(relative: str, starts) -> Path | None:
    for start in starts:
        for d in [start, *start.parents]:
            cand = d / relative
            if cand.exists():
                return cand
    return None


def vox30_path() -> Path | None:
    """Path of the ModelNet10 30^3 grid file, or None when it cannot be found."""
    env = os.environ.get("HBEO_VOX30")
    if env:
        p = Path(env).expanduser()
        return p / "modelnet10_vox30.npz" if p.is_dir() else p
    return _find_upwards("shared/modelnet10_vox30/modelnet10_vox30.npz",
                         [REPO_ROOT.parent, Path.cwd().resolve()])


def modelnet10_sample_dir() -> Path | None:
    """The five-mesh ModelNet10 sample beside the repository (for tests), or None."""
    env = os.environ.get("HBEO_MODELNET10_SAMPLE")
    if env:
        return Path(env).expanduser()
    return _find_upwards("shared/modelnet10_sample", [REPO_ROOT.parent, Path.cwd().resolve()])


def data_dir() -> Path:
    """Root for downloaded data (``HBEO_DATA``, default ``~/.cache/hbeo``)."""
    return Path(os.environ.get("HBEO_DATA", Path.home() / ".cache" / "hbeo")).expanduser()


def cache_dir() -> Path:
    """Root of the voxelization cache (``HBEO_CACHE``, default ``<data_dir>/cache``)."""
    env = os.environ.get("HBEO_CACHE")
    return Path(env).expanduser() if env else data_dir() / "cache"


def run_path(profile: str, dataset: str, out_dir: str | os.PathLike | None = None, training_seed: int = 0) -> Path:
    """Where a run lives (not created; :class:`hbeo.rundir.RunDir` owns what is inside): ``out_dir``
    if given (relative paths are taken from the repository root), else
    ``<HBEO_RESULTS>/<profile>-<dataset>``, or ``<HBEO_RESULTS>/<profile>-<dataset>-seed<S>`` for a
    run whose models are trained with a training seed ``S`` other than 0 (:attr:`hbeo.run.Run.training_seed`)."""
    if out_dir:
        p = Path(out_dir).expanduser()
        return p if p.is_absolute() else REPO_ROOT / p
    base = Path(os.environ.get("HBEO_RESULTS", REPO_ROOT / "results"))
    safe = str(dataset).replace(os.sep, "_").strip("_") or "dataset"
    return base / (f"{profile}-{safe}" + (f"-seed{int(training_seed)}" if training_seed else ""))
