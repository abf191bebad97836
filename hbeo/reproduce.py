"""Run the numbered notebooks with papermill; executed copies go into the run folder."""
from __future__ import annotations

from pathlib import Path

from . import config

NOTEBOOKS = config.REPO_ROOT / "notebooks"


def notebooks(only=None) -> list[Path]:
    """The numbered notebooks (``NN_name.ipynb``) in order, optionally filtered by name prefix."""
    nbs = sorted(p for p in NOTEBOOKS.glob("[0-9][0-9]_*.ipynb"))
    if only:
        nbs = [p for p in nbs if any(p.name.startswith(o) for o in only)]
    return nbs


def run_notebooks(profile: str = "cpu", dataset: str = "procedural", out_dir=None, only=None) -> list[Path]:
    """Execute notebooks in order with parameters ``profile``, ``dataset``, ``out_dir``.

    Each executed copy is written to ``<run dir>/<notebook name>``; the first failing
    notebook stops the run (papermill raises, and the failing copy shows where).
    """
    import papermill as pm
    config.get_profile(profile)  # fail fast on a bad name
    run = config.run_dir(profile, dataset, out_dir)
    done = []
    for nb in notebooks(only):
        target = run / nb.name
        print(f"[hbeo] {nb.name} (profile={profile}, dataset={dataset}) -> {target}", flush=True)
        pm.execute_notebook(str(nb), str(target), cwd=str(NOTEBOOKS),
                            parameters={"profile": profile, "dataset": dataset, "out_dir": str(run)},
                            progress_bar=False)
        done.append(target)
    return done
