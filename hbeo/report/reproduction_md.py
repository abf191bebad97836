"""``REPRODUCTION.md``: the paper's numbers beside a finished run's, with intervals, verdicts and every
deviation from the paper's setup.

:func:`write_reproduction` reads the run folder's manifest (:mod:`hbeo.report.provenance`) and
the tables and figures notebooks 04-07 wrote there (every path from :class:`hbeo.rundir.RunDir`), with the
paper's claims under each reading of the view protocol the run has evaluated (:mod:`hbeo.report.readings`) and
the spread over training seeds where ``report --seeds`` wrote it into the folder (:mod:`hbeo.report.seeds`), and
writes one Markdown file (atomically) that links into the run: nothing in it is typed by hand except
the list of deviations, whose figures come from the manifest. :func:`write_reports` is what ``python -m
hbeo reproduce`` calls after the last notebook: the run's own ``REPRODUCTION.md``, and for the
reference run (:data:`REFERENCE_RUN`) ``paper/REPRODUCTION.md`` as well.

The README's verdict on the reference run, its command table and the documentation's generated blocks are
:mod:`hbeo.report.readme`'s (its :func:`~hbeo.report.readme.write_summary` is the one ``python -m hbeo report
--readme`` calls, imported here).

May import: foundation and the other reproduction modules.
"""
from __future__ import annotations

import os
from pathlib import Path

from hbeo import config
from hbeo.errors import DataError
from hbeo.report import completion_gap, readings, seeds, tables as T
from hbeo.report.provenance import commit_line, reproduce_command
from hbeo.rundir import RunDir
from hbeo.storage import atomic_text, read_json

PAPER = config.REPO_ROOT / "paper"
#: (profile, dataset) of the committed reference run, whose report is ``paper/REPRODUCTION.md``.
REFERENCE_RUN = ("cpu", "modelnet10-vox30")


def write_reports(run, profile: str, dataset: str) -> list[Path]:
    """The run's ``REPRODUCTION.md``, and ``paper/REPRODUCTION.md`` too when ``run`` is the reference
    run in its default place. Returns the paths written."""
    run = RunDir.of(run)
    out = [write_reproduction(run, run.path / "REPRODUCTION.md")]
    if (profile, dataset) == REFERENCE_RUN and run.path.resolve() == config.run_path(*REFERENCE_RUN).resolve():
        out.append(write_reproduction(run, PAPER / "REPRODUCTION.md"))
    return out


def _read(path: Path) -> str:
    return path.read_text().strip() if path.exists() else f"*(missing: {path.name}; run the notebooks first)*"


def _timing(man: dict) -> list[str]:
    nbs = man.get("notebooks", {})
    if not nbs:
        return ["*(no notebook timings in the manifest)*"]
    rows = ["| notebook | wall time (min) | commit |", "| --- | ---: | --- |"]
    rows += [f"| {k} | {v['wall_s'] / 60:.1f} | `{(v.get('commit') or '?')[:10]}` |" for k, v in sorted(nbs.items())]
    rows.append(f"| **total** | **{man.get('wall_time_total_s', 0) / 60:.1f}** | |")
    return rows


def _training(man: dict) -> str:
    recs = man.get("training", {})
    if not recs:
        return "*(no training record in the manifest)*"
    parts = []
    for name, r in sorted(recs.items()):
        how = ("from scratch" if r.get("resumed_from_step") is None
               else f"**resumed** from the checkpoint at step {r['resumed_from_step']} of an interrupted run")
        parts.append(f"`{name}`: {r.get('epochs')} epochs, {how}" +
                     (f", {r['n_params']:,} parameters" if r.get("n_params") else ""))
    return "; ".join(parts) + "."


#: Datasets the deviations describe by name (:mod:`hbeo.data.datasets`); others get a generic line.
_DATASET_TEXT = {
    "modelnet10-vox30": "ModelNet10 as the published 30³ grids (3D ShapeNets layout, {test_text}). Depth images "
                        "are rendered from a smoothed surface of each grid, not from the meshes, so detail below a "
                        "voxel is missing from the inputs. `python -m hbeo voxelize --dataset modelnet10 --out FILE` "
                        "rebuilds the grid file from the meshes (docs/method.md, *Voxelization*).",
    "modelnet10": "ModelNet10's meshes, voxelized here to 30³ grids ({test_text}). Depth images are rendered "
                  "from a smoothed surface of each grid, not from the meshes.",
    "procedural": "Procedural objects (`hbeo.data.procedural`), not ModelNet10: {train} training and {test_run} "
                  "test objects in the paper's ten class names, generated as 30³ grids; the numbers measure the "
                  "method, not the paper's benchmark.",
}


def _class_counts(run) -> dict:
    """Totals of the run's class-count table (notebook 01): source and run objects per split, skipped."""
    import pandas as pd
    if run is None or not RunDir.of(run).table(T.CLASS_COUNTS).exists():
        return {}
    t = pd.read_csv(RunDir.of(run).table(T.CLASS_COUNTS), index_col=0)
    return {k: int(v) for k, v in t.loc["total"].items()} if "total" in t.index else {}


def _data_line(man: dict, counts: dict) -> str:
    p = man.get("profile_settings", {})
    train, test = counts.get("train"), counts.get("test")
    train_run, test_run = counts.get("train (run)", train), counts.get("test (run)", test)
    if test is None:
        test_text = "test objects: see notebook 01"
    elif p.get("n_test_per_class") is None:
        missing = test - test_run
        test_text = (f"all {test} test grids" if missing == 0 else
                     f"{test_run} of {test} test grids: {'one is' if missing == 1 else f'{missing} are'} empty")
    else:
        test_text = f"{test_run} of {test} test grids: the profile's {p['n_test_per_class']} per class"
    name = man.get("dataset", "?")
    text = _DATASET_TEXT.get(name, f"Dataset `{name}`: {{train_run}} training and {{test_run}} test objects "
                                   f"(not the paper's benchmark).")
    return "- **Data.** " + text.format(test_text=test_text, train=train, test=test, train_run=train_run,
                                        test_run=test_run)


def _so3_spacing_deg(n: int) -> float:
    """Mean nearest-neighbour angle (degrees) of BEO's super-Fibonacci search grid of ``n`` rotations."""
    import numpy as np
    from hbeo.rotations import geodesic_deg, super_fibonacci
    R, best = super_fibonacci(n), np.empty(n)
    for i in range(0, n, 128):
        d = geodesic_deg(R[i:i + 128, None], R[None])
        d[np.arange(len(d)), np.arange(i, i + len(d))] = np.inf
        best[i:i + 128] = d.min(1)
    return float(best.mean())


def _components(run) -> int | None:
    """Subspace components over all classes (notebook 02's ``02_components.csv``), or None."""
    import pandas as pd
    if run is None or not RunDir.of(run).table(T.COMPONENTS).exists():
        return None
    comp = pd.read_csv(RunDir.of(run).table(T.COMPONENTS), index_col=0)
    cols = [c for c in comp.columns if c.startswith("components")]
    return int(comp[cols[0]].sum()) if cols else None


def deviations(man: dict, run=None) -> list[str]:
    """Every difference between the run's setup and the paper's, with why: figures from the manifest and,
    where ``run`` (its folder) is given, from its dataset tables (notebooks 01 and 02)."""
    p = man.get("profile_settings", {})
    hw = man.get("hardware", {})
    main = man.get("training", {}).get("model.hbeo", {})
    size = "×".join(map(str, p.get("image_size", ["?"])))
    n_params = f"{main['n_params'] / 1e6:.2f} M" if main.get("n_params") else "fewer"
    paper = config.RecipeConfig(epochs=0, batch_size=0).fit_kwargs()     # the recipe's defaults are the paper's
    recipe = main.get("recipe") or {k: p[k] for k in paper if k in p}      # the model's record, else the profile's
    if recipe and "class_balance" not in recipe:          # recorded before class balance existed: none
        recipe = {**recipe, "class_balance": main.get("class_balance", "none")}
    balanced, mix = "", ""
    if recipe.get("class_balance", "none") != "none":
        balanced = f", class balance `{recipe['class_balance']}` (against the training split's class imbalance)"
        mix = ", the training split's class mix"
    if set(recipe) != set(paper):
        recipe_line = "- **Training recipe.** The run's manifest does not record the model's training recipe"
    elif recipe == paper:
        recipe_line = ("- **Training recipe.** The run's model uses the paper's recipe (axis-angle regression, no "
                       f"augmentation, coefficient loss), {p.get('epochs', '?')} epochs")
    else:
        recipe_line = (
            "- **Training recipe.** The run's model uses the recipe chosen on validation objects: "
            f"pose output `{recipe['rotation']}`, roll augmentation {'on' if recipe['augment_roll'] else 'off'}, "
            f"shape loss `{recipe['shape_loss']}`{balanced} (the paper: axis-angle regression, no augmentation, "
            f"coefficient loss{mix}). The paper's recipe is trained in notebook 04 for comparison ({p.get('option_epochs') or p.get('epochs')} "
            "epochs, validation objects)")
    why = ("the `full` profile is the paper's scale, on a GPU" if p.get("needs_gpu") else
           "the reproduction must finish on a 2-core machine (the `full` profile is the paper's scale, GPU only)")
    k = _components(run)
    comps = ("the run's component counts are in notebook 02" if k is None else
             f"on these grids that gives {k} components in all, {'fewer' if k < 344 else 'more'} than the paper's "
             "344 shared dimensions (notebook 02)")
    grid = p.get("beo_so3_grid")
    spacing = f", about {_so3_spacing_deg(int(grid)):.0f}° apart" if isinstance(grid, int) and grid > 1 else ""
    everyone = lambda n: "all" if n is None else f"the first {n}"     # noqa: E731
    return [
        f"- **Scale of training.** The paper trains on about 7 million 320×240 depth images on a GPU. Here: "
        f"{p.get('views_per_object', '?')} views of each training object at {size} pixels, {p.get('epochs', '?')} "
        f"epochs, on {hw.get('cores', '?')} CPU cores ({hw.get('cpu', '?')}, GPU: {hw.get('gpu') or 'none'}). "
        f"Why: {why}.",
        f"- **Network size.** HBEONet has {n_params} parameters at {size} input (convolutions "
        f"{p.get('conv_channels')}, fully connected {p.get('fc')}); at 320×240 the paper's design has about 15 M. "
        f"The layer pattern (four strided convolutions, three shared fully connected layers, three heads) is the paper's.",
        recipe_line + ". 10 % of each class's training objects are held out for validation (the paper trains on all).",
        _completion_line(run),
        *_resolution_line(run),
        "- **HBEO + verify** (rows marked *ours*) adds test-time roll averaging and a check of the network's top "
        "rotation hypotheses against the depth image (`hbeo.model.verify`); it is not in the paper and is "
        "reported beside, never instead of, HBEO.",
        _data_line(man, _class_counts(run)),
        f"- **Subspace.** Per-class VBPCA at 60 % of the variance, as in the paper; {comps}.",
        "- **BEO** is reimplemented (not the authors' Matlab). Its class-and-pose score adds the likelihood of the "
        "observed voxels to the paper's density (`score=\"joint\"`), and its partial projection has a small ridge "
        "term; both measured in `hbeo/baselines/beo.py` and benchmarks/README.md. Its 3-DOF search covers "
        f"{grid if grid is not None else '?'} rotations (a super-Fibonacci grid{spacing}).",
        f"- **Query counts.** BEO in 3-DOF and ICP answer view 0 of {everyone(p.get('beo_3dof_test_per_class'))} "
        f"and {everyone(p.get('icp_test_per_class'))} test objects per class (their pose searches take seconds per "
        f"query); their comparisons with HBEO use those pairs only. Every other method answers {p.get('eval_views')} "
        f"paired views of every test object.",
        "- **3DShapeNets** (a 2015 convolutional deep belief network) is not rerun: its Table I row is the paper's, "
        "and a 3-D CNN on the partial grid trained here (`hbeo.baselines.voxcnn`, "
        f"{p.get('voxcnn_epochs')} epochs) plays its role in the measured comparisons.",
        "- **Views.** Uniform random rotations over SO(3) at random distances, paired across methods (the paper "
        "does not state its test views). BEO and the 3-D CNN get the object's position and size (and rotation, "
        "for known pose), as in the paper.",
        "- **Totals.** The paper's HBEO total is the mean of its per-class accuracies; Table I shows that (*class "
        "mean*) and the share over all queries (*total*).",
        "- **Runtime** is measured where each evaluation ran (its file records the machine; the note under "
        "Table II names them, and the hardware above is where the models were trained), the paper's on a 4-core "
        "CPU with a GTX 1070 and Matlab baselines; ratios between methods are the comparable figures.",
    ]


def _completion_line(run) -> str:
    """The completion rule the run's HBEO evaluations used (the first line of its ``eval_hbeo_3dof.json``'s
    ``completion_rule``, absent: the paper's) and HBEO's default rule."""
    from hbeo.model.completion_rule import NONEMPTY, of_record
    path = RunDir.of(run).evaluation("hbeo", "3dof") if run is not None else None
    used = of_record(read_json(path, "metrics", dict).get("completion_rule")) if path and path.exists() else None
    head = ("- **Completion rule.** The paper keeps the voxels whose back-projection reaches 0.5, which can leave a "
            "completion empty. HBEO's default completes never empty (`hbeo.model.completion_rule`: back-projection "
            f">= {NONEMPTY.threshold:g}, a threshold chosen on validation, else the predicted class's mean-shape "
            "occupancy in top voxels); `--completion paper` gives the paper's rule, and an evaluation under the default "
            "scores the paper's rule beside (`completion_paper`). ")
    if used is None:
        return head + "This run's HBEO evaluation file is missing."
    if used.name == "paper":
        return head + ("This run's HBEO evaluations used the paper's rule (made before the default changed); the "
                       "never-empty rule on the same queries is in the completion section above, where computed.")
    return head + "This run's HBEO evaluations used the never-empty rule; the paper's is beside in each file."


#: the resolution study's validation files in the run folder: (image size, metrics file, paired file against 80x60)
RESOLUTION_FILES = (("80×60", "eval_val-basis143-e10.json", None),
                    ("120×90", "eval_val-res120-e10.json", "res120-e10_vs_basis143-e10_val.json"),
                    ("160×120", "eval_val-res160-e10.json", "res160-e10_vs_basis143-e10_val.json"))


def _entry(path: Path, *keys, kind=dict):
    """The value at ``keys`` in the JSON file ``path`` (a metrics or paired-comparison file), of type ``kind``;
    DataError naming the file when it is not valid JSON or lacks the entry."""
    value = read_json(path, "metrics")
    for k in keys:
        value = value.get(k) if isinstance(value, dict) else None
    if not isinstance(value, kind) or isinstance(value, bool):
        raise DataError(path, f"no {'.'.join(keys)} entry of the right type (not a metrics file of this hbeo?)")
    return value


def _resolution_line(run) -> list[str]:
    """The resolution study's deviation line, from its validation files (none: no line): the class mean at each
    image size after the same 10 epochs, the paired difference against 80x60 with its interval."""
    d = RunDir.of(run).path if run is not None else None
    if d is None or not all((d / f).exists() and (p is None or (d / p).exists()) for _, f, p in RESOLUTION_FILES):
        return []
    parts = []
    for size, f, paired in RESOLUTION_FILES:
        cm = 100 * _entry(d / f, "class_mean_accuracy", kind=(int, float))
        if paired is None:
            parts.append(f"{size} {cm:.1f} %")
            continue
        c = _entry(d / paired, "contrasts", "class_accuracy")
        parts.append(f"{size} {cm:.1f} % ({100 * c['value']:+.1f} points [{100 * c['low']:+.1f}, "
                     f"{100 * c['high']:+.1f}], {c['n_objects']} objects)")
    return ["- **Image size.** Is 80×60 the gap? The same recipe for 10 epochs at three sizes (the camera scaled, the "
            f"same views), validation class mean: {'; '.join(parts)}. Larger images scored lower at that budget, so "
            "80×60 stays (the model table's resolution rows and their rule, `docs/experiments.md`)."]


def check_finished_run(run) -> RunDir:
    """``run`` as a RunDir if it is a finished run folder: a folder whose ``manifest.json`` (written by
    ``python -m hbeo reproduce``) records the profile and the executed notebooks, each of them there. Else
    DataError naming the folder (or the manifest) and what is missing."""
    path = RunDir.of(run).path
    if not path.exists():
        raise DataError(path, "no such run folder")
    if not path.is_dir():
        raise DataError(path, "not a folder (expected a run folder, e.g. results/cpu-modelnet10-vox30)")
    run = RunDir.of(run)
    if not run.manifest.is_file():
        raise DataError(path, "not a finished run: no manifest.json (python -m hbeo reproduce writes it)")
    man = run.read_manifest()                   # not JSON, or an entry of another type: DataError naming it
    done = man.get("notebooks")
    if not isinstance(done, dict) or not done or not man.get("profile"):
        raise DataError(run.manifest, "records no executed notebook or no profile: not a finished run "
                                      "(python -m hbeo reproduce writes it)")
    missing = [f"{nb}.ipynb" for nb in done if not run.notebook(nb).is_file()]
    if missing:
        raise DataError(path, f"not a finished run: the manifest's executed notebooks are missing ({', '.join(missing)})")
    return run


def write_reproduction(run, out=None) -> Path:
    """The run's ``REPRODUCTION.md`` (or ``out``, e.g. ``paper/REPRODUCTION.md``) from a finished run folder
    (a RunDir or a path; ``python -m hbeo report`` checks it first, :func:`check_finished_run`): the text of
    :func:`reproduction_text`, written atomically. Returns the path written."""
    out = Path(out) if out else RunDir.of(run).path / "REPRODUCTION.md"
    atomic_text(out, reproduction_text(run, out))
    return out


def reproduction_text(run, out: Path) -> str:
    """The Markdown of ``REPRODUCTION.md`` for a file at ``out`` (links are relative to its folder)."""
    run = RunDir.of(run)
    out = Path(out)
    man = run.read_manifest()

    def link(path: Path) -> str:
        return os.path.relpath(path, out.parent)

    def fig(name: str, alt: str) -> str:
        return f"![{alt}]({link(run.figure(name))})" if run.figure(name).exists() else f"*(missing: {name}.png)*"

    rel = link(run.path)
    seed = int((man.get("seeds") or {}).get("training", 0))
    cmd = reproduce_command(run, man.get("profile"), man.get("dataset"), seed)
    lines = [
        "# Reproduction: reported vs. reproduced",
        "",
        f"Generated from the run in [`{rel}`]({rel}) by `{cmd}` (or `python -m hbeo report --run "
        f"{os.path.relpath(run.path, config.REPO_ROOT)}`): profile `{man.get('profile')}`, dataset "
        f"`{man.get('dataset')}`, training seed {seed}, {commit_line(man)}, code version `{man.get('code_version')}`. "
        f"Every number below "
        f"is read from a file of that folder; intervals are 95 % bootstrap intervals over test objects "
        f"(`hbeo.evaluation.paired`), n is given with each.",
        "",
        f"Training: {_training(man)}",
        "",
        *_timing(man),
        "",
        "## The paper's claims, judged by paired intervals",
        "",
        "*holds*: the whole interval of the claim's contrast lies on its side; *fails*: the whole interval on the "
        "other side; *inconclusive*: the interval straddles zero.",
        "",
        _read(run.table(T.CLAIMS, "md")),
        "",
        "## Table I: classification accuracy (%)",
        "",
        _read(run.table(T.ACCURACY_CI, "md")),
        "",
        "Per class, reported beside reproduced:",
        "",
        _read(run.table(T.TABLE1, "md")),
        "",
        fig("05_confusion", "confusion matrices"),
        "",
        "## Pose error (the paper's pose figure)",
        "",
        _read(run.table(T.POSE_CI, "md")),
        "",
        _read(run.table(T.POSE, "md")),
        "",
        fig("06_pose_error", "pose error distributions"),
        "",
        "## Completion error (the paper's completion figure)",
        "",
        _read(run.table(T.COMPLETION_CI, "md")),
        "",
        _read(run.table(T.COMPLETION, "md")),
        "",
        fig("06_completion", "completion errors"),
        "",
        fig("06_gallery", "completion gallery"),
        "",
        *completion_gap.section(run, man),
        *([fig(completion_gap.NAME, "the completion error taken apart"), ""]
          if run.figure(completion_gap.NAME).exists() else []),
        "## Table II: runtime per query",
        "",
        _read(run.table(T.TABLE2, "md")),
        "",
        fig("07_runtime", "runtime"),
        "",
        *readings.section(run, man),
        *seeds.section(run, man),
        "## Options trained in the run (notebook 04, validation objects)",
        "",
        _read(run.table(T.OPTIONS, "md")),
        "",
        "## Deviations from the paper",
        "",
        *deviations(man, run),
        "",
    ]
    return "\n".join(lines)


from hbeo.report.readme import write_summary  # noqa: E402,F401  (``report --run RUN --readme FILE``)
