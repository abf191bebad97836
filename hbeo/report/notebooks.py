"""Running the numbered notebooks (``notebooks/NN_name.ipynb``) with papermill into a run folder.

:func:`run_notebooks` executes them in order with the parameters ``profile``, ``dataset`` and
``out_dir`` (and ``training_seed``, the seed of every model the run trains, when it is not 0: a
seed-0 run is executed exactly as before the option existed); each executed copy goes to :meth:`hbeo.rundir.RunDir.notebook`, and the run's
manifest (:mod:`hbeo.report.provenance`) gets its wall time. :func:`preflight` fails in
seconds, with what to do, what would otherwise fail hours later.

May import: foundation, data, run, and the other report modules (papermill and torch lazily).
"""
from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

from hbeo import config
from hbeo.errors import HBEOError
from hbeo.progress import ProgressEcho
from hbeo.report.provenance import reproduce_command, write_manifest
from hbeo.rundir import RunDir
from hbeo.storage import exclusive_lock

NOTEBOOKS = config.REPO_ROOT / "notebooks"
#: The file in a run folder that ``reproduce`` holds locked while it runs (its pid and start inside).
LOCK_NAME = ".reproduce.lock"


def notebooks(only=None) -> list[Path]:
    """The numbered notebooks (``NN_name.ipynb``) in order, optionally filtered by name prefix."""
    nbs = sorted(p for p in NOTEBOOKS.glob("[0-9][0-9]_*.ipynb"))
    if only is not None:
        unknown = [o for o in only if not any(p.name.startswith(o) for p in nbs)]
        if unknown or not only:
            from hbeo.errors import HBEOError
            what = f"--only {' '.join(unknown)}: no such notebook" if unknown else "--only: no notebook named"
            raise HBEOError(f"{what}; the notebooks are {', '.join(p.stem for p in nbs)}")
        nbs = [p for p in nbs if any(p.name.startswith(o) for o in only)]
    return nbs


#: the errors a notebook stops on for its input (a file, a setting), not for a defect of hbeo
INPUT_ERRORS = ("DataError", "HBEOError", "ValueError", "FileNotFoundError", "PermissionError", "MemoryError")


class NotebookFailed(HBEOError):
    """A numbered notebook stopped on an error: which one, in which cell, the error's name and message, where its
    executed copy (with the whole traceback) is, and what to do next: fix the input it names and go on with
    ``RESUME=1`` (finished stages are skipped), or report an error that is not about the input as a bug."""

    def __init__(self, name: str, copy, cell, ename: str, evalue: str, resume: str = "make reproduce ... RESUME=1"):
        self.name, self.copy, self.cell, self.ename, self.evalue = name, Path(copy), cell, ename, evalue
        if ename in INPUT_ERRORS:
            then = (f"fix what it names, then go on with `{resume}` (what finished, grids, renderings, models and "
                    "evaluations, is read, not made again; training resumes from its checkpoint)")
        else:
            then = (f"an unexpected {ename} inside a notebook is a bug in hbeo; please report it with the command "
                    "and that copy on the project's issue tracker")
        super().__init__(f"notebook {name} stopped in cell {cell}: {ename}: {evalue}\n  the executed copy, with the "
                         f"traceback: {self.copy}\n  {then}")


def run_notebooks(profile: str = "cpu", dataset: str = "procedural", out_dir=None, only=None,
                  fresh: bool = False, training_seed: int = 0) -> list[Path]:
    """Execute notebooks in order with parameters ``profile``, ``dataset``, ``out_dir`` and, when not 0,
    ``training_seed`` (:attr:`hbeo.run.Run.training_seed`: HBEONet's and the 3-D CNN's training seed; the
    data, renderings and test views keep seed 0, so every seed's run scores the same test images).
    ``out_dir`` defaults to ``results/PROFILE-DATASET``, ``-seed<S>`` appended for a seed S other than 0.

    Each executed copy is written into the run folder under the notebook's name; a progress line
    per notebook says what runs and how long it took, and while it runs the terminal shows its latest
    progress bar (step, items done, time estimate; :class:`hbeo.progress.ProgressEcho`); the run's ``manifest.json`` is updated after
    each. The first failing notebook stops the run: :class:`NotebookFailed` says which, in which cell, the error
    and what to do, and the failing copy shows the traceback. ``fresh``: first remove what earlier runs trained or
    evaluated there (:func:`clear_products`), so every model is trained inside this run. After the last notebook,
    the run's ``REPRODUCTION.md`` is written (:func:`hbeo.report.reproduction_md.write_reproduction`; for the
    reference run, :data:`~hbeo.report.reproduction_md.REFERENCE_RUN`, also ``paper/REPRODUCTION.md``).
    Returns the executed copies. One run at a time in a folder: a second one into it is refused while the first
    runs (:func:`hbeo.storage.exclusive_lock` on ``RUN/.reproduce.lock``), since its ``--fresh`` would remove the
    first one's products under it.
    """
    nbs = notebooks(only)                    # an unknown --only fails before anything is opened
    run = preflight(profile, dataset, out_dir, training_seed).dir
    with exclusive_lock(run.path / LOCK_NAME, "python -m hbeo reproduce (make reproduce)"):
        return _run_locked(run, nbs, profile, dataset, fresh, training_seed)


def _run_locked(run, nbs, profile, dataset, fresh, training_seed) -> list[Path]:
    """:func:`run_notebooks` once it holds the run folder's lock."""
    import papermill as pm
    from hbeo.report.reproduction_md import write_reports
    if not fresh:
        check_run_folder(run, profile, dataset, training_seed)
    params = {"profile": profile, "dataset": dataset, "out_dir": str(run.path)}
    if training_seed:
        params["training_seed"] = training_seed
    if fresh:
        for p in clear_products(run):
            print(f"[hbeo] fresh run: removed {p}", flush=True)
        write_manifest(run, profile, dataset, fresh=True, training_seed=training_seed)
    resume = reproduce_command(run, profile, dataset, training_seed, resume=True)
    done = []
    t_all = time.perf_counter()
    for k, nb in enumerate(nbs, 1):
        target = run.notebook(nb.stem)
        seed = f", training seed {training_seed}" if training_seed else ""
        print(f"[hbeo {k}/{len(nbs)}] {nb.name} (profile={profile}, dataset={dataset}{seed}) -> {target}", flush=True)
        t0 = time.perf_counter()
        with ProgressEcho(Path(tempfile.gettempdir()) / f"hbeo-progress-{os.getpid()}.txt",
                          f"[hbeo {k}/{len(nbs)}] {nb.stem}"):
            try:
                pm.execute_notebook(str(nb), str(target), cwd=str(NOTEBOOKS), parameters=params, progress_bar=False)
            except pm.PapermillExecutionError as err:
                raise NotebookFailed(nb.stem, target, err.exec_count, err.ename, err.evalue, resume) from None
            except KeyboardInterrupt:
                # the copy so far is no finished notebook: set it aside under a name that says so
                partial = target.with_name(target.stem + ".partial.ipynb")
                if target.exists():
                    target.replace(partial)
                print(f"\n[hbeo] interrupted in {nb.stem} (its copy so far: {partial}); go on with `{resume}`",
                      file=sys.stderr, flush=True)
                raise
        sec = time.perf_counter() - t0
        write_manifest(run, profile, dataset, {nb.stem: round(sec, 1)}, training_seed=training_seed)
        print(f"[hbeo {k}/{len(nbs)}] {nb.name} done in {sec / 60:.1f} min "
              f"(total {(time.perf_counter() - t_all) / 60:.1f} min)", flush=True)
        done.append(target)
    if nbs and nbs[-1] == notebooks()[-1]:
        for path in write_reports(run, profile, dataset):
            print(f"[hbeo] wrote {path}", flush=True)
    return done


def check_run_folder(run, profile: str, dataset: str, training_seed: int) -> None:
    """HBEOError when the manifest of the run folder ``run`` records another profile, dataset or training seed
    than asked: its models, evaluations and tables would mix two runs' (a folder without a manifest takes any;
    one that is not valid JSON or has entries of the wrong type: DataError naming it, :meth:`RunDir.read_manifest`)."""
    run = RunDir.of(run)
    if not run.manifest.is_file():
        return
    m = run.read_manifest()
    recorded = m.get("seeds", {}).get("training", 0)
    if recorded != training_seed:
        raise HBEOError(f"{run.manifest}: the run's models were trained with training seed {recorded}, not "
                        f"{training_seed}; pass --seed {recorded}, or --fresh to train them all again, or another --out")
    for what, asked, option in (("profile", profile, "--profile"), ("dataset", dataset, "--dataset")):
        if m.get(what) not in (None, asked):
            raise HBEOError(f"{run.manifest}: this run folder holds a run of {what} {m[what]}, not {asked}; pass "
                            f"{option} {m[what]}, or --fresh to start it again with {asked}, or another --out")


def clear_products(run) -> list[Path]:
    """Remove what a run trained, evaluated or reported (model and baseline files, training folders with their
    checkpoints, the protocol's metrics files, the executed notebooks with their tables and figures
    (``NN_*``), ``REPRODUCTION.md`` and the book), so that nothing of an earlier run is left looking like this
    one's if it stops midway; grids, subspace and rendered sets stay (they are checked against their settings
    and rebuilt when stale). Returns the removed paths."""
    import re
    import shutil
    from hbeo.evaluation.protocol import EVALUATIONS
    run = RunDir.of(run)
    made = [p for p in sorted(run.path.iterdir()) if re.match(r"\d\d_", p.name)] if run.path.is_dir() else []
    gone = [*run.model_files(), *[run.baseline(m) for m in ("beo", "icp", "voxcnn")],
            *[run.evaluation(m, p) for m, p in EVALUATIONS], *run.training_dirs(), *made,
            run.path / "REPRODUCTION.md", run.path / "book"]
    out = []
    for p in gone:
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
        else:
            continue
        out.append(p)
    return out


def preflight(profile: str, dataset: str, out_dir=None, training_seed: int = 0):
    """Fail in seconds, with what to do, instead of hours later: the profile must exist, the dataset
    must be readable (``modelnet10`` is downloaded first when missing; without a network that fails
    with the downloader's message), and a profile that ``needs_gpu`` (``full``) needs CUDA unless
    ``HBEO_ALLOW_CPU=1``. Returns the :class:`hbeo.run.Run` of ``training_seed`` (its folder ``out_dir``,
    by default :func:`hbeo.config.run_path`'s, created only then)."""
    from hbeo.errors import HBEOError, MissingDataError
    from hbeo.run import Run
    prof = config.get_profile(profile)
    if prof.needs_gpu and os.environ.get("HBEO_ALLOW_CPU") != "1":
        import torch
        if not torch.cuda.is_available():
            raise HBEOError(f"the {prof.name} profile trains the paper-sized network on millions of "
                            f"{prof.data.image_size[0]}x{prof.data.image_size[1]} images and needs a CUDA GPU; none is visible "
                            f"to torch (install the CUDA build of torch, or set HBEO_ALLOW_CPU=1 to run it on the "
                            f"CPU anyway: days)")
    try:
        return Run.open(prof, dataset, out_dir, training_seed=training_seed)
    except MissingDataError:
        if dataset != "modelnet10":
            raise
        print("[hbeo] ModelNet10 meshes missing: downloading (about 0.5 GB)", flush=True)
        return Run.open(prof, dataset, out_dir, training_seed=training_seed, download=True)
