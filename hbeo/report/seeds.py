"""The spread over training seeds: runs of one profile and dataset whose models were trained with
different seeds (``python -m hbeo reproduce --seed S``), set side by side in one table.

A run's figure is uncertain in two ways: which test objects happened to be drawn (its 95 % interval
over objects, :mod:`hbeo.evaluation.intervals`) and how its training happened to go (initial weights,
batch order, augmentation: the training seed, :attr:`hbeo.run.Run.training_seed`). :func:`seed_table`
reads the metrics files ``eval_<method>_<pose>.json`` (:meth:`hbeo.rundir.RunDir.evaluation`) that every
run holds and gives, for each method and measure (:data:`MEASURES`), each seed's figure with its interval
over objects, and the mean, sample standard deviation and range over the seeds. The seeds must be
paired, every run scoring the very same test images: it refuses (DataError naming the file and the
problem) a folder without a run manifest, runs of another profile or dataset, a training seed given
twice, and an evaluation of other test images than the first run's (another dataset, split, views, view
seed, sampler, noise, objects per class, or other (object, view) pairs). :func:`seed_claims` judges the
paper's claims (:func:`hbeo.report.tables.claims`, as notebook 06 does) on each run's own evaluations and
gives each seed's verdict and contrast, and how many seeds each verdict got. :func:`write_seed_table` writes
both, ``seeds_table.csv``/``.md`` (:data:`hbeo.report.tables.SEEDS`) and ``seeds_claims.csv``/``.md``
(:data:`hbeo.report.tables.SEEDS_CLAIMS`), by default into the first run's folder (``python -m hbeo report
--seeds RUN RUN ...``), whose ``REPRODUCTION.md`` then shows them (:func:`section`) while they still agree
with that run's own evaluation files.

May import: foundation, :mod:`hbeo.evaluation` and the other report modules.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from hbeo import config
from hbeo.errors import DataError, HBEOError
from hbeo.evaluation.intervals import intervals
from hbeo.evaluation.method import label
from hbeo.evaluation.paired import LEVEL, N_BOOT, NOT_COMPARABLE
from hbeo.evaluation.protocol import COMPLETION, EVALUATIONS, POSE, TABLE1
from hbeo.report import tables
from hbeo.rundir import RunDir
from hbeo.storage import read_json


#: statistic of :data:`hbeo.evaluation.intervals.STATISTICS` -> (what the table calls it, the settings
#: (method, pose) it applies to: those of the notebooks' Table I, pose figure and completion figure,
#: shown as a percentage)
MEASURES = {
    "class_mean": ("class mean accuracy", TABLE1, True),
    "accuracy": ("accuracy", TABLE1, True),
    "lowest_class": ("lowest class accuracy", TABLE1, True),
    "within_30": ("within 30°", POSE, True),
    "within_30_sym": ("within 30° modulo symmetry", POSE, True),
    "iou": ("mean IoU", COMPLETION, False),
}
#: What must agree between two runs' evaluations of one setting for them to score the same test images:
#: the metrics dict's own fields, and those of its cache key (``request``, :func:`hbeo.evaluation.protocol.request`).
PAIRING = ("dataset", "split", "views", "seed", "sampler", "noise", "noise_scale")
REQUEST_PAIRING = {"per_class": "objects per class", "dataset_fingerprint": "dataset fingerprint"}


@dataclass(frozen=True)
class SeedRun:
    """A run folder as its manifest describes it."""

    dir: RunDir
    profile: str
    dataset: str
    training_seed: int


def read_run(run) -> SeedRun:
    """The profile, dataset and training seed (``seeds.training``) of run folder ``run`` from its
    ``manifest.json`` (:mod:`hbeo.report.provenance`); DataError naming the manifest when there is none
    or it does not say."""
    run = RunDir.of(run)
    if not run.manifest.is_file():
        raise DataError(run.manifest, "missing: not a run folder of python -m hbeo reproduce (its manifest "
                                      "names the profile, dataset and training seed)")
    man = run.read_manifest()                  # not JSON, or an entry of the wrong type: DataError naming it
    seed = man.get("seeds", {}).get("training")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0 or not man.get("profile") \
            or not man.get("dataset"):
        raise DataError(run.manifest, "records no profile, dataset or training seed (seeds.training)")
    return SeedRun(run, str(man["profile"]), str(man["dataset"]), seed)


def _check_runs(runs: list[SeedRun]) -> None:
    first = runs[0]
    seen = {}
    for r in runs:
        if (r.profile, r.dataset) != (first.profile, first.dataset):
            raise DataError(r.dir.manifest, f"profile {r.profile}, dataset {r.dataset}; {first.dir.path} is profile "
                                            f"{first.profile}, dataset {first.dataset}: a seed table compares runs "
                                            f"of one profile and dataset")
        if r.training_seed in seen:
            raise DataError(r.dir.manifest, f"training seed {r.training_seed} again ({seen[r.training_seed]} has "
                                            f"it too): a seed table takes one run per training seed")
        seen[r.training_seed] = r.dir.path


def _evaluation(run: SeedRun, method: str, pose: str) -> dict:
    path = run.dir.evaluation(method, pose)
    m = read_json(path, "metrics")
    if not isinstance(m, dict) or not (m.get("per_query") or {}).get("object"):
        raise DataError(path, "no per-query object ids (a file older than the paired protocol): evaluate again")
    return m


def _pairing(m: dict) -> dict:
    req = m.get("request") or {}
    return {**{k: m.get(k) for k in PAIRING}, **{name: req.get(k) for k, name in REQUEST_PAIRING.items()}}


def _pairs(m: dict) -> set:
    q = m["per_query"]
    return set(zip(q["class"], q["object"], q["view"]))


def _check_paired(path: Path, m: dict, first_path: Path, first: dict) -> None:
    a, b = _pairing(m), _pairing(first)
    if diff := [f"{k} {a[k]!r} here, {b[k]!r} there" for k in a if a[k] != b[k]]:
        raise DataError(path, f"scores other test images than {first_path} ({'; '.join(diff)}): the seeds of a "
                              f"seed table must be evaluated on the same images")
    pa, pb = _pairs(m), _pairs(first)
    if pa != pb:
        raise DataError(path, f"scores other (object, view) pairs than {first_path} ({len(pa)} here, {len(pb)} "
                              f"there, {len(pa & pb)} in both): the seeds of a seed table must be evaluated on "
                              f"the same images")


def _read_runs(runs) -> list[SeedRun]:
    """The runs (:func:`read_run`), checked to make one seed table, in the order of their training seeds."""
    runs = list(runs)
    if len(runs) < 2:
        raise HBEOError(f"a seed table needs at least 2 run folders, one per training seed; got {len(runs)}"
                        + (f" ({runs[0]})" if runs else ""))
    read = [read_run(r) for r in runs]
    _check_runs(read)
    return sorted(read, key=lambda r: r.training_seed)


def _load(runs) -> tuple[list[SeedRun], dict[tuple, list[dict]]]:
    """The runs (:func:`_read_runs`) and, for each setting of :data:`~hbeo.evaluation.protocol.EVALUATIONS` whose
    metrics file every run holds, its metrics in every run, checked to score the first run's test images
    (DataError naming the file that does not, or the first run's folder when no setting is common)."""
    found = _read_runs(runs)
    settings = [k for k in EVALUATIONS if all(r.dir.evaluation(*k).is_file() for r in found)]
    if not settings:
        raise DataError(found[0].dir.path, "no eval_<method>_<pose>.json that every run of the seed table holds "
                                           "(run the notebooks 04-07 in each)")
    loaded = {}
    for key in settings:
        evals = loaded[key] = [_evaluation(r, *key) for r in found]
        for r, m in zip(found[1:], evals[1:]):
            _check_paired(r.dir.evaluation(*key), m, found[0].dir.evaluation(*key), evals[0])
    return found, loaded


def seed_table(runs, n_boot: int = N_BOOT, level: float = LEVEL) -> pd.DataFrame:
    """One row per evaluated setting (method, pose) and measure (:data:`MEASURES`) that applies to it, over
    the run folders ``runs`` (at least 2; one profile and dataset, one per training seed, checked, see the
    module docstring), runs in the order of their seeds: ``method``, ``pose``, ``label``, ``statistic``,
    ``measure``, ``seeds`` (how many), ``mean``, ``sd`` (sample standard deviation, n - 1), ``min``, ``max``
    of the seeds' figures, then for each seed S ``seed S`` (its figure) and ``seed S low``, ``seed S high``
    (its interval at ``level`` over test objects, ``n_boot`` resamples, :func:`hbeo.evaluation.intervals.intervals`).
    Figures are fractions (an IoU for ``iou``). The settings are those of
    :data:`hbeo.evaluation.protocol.EVALUATIONS` whose metrics file every run holds."""
    return _table(*_load(runs), n_boot, level)


def _table(found: list[SeedRun], loaded: dict, n_boot: int, level: float) -> pd.DataFrame:
    """:func:`seed_table` of what :func:`_load` read."""
    rows = []
    for key, evals in loaded.items():
        stats = [s for s, (_, applies, _) in MEASURES.items() if key in applies]
        if not stats:
            continue
        per_seed = [intervals(m, stats, n_boot=n_boot, level=level) for m in evals]
        for s in stats:
            v = np.array([p[s][0] for p in per_seed])
            row = {"method": key[0], "pose": key[1], "label": label(evals[0]), "statistic": s,
                   "measure": MEASURES[s][0], "seeds": len(v), "mean": float(v.mean()), "sd": float(v.std(ddof=1)),
                   "min": float(v.min()), "max": float(v.max())}
            for r, p in zip(found, per_seed):
                t = r.training_seed
                row[f"seed {t}"], row[f"seed {t} low"], row[f"seed {t} high"] = p[s]
            rows.append(row)
    return pd.DataFrame(rows)


#: The verdicts of :func:`hbeo.evaluation.paired.judge`, in the order :func:`seed_claims` counts them.
VERDICTS = ("holds", "inconclusive", "fails", NOT_COMPARABLE)


def seed_claims(runs) -> pd.DataFrame:
    """The paper's claims judged on each run of ``runs`` (checked as for :func:`seed_table`) by its own
    evaluations (:func:`hbeo.report.tables.claims` of the settings every run holds: notebook 06's claims
    table, each of :data:`hbeo.report.tables.PLAYERS` playing HBEO): a row per (player, claim) judged in
    some run, with ``claim (paper)``, ``HBEO played by``, a column ``seed S`` per run ("**verdict**:
    contrast [low, high]", the contrast's paired 95 % interval over that run's test objects; "–" where the
    run could not judge it) and ``verdicts`` (how many seeds gave each verdict, e.g. "fails 3 of 3")."""
    return _claims(*_load(runs))


def _claims(found: list[SeedRun], loaded: dict) -> pd.DataFrame:
    """:func:`seed_claims` of what :func:`_load` read."""
    judged = [tables.claims({key: evals[i] for key, evals in loaded.items()}) for i in range(len(found))]
    order = list(dict.fromkeys(i for j in judged for i in j.index))
    rows = []
    for idx in order:
        first = next(j.loc[idx] for j in judged if idx in j.index)
        row = {"claim (paper)": first["claim (paper)"], "HBEO played by": first["HBEO played by"]}
        got = []
        for r, j in zip(found, judged):
            if idx in j.index:
                got.append(j.loc[idx, "verdict"])
                row[f"seed {r.training_seed}"] = f"**{got[-1]}**: {j.loc[idx, 'contrast (claim: < 0)']}"
            else:
                row[f"seed {r.training_seed}"] = "–"
        row["verdicts"] = ", ".join(f"{v} {got.count(v)} of {len(found)}" for v in VERDICTS if v in got)
        rows.append(row)
    return pd.DataFrame(rows)


def markdown_view(table: pd.DataFrame) -> pd.DataFrame:
    """:func:`seed_table` to read: per row the method, the measure (with its unit), each seed's figure
    "value [low, high]", "mean ± sd" and "min – max" (percentages to 0.1, IoU to 0.001)."""
    seeds = [c for c in table.columns if c.startswith("seed ") and not c.endswith((" low", " high"))]
    out = []
    for _, r in table.iterrows():
        pct = MEASURES[r["statistic"]][2]
        scale, f = (100, "{:.1f}") if pct else (1, "{:.3f}")

        def num(x):
            return f.format(scale * x)
        row = {"method": r["label"], "measure": r["measure"] + (" (%)" if pct else "")}
        row.update({c: f"{num(r[c])} [{num(r[c + ' low'])}, {num(r[c + ' high'])}]" for c in seeds})
        row["mean ± sd"] = f"{num(r['mean'])} ± {num(r['sd'])}"
        row["min – max"] = f"{num(r['min'])} – {num(r['max'])}"
        out.append(row)
    return pd.DataFrame(out)


def write_seed_table(runs, out=None, n_boot: int = N_BOOT, level: float = LEVEL) -> tuple[Path, ...]:
    """:func:`seed_table` of ``runs`` written as ``seeds_table.csv`` (numbers) and ``seeds_table.md``
    (:func:`markdown_view`, with a note naming the runs), and :func:`seed_claims` as ``seeds_claims.csv`` and
    ``.md``, into the folder ``out`` (default: the first run folder given), atomically
    (:func:`hbeo.report.tables.save_table`). Returns the four paths."""
    runs = list(runs)
    found, loaded = _load(runs)
    table = _table(found, loaded, n_boot, level)
    which = (f"{len(found)} runs of profile {found[0].profile} on {found[0].dataset}, one per training seed: "
             + ", ".join(f"`{r.dir.name}` (seed {r.training_seed})" for r in found) + ". ")
    note = (f"\n\n{which}Each seed's figure with its {level * 100:g} % interval over test objects (bootstrap over "
            f"the objects of the whole split, {n_boot} resamples); every run scored the same test images. Mean ± "
            f"sample standard deviation (n − 1) and range over the seeds.\n")
    claims_note = (f"\n\n{which}Each claim judged on each run's own evaluations as notebook 06 judges them (the "
                   f"contrast's paired 95 % interval over that run's test objects; *holds*: the whole interval on the "
                   f"claim's side, *fails*: on the other, *inconclusive*: it straddles zero).\n")
    folder = out if out is not None else runs[0]
    return (*tables.save_table(table, folder, tables.SEEDS, markdown=markdown_view(table), note=note),
            *tables.save_table(_claims(found, loaded), folder, tables.SEEDS_CLAIMS, note=claims_note))


def stale(run, seed: int) -> str | None:
    """Why the seed table in run folder ``run`` (of training seed ``seed``) does not describe that run's own
    evaluations, or None when every figure of its ``seed S`` column is the point estimate of the run's file
    of that setting (the run was evaluated again after ``report --seeds``, or the table was written there
    from other runs: then it is not shown)."""
    run = RunDir.of(run)
    try:
        t = pd.read_csv(run.table(tables.SEEDS))
    except (OSError, ValueError) as err:
        return f"{run.table(tables.SEEDS).name} unreadable ({type(err).__name__})"
    col = f"seed {seed}"
    if col not in t.columns:
        return f"it has no column for this run's training seed {seed}"
    for (method, pose), rows in t.groupby(["method", "pose"], sort=False):
        path = run.evaluation(method, pose)
        try:
            m = json.loads(path.read_text())
            est = intervals(m, list(rows["statistic"]), n_boot=1)
        except (OSError, ValueError, KeyError, TypeError):
            return f"{path.name} is missing or unreadable"
        for _, r in rows.iterrows():
            if not np.isclose(r[col], est[r["statistic"]][0], rtol=0, atol=1e-9):
                return f"its {r['statistic']} of {method} ({pose}) is not {path.name}'s"
    return None


def spread(run, man: dict) -> tuple[list[str], list[dict]]:
    """The spread over training seeds of run folder ``run`` (``man``: its manifest), from ``seeds_table.csv`` and
    ``seeds_claims.csv`` when they describe this run (:func:`stale`), else ``([], [])``: the seeds' names and,
    for each HBEO row (HBEO and its extensions), its ``label``, ``method``, ``pose``, the class-mean accuracy's
    ``mean``, sample ``sd``, ``min`` and ``max`` over the seeds (fractions) and, of the paper's claims judged with
    it, how many ``hold`` and ``fail`` on every seed, how many ``differ`` between seeds, of ``claims``."""
    run = RunDir.of(run)
    seed = (man.get("seeds") or {}).get("training", 0)
    if not run.table(tables.SEEDS).is_file() or not run.table(tables.SEEDS_CLAIMS).is_file() or stale(run, seed):
        return [], []
    t = pd.read_csv(run.table(tables.SEEDS))
    cm = t[t["method"].str.startswith("hbeo") & (t["statistic"] == "class_mean")]     # HBEO and its extensions
    cl = pd.read_csv(run.table(tables.SEEDS_CLAIMS))
    names = [c[len("seed "):] for c in t.columns if c.startswith("seed ") and not c.endswith(("low", "high"))]
    n = len(names)
    rows = []
    for _, r in cm.iterrows():
        g = cl[cl["HBEO played by"] == r["label"]]
        every = {v: int((g["verdicts"] == f"{v} {n} of {n}").sum()) for v in ("holds", "fails")}
        rows.append({"label": r["label"], "method": r["method"], "pose": r["pose"], "mean": float(r["mean"]),
                     "sd": float(r["sd"]), "min": float(r["min"]), "max": float(r["max"]), "hold": every["holds"],
                     "fail": every["fails"], "differ": len(g) - every["holds"] - every["fails"], "claims": len(g)})
    return names, rows


def section(run, man: dict) -> list[str]:
    """The lines of ``REPRODUCTION.md``'s section on the spread over training seeds for run folder ``run``
    (``man``: its manifest): the seed table and the claims per seed when the folder holds them and they agree
    with its evaluations (:func:`stale`), else what is missing and the commands that make it."""
    run = RunDir.of(run)
    seed = (man.get("seeds") or {}).get("training", 0)
    lines = ["## The spread over training seeds", ""]
    where = os.path.relpath(run.path, config.REPO_ROOT)
    base = where[:-len(f"-seed{seed}")] if seed and where.endswith(f"-seed{seed}") else where
    make = (f"`make reproduce PROFILE={man.get('profile')} DATASET={man.get('dataset')} SEED=S` for seeds 1 and 2, "
            f"then `python -m hbeo report --seeds {base} {base}-seed1 {base}-seed2`")
    if not run.table(tables.SEEDS, "md").is_file() or not run.table(tables.SEEDS_CLAIMS, "md").is_file():
        return lines + [f"This run has not been repeated with other training seeds here, so its figures carry "
                        f"intervals over test objects only; {make} puts every figure's spread over the seeds and each "
                        f"claim's verdict per seed here.", ""]
    why = stale(run, seed)
    if why:
        return lines + [f"`{tables.SEEDS}.md` in this folder does not describe this run's evaluations ({why}): not "
                        f"shown; {make} writes it again.", ""]
    return lines + ["The run made again with other training seeds (`python -m hbeo reproduce --seed S`: HBEONet, "
                    "its options and the 3-D CNN trained with seed S; data, subspace, renderings and test views keep "
                    "seed 0, so every run scores the same test images, and the methods that train nothing give the "
                    "same figures in each): each figure per seed with its interval over test objects, and the "
                    "spread over the seeds.", "", run.table(tables.SEEDS, "md").read_text().strip(), "",
                    "The paper's claims, judged on each seed's run:", "",
                    run.table(tables.SEEDS_CLAIMS, "md").read_text().strip(), ""]
