"""`RunDir`: the one owner of a run folder's layout.

A run (``results/<profile>-<dataset>/`` by default) holds every product of the pipeline, each
written by one step and read by the later ones. Only this module spells their file names; every
other module and every notebook asks a :class:`RunDir` for a path::

    grids_<split>.npz            data: the split's 30^3 grids and labels (notebook 01)
    subspace.npz                 subspace: the shared VBPCA basis (notebook 02)
    subspace_summary.json        subspace: what ``python -m hbeo subspace`` measured
    render_<split>/              render: the rendered depth set, manifest.json written last (notebook 03)
    model.hbeo                   model: the trained HBEO model file (notebook 04); others model_<name>.hbeo
    train_<model stem>/          model: checkpoint.pt, train_log.csv and provenance.json of that model's training
    beo.npz, icp.npz, voxcnn.hbeo  baselines: fitted baseline files
    partial_train*.npz           baselines: the 3-D CNN's cached partial training grids
    eval_<method>_<pose>.json    evaluation: metrics of one method on the test views
    eval_<method>_<pose>_<sampler>.json  evaluation: the same under another reading of the view protocol
    eval_<name>.json             evaluation: other evaluations, named by whoever ran them
    validation.csv, verify_sweep.csv  evaluation: validation runs and verify settings tried
    models.json, model_table.md  report: the model table (docs/experiments.md), its rows and the table
    NN_<name>.png / .csv / .md   report: the notebooks' figures and tables (names: hbeo.report.tables)
    NN_<name>.ipynb              report: the executed notebooks
    manifest.json                report: provenance (commit, versions, hardware, wall times)
    REPRODUCTION.md              report: the paper's numbers beside the run's
    seeds_table.csv / .md        report: the spread over training seeds of this and other runs (report --seeds)
    seeds_claims.csv / .md       report: the paper's claims judged on each of those runs (report --seeds)
    failures.json                batch steps: the objects each left out, ``[{file, reason, step, ...}]``

Metrics files of models the run no longer holds live outside it, in ``docs/history/<run folder name>/``
(:attr:`RunDir.history`). The rendered set's shards are :mod:`hbeo.render.renderset`'s own layout, and
the book (:mod:`hbeo.report.book`) lists the notebooks, figures and tables a run holds by pattern.

Complete means "written to the end": every file here is written through a temporary name and
renamed (:mod:`hbeo.storage`), and a rendered set counts only once its manifest exists, so
"exists" and "complete" coincide for files, and :meth:`RunDir.status` reports both kinds.

Also owns the record of a batch's bad items (:func:`failure`, :meth:`RunDir.write_failures`,
:func:`failure_summary`), which every batch step (voxelize, render, evaluate) shares.
Imports only :mod:`hbeo.config`, :mod:`hbeo.errors` and :mod:`hbeo.storage`, so every layer may use it.
"""
from __future__ import annotations

import json
import os
import re
from pathlib import Path

from hbeo import config
from hbeo.errors import DataError
from hbeo.storage import atomic_text, json_text, json_type, read_json

_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")

#: The baseline files, by method (``hbeo``'s own file is :attr:`RunDir.model`).
BASELINE_FILES = {"beo": "beo.npz", "icp": "icp.npz", "voxcnn": "voxcnn.hbeo"}
MODEL_SUFFIX = ".hbeo"
#: The name of a run's own HBEO model file (:attr:`RunDir.model`).
DEFAULT_MODEL = f"model{MODEL_SUFFIX}"
CHECKPOINT = "checkpoint.pt"
TRAIN_LOG = "train_log.csv"
PROVENANCE = "provenance.json"
#: Written by a data-parallel run: every rank's final weights digest (they must agree).
RANKS = "ranks.json"
RENDER_MANIFEST = "manifest.json"

#: The types of a run manifest's entries that the reports read, as :mod:`hbeo.report.provenance` writes them:
#: ``text``, ``number``, ``int``, ``bool`` or ``list`` (``?`` after it: or null), or a dict (the entry must be a
#: JSON object; its keys' types, ``*`` for each of its values). Keys not listed may hold anything.
MANIFEST_TYPES = {
    "profile": "text", "dataset": "text", "git_commit": "text?", "git_tag": "text?", "git_dirty": "bool?",
    "code_version": "text?", "updated": "text?", "command": "text?", "one_commit": "bool?",
    "wall_time_total_s": "number",
    "profile_settings": {"name": "text", "image_size": "list", "conv_channels": "list", "fc": "list",
                         "needs_gpu": "bool", "rotation": "text", "augment_roll": "bool", "shape_loss": "text",
                         "class_balance": "text", **{k: "int?" for k in (
                             "n_train_per_class", "n_test_per_class", "views_per_object", "epochs", "option_epochs",
                             "eval_views", "voxcnn_epochs", "beo_so3_grid", "beo_1dof_test_per_class",
                             "beo_3dof_test_per_class", "icp_test_per_class")}},
    "versions": {"*": "text?"},
    "hardware": {"cpu": "text?", "cores": "int?", "memory_gib": "number?", "gpu": "text?", "torch_threads": "int?",
                 "cpu_capability": "text?", "platform": "text?"},
    "seeds": {"training": "int", "evaluation": "int", "rendering": "int"},
    "notebooks": {"*": {"wall_s": "number", "commit": "text?", "dirty": "bool?", "cpu": "text?"}},
    "wall_time_s": {"*": "number?"},                     # the notebooks' wall times in older manifests
    "training": {"*": {"model": "text", "epochs": "int?", "n_params": "int?", "resumed_from_step": "int?",
                       "class_balance": "text?",
                       "recipe": {"rotation": "text", "augment_roll": "bool", "shape_loss": "text",
                                  "class_balance": "text"}}},
}
_MANIFEST_HINT = "; python -m hbeo reproduce writes it (make the run again, or restore the file from git)"
_TYPE_WORDS = {"text": "text", "number": "a number", "int": "a whole number", "bool": "true/false",
               "list": "a JSON list"}
_TYPES = {"text": str, "number": (int, float), "int": int, "bool": bool, "list": list}


def _check_types(value, spec, key: str, path) -> None:
    """DataError naming ``path`` and ``key`` (dotted: ``notebooks.01_voxelize.wall_s``) where ``value`` is not of
    the type ``spec`` says (:data:`MANIFEST_TYPES`)."""
    if isinstance(spec, dict):
        if not isinstance(value, dict):
            raise DataError(path, f"key {key!r} holds {json_type(value)}, not a JSON object{_MANIFEST_HINT}")
        for k, v in value.items():
            sub = spec.get(k, spec.get("*"))
            if sub is not None:
                _check_types(v, sub, f"{key}.{k}" if key else k, path)
        return
    kind = spec.rstrip("?")
    if value is None and spec.endswith("?"):
        return
    if not isinstance(value, _TYPES[kind]) or (isinstance(value, bool) and kind in ("number", "int")):
        words = _TYPE_WORDS[kind] + (" or null" if spec.endswith("?") else "")
        raise DataError(path, f"key {key!r} holds {json_type(value)}, not {words}{_MANIFEST_HINT}")


def failure(file, reason: str, step: str, **extra) -> dict:
    """One bad item of a batch, as ``failures.json`` lists it: ``{"file", "reason", "step", **extra}``
    (``extra``: ``object``, ``split``, ... as the step knows them)."""
    return {"file": None if file is None else os.fspath(file), "reason": str(reason), "step": step, **extra}


def failure_summary(failures: list[dict], total: int, where=None, limit: int = 20) -> str:
    """``"3 of 120 objects failed: ... see RUN/failures.json"`` and one line per bad file (at most
    ``limit``); empty when nothing failed."""
    if not failures:
        return ""
    lines = [f"{len(failures)} of {total} objects failed" + (f"; see {where}" if where else "") + ":"]
    lines += [f"  {f['file']}: {f['reason']} ({f['step']})" for f in failures[:limit]]
    if len(failures) > limit:
        lines.append(f"  ... and {len(failures) - limit} more" + (f" in {where}" if where else ""))
    return "\n".join(lines)


def _check_name(what: str, name: str) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise ValueError(f"{what} must be a plain file name (letters, digits, '_', '-', '.'), got {name!r}")
    return name


class RunDir:
    """A run folder: ``RunDir(path)`` for an existing or new folder, :meth:`for_run` for the default
    ``<results>/<profile>-<dataset>`` place. Paths are returned, never opened; folders are created
    only by :meth:`create` (and by the writers, through :mod:`hbeo.storage`)."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path).expanduser()

    @classmethod
    def of(cls, run: "RunDir | str | os.PathLike") -> "RunDir":
        """``run`` itself if it is a RunDir, else the RunDir at that path (not created): what every
        function taking a ``run`` argument calls first."""
        return run if isinstance(run, RunDir) else cls(run)

    @classmethod
    def for_run(cls, profile: str, dataset: str, out_dir: str | os.PathLike | None = None,
                training_seed: int = 0) -> "RunDir":
        """The run folder of ``profile`` on ``dataset`` (created): ``out_dir`` if given (a relative
        path is taken from the repository root), else ``<HBEO_RESULTS>/<profile>-<dataset>``, with
        ``-seed<S>`` appended for a training seed ``S`` other than 0 (:func:`hbeo.config.run_path`)."""
        return cls(config.run_path(profile, dataset, out_dir, training_seed)).create()

    def create(self) -> "RunDir":
        self.path.mkdir(parents=True, exist_ok=True)
        return self

    def __fspath__(self) -> str:
        return str(self.path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    def __eq__(self, other) -> bool:
        return isinstance(other, RunDir) and self.path == other.path

    def __hash__(self) -> int:
        return hash(self.path)

    @property
    def name(self) -> str:
        return self.path.name

    # --- data (notebook 01) ---
    def grids(self, split: str) -> Path:
        """The grid set of ``split`` (``train`` or ``test``)."""
        return self.path / f"grids_{_check_name('split', split)}.npz"

    # --- subspace (notebook 02) ---
    @property
    def subspace(self) -> Path:
        return self.path / "subspace.npz"

    @property
    def subspace_summary(self) -> Path:
        """The JSON summary ``python -m hbeo subspace`` writes (dimension, components, completion errors)."""
        return self.path / "subspace_summary.json"

    # --- render (notebook 03) ---
    def renders(self, split: str) -> Path:
        """The rendered depth set of ``split`` (a folder; complete once its manifest exists)."""
        return self.path / f"render_{_check_name('split', split)}"

    def render_manifest(self, split: str) -> Path:
        return self.renders(split) / RENDER_MANIFEST

    # --- model (notebook 04) ---
    @property
    def model(self) -> Path:
        """The run's HBEO model file (the one notebooks 05-07 evaluate)."""
        return self.path / DEFAULT_MODEL

    def model_file(self, name: str | None = None) -> Path:
        """A model file of this run: the default one, or ``name`` (``model_6d.hbeo``; the suffix
        is added when missing)."""
        if name is None:
            return self.model
        name = _check_name("model name", name)
        return self.path / (name if name.endswith(MODEL_SUFFIX) else name + MODEL_SUFFIX)

    def training(self, model_file: str | os.PathLike) -> Path:
        """The training folder (checkpoint, log) of the model written to ``model_file``."""
        return self.path / f"train_{Path(model_file).stem}"

    @property
    def validation_log(self) -> Path:
        """``validation.csv``: one row per ``evaluate --split val`` of a model in this folder."""
        return self.path / "validation.csv"

    @property
    def verify_sweep(self) -> Path:
        """``verify_sweep.csv``: every verify setting tried on validation objects, one row each."""
        return self.path / "verify_sweep.csv"

    @property
    def model_rows(self) -> Path:
        """``models.json``: the rows of the model table (``docs/experiments.md``) (label, validation and test
        metrics files of this folder, chosen on validation or not; :mod:`hbeo.report.model_table`)."""
        return self.path / "models.json"

    @property
    def history(self) -> Path:
        """``docs/history/<run folder name>/``: metrics files of models this run no longer holds (earlier
        configurations, ablations), kept for the model table and ``docs/history/test-split-comparisons.md``; outside the run folder."""
        return config.REPO_ROOT / "docs" / "history" / self.path.name

    @property
    def model_table(self) -> Path:
        """``model_table.md``: that table, generated from ``models.json`` and the files it names."""
        return self.path / "model_table.md"

    def checkpoint(self, model_file: str | os.PathLike) -> Path:
        return self.training(model_file) / CHECKPOINT

    def train_log(self, model_file: str | os.PathLike) -> Path:
        return self.training(model_file) / TRAIN_LOG

    def training_provenance(self, model_file: str | os.PathLike) -> Path:
        """How the model written to ``model_file`` was trained (recipe, epochs, resumption), JSON."""
        return self.training(model_file) / PROVENANCE

    def training_provenances(self) -> list[Path]:
        """Every trained model's :meth:`training_provenance` present, sorted."""
        return sorted(self.path.glob(f"train_*/{PROVENANCE}"))

    def model_files(self) -> list[Path]:
        """Every model file (``*.hbeo``: the run's models and the 3-D CNN baseline) present, sorted."""
        return sorted(self.path.glob(f"*{MODEL_SUFFIX}"))

    def training_dirs(self) -> list[Path]:
        """Every model's :meth:`training` folder present, sorted."""
        return sorted(p for p in self.path.glob("train_*") if p.is_dir())

    # --- baselines ---
    def baseline(self, method: str) -> Path:
        """The fitted file of baseline ``method`` (``beo``, ``icp``, ``voxcnn``)."""
        try:
            return self.path / BASELINE_FILES[method]
        except KeyError:
            raise ValueError(f"unknown baseline {method!r}; expected one of {', '.join(BASELINE_FILES)}") from None

    def partial_train(self, views: int | None = None) -> Path:
        """The 3-D CNN's cache of partial training grids (all rendered views, or the first ``views``)."""
        return self.path / ("partial_train.npz" if views is None else f"partial_train_v{int(views)}.npz")

    # --- reproduction (notebooks 05-07) ---
    def evaluation(self, method: str, pose: str, sampler: str | None = None) -> Path:
        """Metrics JSON of ``method`` under pose setting ``pose`` on this run's test views: with the
        model's own view sampler (``sampler`` None), or under another reading of the view protocol
        (``sampler``, a name of :data:`hbeo.render.poses.SAMPLERS`, checked by the caller):
        ``eval_<method>_<pose>_<sampler>.json``."""
        stem = f"eval_{_check_name('method', method)}_{_check_name('pose', pose)}"
        if sampler is not None:
            stem += f"_{_check_name('sampler', sampler)}"
        return self.path / f"{stem}.json"

    def figure(self, name: str) -> Path:
        """A figure of a notebook, ``name`` like ``05_confusion``."""
        return self.path / f"{_check_name('figure name', name)}.png"

    def table(self, name: str, ext: str = "csv") -> Path:
        """A table of a notebook, ``name`` like ``05_table1``; ``ext`` ``csv`` or ``md``."""
        if ext not in ("csv", "md"):
            raise ValueError(f"table ext must be 'csv' or 'md', got {ext!r}")
        return self.path / f"{_check_name('table name', name)}.{ext}"

    def notebook(self, name: str) -> Path:
        """The executed copy of notebook ``name`` (``01_voxelize``)."""
        return self.path / f"{_check_name('notebook', name)}.ipynb"

    @property
    def manifest(self) -> Path:
        """``manifest.json``: the run's provenance (:mod:`hbeo.report.provenance` writes it; read it with
        :meth:`read_manifest`)."""
        return self.path / "manifest.json"

    def read_manifest(self) -> dict:
        """The run's :attr:`manifest` ({} when there is none), its entries' types checked
        (:data:`MANIFEST_TYPES`): DataError naming the file, and the key, when it is not valid JSON or an
        entry the reports read has another type (a hand-edited manifest) than the one its writer gives it."""
        if not self.manifest.exists():
            return {}
        man = read_json(self.manifest, "run manifest", dict, _MANIFEST_HINT)
        _check_types(man, MANIFEST_TYPES, "", self.manifest)
        return man

    @property
    def reproduction(self) -> Path:
        """``REPRODUCTION.md``: the run's report (:mod:`hbeo.report.reproduction_md`)."""
        return self.path / "REPRODUCTION.md"

    @property
    def failures(self) -> Path:
        """The bad items of the batch steps (:meth:`write_failures`)."""
        return self.path / "failures.json"

    def read_failures(self) -> list[dict]:
        """The list in :attr:`failures` ([] when there is none or it is unreadable)."""
        try:
            data = json.loads(self.failures.read_text())
        except (OSError, ValueError):
            return []
        return [f for f in data if isinstance(f, dict)] if isinstance(data, list) else []

    def write_failures(self, step: str, failures: list[dict], splits=None) -> Path:
        """Replace the entries of ``step`` (only those of ``splits`` when given) in :attr:`failures`
        by ``failures``, atomically; entries of other steps stay. The file is removed once empty."""
        keep = [f for f in self.read_failures()
                if f.get("step") != step or (splits is not None and f.get("split") not in splits)]
        data = keep + [dict(f, step=step) for f in failures]
        if data:
            atomic_text(self.failures, json_text(data, indent=1))
        else:
            self.failures.unlink(missing_ok=True)
        return self.failures

    # --- what is there ---
    def status(self) -> dict[str, bool]:
        """Which pipeline products are complete: ``grids_train``, ``grids_test``, ``subspace``,
        ``render_train``, ``render_test``, ``model`` and one entry per baseline file."""
        out = {f"grids_{s}": self.grids(s).is_file() for s in ("train", "test")}
        out["subspace"] = self.subspace.is_file()
        out.update({f"render_{s}": self.render_manifest(s).is_file() for s in ("train", "test")})
        out["model"] = self.model.is_file()
        out.update({m: self.baseline(m).is_file() for m in BASELINE_FILES})
        return out
