"""Provenance of a run: the run folder's ``manifest.json`` (:attr:`hbeo.rundir.RunDir.manifest`).

It records the profile and its settings, the dataset, the git commit and tag, whether the working
tree had uncommitted changes outside ``results/`` (the run writes there), the code version of the
evaluations (:func:`hbeo.evaluation.protocol.code_version`), package versions, this machine's
hardware (:func:`hbeo.machine.hardware`), the seeds (``seeds.training``: the run's training seed, 0 unless
``python -m hbeo reproduce --seed`` asked for another; evaluation and rendering always :data:`SEED`),
for every notebook its wall time and the commit it ran at, how each model of the run was trained (from
scratch, or resumed from a checkpoint of an interrupted run: ``train_*/provenance.json``) and the
command line. Written atomically; each update merges the
notebooks into those already recorded.

May import: foundation and :mod:`hbeo.evaluation.protocol`.
"""
from __future__ import annotations

import platform
import subprocess
import sys
from datetime import datetime, timezone
from pathlib import Path

from hbeo import __version__
from hbeo import config
from hbeo.evaluation.protocol import SEED
from hbeo.machine import hardware
from hbeo.rundir import RunDir
from hbeo.storage import atomic_text, json_text, read_json

#: The packages whose versions a manifest records (beside Python and hbeo).
PACKAGES = ("numpy", "scipy", "torch", "trimesh", "scikit-learn", "scikit-image", "pandas", "matplotlib",
            "embreex", "pyrender", "papermill")


def _git(*args) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=config.REPO_ROOT, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


def versions() -> dict:
    """Python, hbeo and :data:`PACKAGES` versions (None for a package that is not installed)."""
    from importlib import metadata
    out = {"python": platform.python_version(), "hbeo": __version__}
    for n in PACKAGES:
        try:
            out[n] = metadata.version(n)
        except metadata.PackageNotFoundError:
            out[n] = None
    return out


def git_state(exclude=("results",)) -> dict:
    """``git_commit``, ``git_tag`` (a tag exactly at it, or None) and ``git_dirty`` (uncommitted changes
    to tracked files outside the folders ``exclude``, by default ``results/``; None without git)."""
    dirty = _git("status", "--porcelain", "--untracked-files=no", "--", ".", *(f":(exclude){d}" for d in exclude))
    return {"git_commit": _git("rev-parse", "HEAD"), "git_tag": _git("describe", "--tags", "--exact-match") or None,
            "git_dirty": bool(dirty) if dirty is not None else None}


def training_records(run) -> dict:
    """{model file: how it was trained} from the run's ``train_*/provenance.json``
    (:meth:`hbeo.run.Run.train`)."""
    out = {}
    for p in RunDir.of(run).training_provenances():
        rec = read_json(p, "training record", dict)
        out[rec.get("model", p.parent.name)] = rec
    return out


#: the notebook that trains a run's models: the manifest's ``hardware`` is the machine it last ran on
TRAINING_NOTEBOOK = "04_train"


def write_manifest(run, profile: str, dataset: str, wall_s: dict | None = None, fresh: bool = False,
                   training_seed: int = 0) -> dict:
    """Create or update the run's ``manifest.json`` (atomically); ``wall_s`` {notebook: seconds} is
    merged into the notebooks already there, each with the commit it ran at and its machine's ``cpu`` and
    ``cpu_capability`` (``fresh``: forget the notebooks of earlier runs); ``training_seed``: the seed the run's
    models were trained with (:attr:`hbeo.run.Run.training_seed`). ``hardware`` is the machine that trained the
    run's models: this one when the update runs :data:`TRAINING_NOTEBOOK` (or starts the manifest), else the one
    recorded before. ``run``: a RunDir or a path. Returns the manifest."""
    from hbeo.evaluation.protocol import code_version
    run = RunDir.of(run)
    old = {} if fresh else run.read_manifest()          # not JSON or a wrong type: DataError naming it
    git, hw = git_state(), hardware()
    nbs = dict(old.get("notebooks", {}))
    for name, sec in (wall_s or {}).items():
        nbs[name] = {"wall_s": sec, "commit": git["git_commit"], "dirty": git["git_dirty"],
                     "finished_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
                     "cpu": hw.get("cpu"), "cpu_capability": hw.get("cpu_capability")}
    if old.get("hardware") and TRAINING_NOTEBOOK not in (wall_s or {}):
        hw = old["hardware"]                        # the models were trained there, not here
    m = {"profile": profile, "dataset": dataset, "profile_settings": config.get_profile(profile).to_dict(),
         **git, "code_version": code_version(), "versions": versions(), "hardware": hw,
         "seeds": {"training": int(training_seed), "evaluation": SEED, "rendering": SEED},
         "notebooks": nbs, "training": training_records(run),
         "one_commit": len({n["commit"] for n in nbs.values()}) <= 1 and not any(n["dirty"] for n in nbs.values()),
         "updated": datetime.now(timezone.utc).isoformat(timespec="seconds"), "command": " ".join(sys.argv)}
    m["wall_time_total_s"] = round(sum(n["wall_s"] for n in nbs.values()), 1)
    atomic_text(run.manifest, json_text(m, indent=1))
    return m


def commit_line(man: dict) -> str:
    """Where a run came from, by commit (never by tag: a clone has none), from its manifest ``man``: the
    commit's first 10 hex digits in backticks and whether the tree was clean, or each commit when its notebooks
    ran at different ones."""
    nbs = man.get("notebooks", {})
    commits = sorted({n.get("commit") or "?" for n in nbs.values()})
    clean = not any(n.get("dirty") for n in nbs.values())
    where = (f"commit `{commits[0][:10]}`" if len(commits) == 1
             else "commits " + ", ".join(f"`{c[:10]}`" for c in commits) + " (notebooks at different commits)")
    return f"{where}, {'clean tree' if clean else 'uncommitted changes outside results/'}"


def reproduce_command(run, profile: str, dataset: str, training_seed: int = 0, resume: bool = False) -> str:
    """The command that makes the run folder ``run`` afresh, or with ``resume`` goes on with it (finished stages
    read, training from its checkpoint): ``make reproduce PROFILE= DATASET=`` (``SEED=`` for a training seed other
    than 0; ``RESUME=1``) where the folder is the one ``make`` uses, else ``python -m hbeo reproduce ... --out``
    (``--fresh`` unless ``resume``) with the folder, relative to the repository root when inside it."""
    path = Path(RunDir.of(run).path).resolve()
    if path == config.run_path(profile, dataset, None, training_seed).resolve():
        return (f"make reproduce PROFILE={profile} DATASET={dataset}" + (f" SEED={training_seed}" if training_seed else "")
                + (" RESUME=1" if resume else ""))
    root = Path(config.REPO_ROOT).resolve()
    out = path.relative_to(root) if path.is_relative_to(root) else path
    return (f"python -m hbeo reproduce --profile {profile} --dataset {dataset}"
            + (f" --seed {training_seed}" if training_seed else "") + ("" if resume else " --fresh") + f" --out {out}")
