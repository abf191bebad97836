"""A run: one profile, one dataset and one run folder, resolved once, with the pipeline's stages as methods.

grids (notebook 01) -> subspace (02) -> rendered sets (03) -> model (04) -> baselines. :meth:`Run.open`
resolves the profile (:func:`hbeo.config.get_profile`) and loads the dataset
(:func:`hbeo.data.datasets.get_dataset`, its warnings printed once) a single time; every stage then reads
them from the :class:`Run` instead of resolving names again. Each stage is skipped when its product is
already in the run folder, so one command (``python -m hbeo train``) or any notebook alone builds
whatever is missing. :meth:`Run.train` is the one way a run's model is trained (the CLI's ``train``,
notebook 04 and its option variants) and always writes ``train_*/provenance.json``. Where each product
lives is :class:`hbeo.rundir.RunDir`'s business (:attr:`Run.dir`); a Run is also a path
(``os.fspath(run)``), so functions taking a ``run`` folder accept it.

The batch steps of the command line (:meth:`Run.voxelize`, :meth:`Run.render`, :meth:`Run.subspace_report`)
live here too: they write the run's ``failures.json`` and tables; the CLI only parses.

May import: foundation, data, subspace, render, model and baselines.
"""
from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import NamedTuple

from hbeo import config
from hbeo.data import datasets
from hbeo.data.gridset import build_gridset, run_gridsets
from hbeo.errors import DataError, HBEOError
from hbeo.model.fit import TrainOptions
from hbeo.render.renderset import Manifest, render_set
from hbeo.limits import check_in_memory, check_workers
from hbeo.progress import PAPERMILL_HEADER, kernel_history
from hbeo.render.noise import check_noise_fraction, check_noise_scale
from hbeo.render.views import RenderSettings, check_grid_records
from hbeo.rundir import BASELINE_FILES, RunDir, failure_summary
from hbeo.storage import atomic_text, json_text
from hbeo.subspace.basis import ObjectSubspace

#: Fraction of each class's variance the run's subspace keeps (the paper's 60 %).
VARIANCE = 0.6

__all__ = ["Run", "TrainOptions", "Trained", "VARIANCE", "dataset_summary", "load_dataset", "record_failures",
           "voxelize_to_file"]


def load_dataset(name: str, prof, **kw):
    """:func:`hbeo.data.datasets.get_dataset` with its warnings (e.g. skipped empty grids) printed to
    stderr as one line each, once: later loads of the same dataset in this process stay quiet about it."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = datasets.get_dataset(name, profile=prof, **kw)
    for w in caught:
        print(f"warning: {w.message}", file=sys.stderr)
    warnings.filterwarnings("ignore", message=r".*skipped \d+ empty grids")
    return ds


def baseline_inputs(folder, method: str, model, dataset, dataset_name: str, progress: bool = True) -> None:
    """Make what :func:`hbeo.baselines.methods.load_method` needs to fit or train baseline ``method`` in the
    run folder ``folder`` of the HBEO model ``model`` (a loaded :class:`~hbeo.model.inference.HBEO`), when
    the baseline's file is missing: the run's grid sets (built from ``dataset``, a loaded Dataset named
    ``dataset_name`` on the command line, with the model's profile; progress bar), and for ``beo`` the
    subspace (the model's own basis, written as ``subspace.npz``). What takes a long job (``voxcnn``'s
    rendered training set) is not started here: HBEOError naming the command that makes it."""
    run = RunDir.of(folder)
    if method == "hbeo" or run.baseline(method).exists():
        return
    prof = config.get_profile(model.settings.profile or "cpu")
    if list(dataset.classes) != list(model.classes):
        raise HBEOError(f"{run.baseline(method)}: missing, and --dataset {dataset_name} is not the model's dataset "
                        f"(classes {', '.join(dataset.classes)} vs the model's {', '.join(model.classes)}), so it "
                        f"cannot be fitted from it; evaluate on the model's dataset first")
    if method == "voxcnn" and not run.render_manifest("train").is_file():
        raise HBEOError(f"{run.baseline(method)}: missing, and the 3-D CNN trains on the run's rendered training "
                        f"set, which is not there; make it with: python -m hbeo render --profile {prof.name} "
                        f"--dataset {dataset_name} --out {run.path}")
    if not run.grids("train").exists():
        print(f"[hbeo] {run.grids('train')} missing: building the run's grid sets from {dataset_name} "
              f"(as python -m hbeo voxelize does)", file=sys.stderr, flush=True)
        run_gridsets(run, dataset, prof, progress=progress)
    if method == "beo" and not run.subspace.exists():
        print(f"[hbeo] {run.subspace} missing: writing the model's basis there", file=sys.stderr, flush=True)
        model.subspace.save(run.subspace)


def record_failures(run, step: str, failures: list, total: int, splits) -> list:
    """A batch's end: its bad items written to ``run``'s failures.json (replacing that step's old ones)
    and printed to stderr. Returns ``failures``."""
    path = RunDir.of(run).write_failures(step, failures, splits=splits)
    if failures:
        print(failure_summary(failures, total, path), file=sys.stderr)
    return failures


class Trained(NamedTuple):
    """What :meth:`Run.train` returns: the model, its file, and the optimizer step of the checkpoint the
    training continued from (None: trained from scratch)."""

    model: object
    path: Path
    resumed: int | None = None


def dataset_summary(dataset: str, profile, root=None, download: bool = False, summary: bool = True) -> str:
    """``python -m hbeo data``: ModelNet10 downloaded first when ``download`` (into ``root``, default
    :func:`hbeo.config.data_dir`), the dataset read, then (``summary``) its object counts per class and split."""
    lines = []
    if download:
        if dataset != "modelnet10":
            raise HBEOError("--download applies to --dataset modelnet10 only")
        from hbeo.data.download import fetch_modelnet10
        lines.append(f"ModelNet10 ready in {fetch_modelnet10(Path(root) if root else config.data_dir())}")
    ds = load_dataset(dataset, profile, **({"root": root} if (dataset == "modelnet10" and root) else {}))
    if not summary:
        return "\n".join(lines)
    n_listed = int(ds.summary().loc["total", "total"])
    lines += [f"dataset {ds.name}: {n_listed} objects listed, {len(ds)} usable, {len(ds.classes)} classes",
              ds.summary().to_string()]
    return "\n".join(lines)


def voxelize_to_file(profile, dataset: str, out, workers: int = 0, strict: bool = False) -> str:
    """``python -m hbeo voxelize --out FILE.npz``: every object of ``dataset`` in one file of the published
    ``modelnet10_vox30.npz`` layout (:func:`hbeo.data.gridfile.write_gridfile`); failures on stderr. Returns
    the report."""
    from hbeo.data.gridfile import write_gridfile
    prof = config.get_profile(profile)
    res = write_gridfile(load_dataset(dataset, prof), out, workers=workers or prof.data.workers, strict=strict)
    if res.failures:
        print(res.failure_report(), file=sys.stderr)
    return res.report()


def _assigned(source: str) -> set:
    """The names a cell's top-level statements assign (nothing when it does not parse)."""
    import ast
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return set()
    targets = [t for node in tree.body if isinstance(node, (ast.Assign, ast.AnnAssign))
               for t in (node.targets if isinstance(node, ast.Assign) else [node.target])]
    return {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}     # a, b = ...: both


def check_notebook_parameters(history=None) -> None:
    """Refuse a papermill parameter that the notebook's ``parameters`` cell does not name.

    Papermill only warns of an unknown ``-p`` name, and the notebook then runs with the default of the name
    it was meant to be (``-p epcohs 3`` trains the profile's epochs). ``history``: the cells the kernel
    ran, in order (default: IPython's ``In``; outside IPython nothing is checked). The cell papermill
    injected (:data:`hbeo.progress.PAPERMILL_HEADER`) is compared with the cells run before it; where none was
    injected (nbval, JupyterLab, a script) this does nothing."""
    import difflib
    history = kernel_history() if history is None else history
    for i in range(len(history) - 1, 0, -1):
        if history[i].startswith(PAPERMILL_HEADER):
            declared = set().union(*map(_assigned, history[:i]))
            unknown = sorted(_assigned(history[i]) - declared)
            if declared and unknown:
                near = [f"{u!r} (did you mean {m[0]!r}?)" if (m := difflib.get_close_matches(u, declared, 1)) else
                        repr(u) for u in unknown]
                raise ValueError(f"papermill parameter {', '.join(near)} is not one of this notebook's parameters "
                                 f"({', '.join(sorted(_assigned(history[i - 1]) or declared))}); papermill only "
                                 "warns of it and would run with the default instead: check the spelling of -p")
            return


@dataclass(frozen=True)
class Run:
    """The run of ``profile`` (a :class:`hbeo.config.Profile`) on ``dataset`` (a loaded
    :class:`hbeo.data.datasets.Dataset`, named ``dataset_name`` on the command line) in the folder ``dir``.
    ``training_seed``: the seed of every model the run trains (HBEONet, :meth:`train`, unless its options
    name one; the 3-D CNN, :meth:`baseline`); data, renderings, the validation split and the evaluation's
    views keep their own fixed seeds, so runs of several training seeds are scored on the same test
    images (:mod:`hbeo.report.seeds`). Build it with :meth:`open`."""

    profile: config.Profile
    dataset: datasets.Dataset
    dir: RunDir
    dataset_name: str
    training_seed: int = 0

    @classmethod
    def open(cls, profile, dataset: str, out=None, *, training_seed: int = 0, **dataset_kw) -> "Run":
        """Resolve ``profile`` (name or Profile), load ``dataset`` (name or folder; warnings printed once)
        and create the run folder ``out`` (default ``<results>/<profile>-<dataset>``, with ``-seed<S>``
        for a ``training_seed`` S other than 0: :func:`hbeo.config.run_path`). In a notebook run by
        papermill, a ``-p`` name its parameters cell lacks is refused first (:func:`check_notebook_parameters`)."""
        if isinstance(training_seed, bool) or not isinstance(training_seed, int) or training_seed < 0:
            raise ValueError(f"training_seed must be a whole number >= 0, got {training_seed!r}")
        check_notebook_parameters()
        prof = config.get_profile(profile)
        ds = load_dataset(dataset, prof, **dataset_kw)
        return cls(prof, ds, RunDir.for_run(prof.name, dataset, out, training_seed), str(dataset), training_seed)

    @property
    def path(self) -> Path:
        return self.dir.path

    def __fspath__(self) -> str:
        return str(self.dir.path)

    def records(self, split: str):
        """The profile's records of ``split`` (:func:`hbeo.data.datasets.select`)."""
        return datasets.select(self.dataset, split, self.profile)

    # ------------------------------------------------------------------ grids and subspace

    def grids(self, progress: bool = True, rebuild: bool = False) -> dict:
        """``{"train": GridSet, "test": GridSet}`` (:func:`hbeo.data.gridset.run_gridsets`): read when
        present, else built and written (``rebuild``: always built, notebook 01)."""
        return run_gridsets(self.dir, self.dataset, self.profile, progress=progress, rebuild=rebuild)

    def subspace(self, progress: bool = True) -> ObjectSubspace:
        """The run's subspace: loaded; when missing, the one the run's model file holds (the subspace HBEO was
        trained on, and so the run's: a committed run keeps its model, not its subspace), saved as the run's;
        else fitted (:meth:`fit_subspace`). Fitting it again would give another subspace on another CPU kind
        (VBPCA's sums in another order change its last bits), and BEO and the renders' coefficients with it."""
        if self.dir.subspace.exists():
            return ObjectSubspace.load(self.dir.subspace)
        if self.dir.model.exists():
            from hbeo.model.modelfile import read_subspace
            from hbeo.subspace.basis import data_fingerprint
            sub, train = read_subspace(self.dir.model), self.grids(progress=progress)["train"]
            if sub.fingerprint_ == data_fingerprint(train.grids, train.labels):    # fitted on this run's grids
                print(f"[hbeo] {self.dir.subspace} missing: the subspace of {self.dir.model} (the one it was "
                      f"trained on)", flush=True)
                sub.save(self.dir.subspace)
                return sub
        return self.fit_subspace(progress)

    def fit_subspace(self, progress: bool = True) -> ObjectSubspace:
        """Fit the subspace on the run's training grids (:data:`VARIANCE`; grids built if missing) and
        save it, replacing any earlier one (notebook 02)."""
        train = self.grids(progress=progress)["train"]
        sub = ObjectSubspace(variance=VARIANCE).fit(train.grids, train.labels, train.classes, progress=progress)
        sub.save(self.dir.subspace)
        return sub

    def subspace_report(self, variance: float = VARIANCE, shared_dim: int | None = None,
                        components: int | None = None, method: str = "lstsq", known: float = 0.5,
                        seed: int = 0) -> str:
        """``python -m hbeo subspace``: fit a subspace on the split's grids (built from the voxel cache),
        save it, score full and partial completion on the test grids (a random ``known``-fraction mask of
        ``seed``; ``method`` the partial solver), write both tables and the summary JSON. Returns the text
        to print: per-class components, shared dimension and the mean completion errors per class."""
        import pandas as pd
        from hbeo.subspace import completion
        prof, run = self.profile, self.dir
        sets = {s: build_gridset(self.dataset, self.records(s), s, workers=prof.data.workers) for s in ("train", "test")}
        if components is not None:
            sub = ObjectSubspace(n_components=components)
        else:
            sub = ObjectSubspace(variance=variance, shared_dim=shared_dim)
        sub.fit(sets["train"].grids, sets["train"].labels, sets["train"].classes)
        sub.save(run.subspace)
        counts = pd.DataFrame({"train objects": sets["train"].counts(), "components": sub.n_components_})
        mask = completion.random_mask(sets["test"].grids.shape, known, seed=seed)
        rows = {}
        for mode, m in (("full", None), ("partial", mask)):
            df = completion.evaluate(sub, sets["test"], m, method=method)
            atomic_text(run.table(f"subspace_completion_{mode}"), df.to_csv(index=False))
            rows[mode] = completion.by_class(df)
        table = pd.concat({m: r[["edt", "naive"]] for m, r in rows.items()}, axis=1)
        summary = {"dataset": self.dataset.name, "profile": prof.name, "dim": sub.dim_,
                   "variance_used": sub.variance_used_, "n_components": sub.n_components_, "known_fraction": known,
                   "seed": seed, "method": method,
                   "errors": {m: r.round(6).to_dict(orient="index") for m, r in rows.items()}}
        atomic_text(run.subspace_summary, json_text(summary, indent=2))
        return "\n".join([
            f"\nper-class components (variance fraction {sub.variance_used_}; paper: 30-70 per class at 0.6):",
            counts.to_string(), f"shared dimension: {sub.dim_} (paper: 344)   -> {run.subspace}",
            f"\ntest completion errors, mean per class (full projection; partial from a random "
            f"{known:.0%}-known mask, seed {seed}, {method}):", table.round(3).to_string()])

    # ------------------------------------------------------------------ batch steps of the command line

    def _failed(self, step: str, failures: list, total: int, splits) -> list:
        return record_failures(self.dir, step, failures, total, splits)

    def voxelize(self, workers: int = 0) -> list:
        """``python -m hbeo voxelize``: both splits' grids written into the run folder (one line printed per
        split). Returns the objects that failed; DataError when nothing of a split succeeded (reported first)."""
        splits, failures, total = ("train", "test"), [], 0
        for split in splits:
            recs = self.records(split)
            total += len(recs)
            try:
                gs = build_gridset(self.dataset, recs, split, workers=workers or self.profile.data.workers)
            except DataError as err:
                self._failed("voxelize", failures + getattr(err, "failures", []), total, splits)
                raise
            failures += gs.failures
            print(f"{split}: {len(gs)} grids -> {gs.save(self.dir.grids(split))}")
        return self._failed("voxelize", failures, total, splits)

    def render(self, splits, settings: RenderSettings, subspace=None, workers: int = 0,
               objects_per_shard: int | None = None, progress: bool = True, scheduler: str | None = None) -> list:
        """``python -m hbeo render``: render ``splits`` with ``settings``, with the coefficients of the
        subspace file ``subspace`` (default: the run's, when it has one), one line printed per split,
        warnings about shards rendered again on stderr. Returns the objects that failed; DataError when
        nothing of a split could be rendered (reported first)."""
        sub_path = Path(subspace) if subspace else self.dir.subspace
        subspace = ObjectSubspace.load(sub_path) if (subspace or sub_path.exists()) else None
        failures, total = [], 0
        for split in splits:
            recs = self.records(split)
            total += len(recs)
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    m = render_set(self.dataset, recs, split, self.dir.renders(split), settings, subspace=subspace,
                                   workers=workers or self.profile.data.workers, objects_per_shard=objects_per_shard,
                                   progress=progress, scheduler=scheduler)
            except DataError as err:
                self._failed("render", failures + getattr(err, "failures", []), total, splits)
                raise
            finally:
                for w in caught:
                    print(f"warning: {w.message}", file=sys.stderr)
            failures += m.failures
            rate = f"{m.images_per_s:.1f} images/s" if m.images_per_s else "already rendered, 0 new images"
            coeffs = f", coeffs k={m.coeffs_dim}" if m.coeffs_dim else ""
            print(f"{split}: {m.n_images} images of {len(recs) - len(m.failures)} objects{coeffs} -> {m.root}  "
                  f"({rate})")
        return self._failed("render", failures, total, splits)

    # ------------------------------------------------------------------ renders and the model

    def renders(self, split: str = "train", settings: RenderSettings | None = None, progress: bool = True) -> Manifest:
        """The rendered set of ``split`` with the run's subspace coefficients (rendered, resumed, or read
        when complete); ``settings`` default to the profile's."""
        sub = self.subspace(progress)
        settings = settings or RenderSettings.from_profile(self.profile)
        return render_set(self.dataset, self.records(split), split, self.dir.renders(split), settings,
                          subspace=sub, workers=self.profile.data.workers, progress=progress)

    def train(self, options: TrainOptions | None = None, progress: bool = True) -> Trained:
        """Train a model of this run (:func:`hbeo.model.fit.fit_model`) with the profile's recipe, overridden
        by ``options``, on its training images (rendered first when missing; for ``data="stream"`` the
        subspace alone), with the options' seed or else the run's :attr:`training_seed`, and write
        ``train_<name>/provenance.json`` (recipe, epochs, resumed step, parameters, the options given, the
        seed when not 0). Under ``torchrun`` rank 0 prepares the files and writes."""
        from hbeo.model import distributed
        from hbeo.model.fit import fit_model
        from hbeo.model.network import check_network
        from hbeo.model.loop import CHECKPOINT, load_checkpoint
        opts = options or TrainOptions()
        seed = self.training_seed if opts.seed is None else opts.seed
        prof = self.profile
        check_noise_scale(opts.noise, opts.noise_scale, "a training view")
        check_noise_fraction(opts.noise, opts.noise_fraction, opts.views or prof.data.views_per_object)
        source = opts.data or prof.data.train_data
        if opts.noise_fraction != 1 and source == "stream":
            raise ValueError(f"--noise-fraction {opts.noise_fraction:g}: --data stream draws one view per object a "
                             f"pass, not an object's views together; use --data memory or shards")
        settings = RenderSettings.from_profile(prof, views_per_object=opts.views, sampler=opts.sampler,
                                               backend=opts.backend, image_size=opts.image_size, noise=opts.noise,
                                               noise_scale=opts.noise_scale, noise_fraction=opts.noise_fraction)
        if settings.noise_scale != 1 and source == "stream" and settings.backend == "torch":
            raise ValueError(f"--noise-scale {settings.noise_scale}: the streamed torch renderer draws a batch at "
                             f"the image's size; render the views one object at a time with --data memory, or "
                             f"--backend embree")
        if settings.backend == "torch":                   # grids only: refuse a mesh dataset before any work
            if opts.backend != "torch" and not all(r.has_grid for r in self.records("train")):
                print(f"[hbeo] profile {prof.name} renders with torch, which needs grids; {self.dataset.name} has "
                      f"meshes: rendering them with embree / pyrender (backend auto)", file=sys.stderr)
                settings = replace(settings, backend="auto")
            else:
                check_grid_records(self.records("train"))
        if opts.loader_workers:
            check_workers(opts.loader_workers, "--loader-workers")
        n = len(self.records("train"))                    # refused before anything is rendered
        check_in_memory(n * settings.views_per_object, settings.image_size, per=n,
                        source=source, value=settings.views_per_object)
        # the network's size too (one coefficient: the subspace may not exist yet; fit_model checks it exactly)
        check_network(opts.net_config(prof, settings.image_size, len(self.dataset.classes), 1))
        main = distributed.world().main
        if main:                                          # rank 0 prepares the shared files, the others wait
            if source == "stream":
                self.subspace(progress)
            else:
                self.renders("train", settings, progress)
        distributed.barrier()
        ckpt = self.dir.training(self.dir.model_file(opts.name)) / CHECKPOINT
        resumed = int(load_checkpoint(ckpt)["step"]) if ckpt.exists() else None
        model, path = fit_model(self.dir, prof, replace(opts, seed=seed), dataset=self.dataset, settings=settings,
                                progress=progress)
        distributed.barrier()                             # the model file is complete before any process goes on
        if main:
            info = {"model": path.name, "recipe": opts.recipe(prof), "epochs": opts.epochs or prof.recipe.epochs,
                    "resumed_from_step": resumed, "n_params": model.net.n_params()}
            if (balance := info["recipe"]["class_balance"]) != "none":
                info["class_balance"] = balance
            if opts.changed():
                info["options"] = opts.changed()
            if seed:                                      # seed-0 trainings keep the provenance they had
                info["seed"] = seed
            atomic_text(self.dir.training_provenance(path), json_text(info, indent=1))
        return Trained(model, path, resumed)

    def model(self, progress: bool = True):
        """The run's HBEO model (:attr:`hbeo.rundir.RunDir.model`): loaded, or trained with the profile's
        recipe first (:meth:`train`) when missing, so a later notebook runs alone."""
        from hbeo.model.inference import HBEO
        if self.dir.model.exists():
            return HBEO.load(self.dir.model)
        print(f"[hbeo] {self.dir.model} missing: training it with profile {self.profile.name}'s recipe "
              f"(notebook 04)", flush=True)
        return self.train(progress=progress).model

    def baseline(self, name: str, progress: bool = True, **kw):
        """Baseline ``name`` (``beo``, ``icp``, ``voxcnn``) of this run: loaded, or fitted/trained beside the
        model when missing (:func:`hbeo.baselines.methods.load_method`; the 3-D CNN with the run's
        :attr:`training_seed`), after what fitting it reads is read or made here first (the training grids; BEO's
        subspace; the 3-D CNN's rendered training set), so a later notebook runs alone in a folder that holds only
        the committed files."""
        from hbeo.baselines.methods import load_method
        if name in BASELINE_FILES and not self.dir.baseline(name).exists():
            self.grids(progress=progress)
            if name == "beo":
                self.subspace(progress)
            elif name == "voxcnn":
                self.renders("train", progress=progress)
        return load_method(name, self.dir, self.profile, progress=progress, seed=self.training_seed, **kw)

