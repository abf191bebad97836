"""The paper's claims under each reading of the view protocol: a section of ``REPRODUCTION.md``.

The paper's views are "multiple random viewpoints"; each sampler of :data:`hbeo.render.poses.SAMPLERS` is
one reading of those words. A run's evaluations under its model's own sampler (the *main reading*) are
``eval_<method>_<pose>.json``, under another reading ``eval_<method>_<pose>_<sampler>.json``
(:meth:`hbeo.rundir.RunDir.evaluation`; written by :func:`hbeo.evaluation.protocol.readings`,
``scripts/readings.sh``). :func:`run_readings` reads what the run folder holds, reading by reading, and
:func:`section` writes the section: the main reading and the documentation's argument for it
(``docs/method.md``), each reading's files, and, once another reading than the main one has files, one table
of the claims (:func:`hbeo.report.tables.claims` of each reading's evaluations, a column per reading with
files) and a
Table I block per reading (class-mean accuracy and accuracy with intervals,
:func:`hbeo.evaluation.paired.estimates` as notebook 05 shows them). What a reading lacks is marked *not
evaluated* with the command that evaluates it; a reading without files is listed, never an error. With the
main reading alone the section adds no table: its claims and Table I are the report's sections above, read
from the notebooks' tables (``06_claims``, ``05_accuracy_ci``), which the main column would repeat.

A file is used under its reading only if it records that reading (its ``sampler``) and, where the main
reading's file of the same setting (else the main HBEO file) records its request, the same dataset,
model file and seed, and for the same setting the same objects: a file left from another model is listed as
stale, not compared. Its baseline file (``baseline_sha256``) may be another than the main reading's when every
file of that baseline under the reading shares it: a fit of the same training grids, recipe and seed made again
can differ in its last bits (VBPCA's subspace and the class densities scikit-learn's EM fits in it need not be
bit-identical on another CPU or BLAS), and the hash does not say how far. Such a reading is used and marked
(:attr:`Reading.refit`, † in the claims table), and the note under the table measures how far: that fit against
the main reading's on the main reading's own queries, from the run's ``refit-<sha>/`` folder
(:func:`refit_folder`; ``scripts/refit.py`` makes it), query by query: the class answers that differ and paired
contrasts of the statistics the claims read; or it says the folder is missing, and the command that makes it.

May import: foundation, :mod:`hbeo.evaluation` and the other report modules.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field

import pandas as pd

from hbeo import config
from hbeo.evaluation import paired
from hbeo.evaluation.method import LABELS, label
from hbeo.evaluation.protocol import EVALUATIONS, TABLE1
from hbeo.render.poses import SAMPLER_HELP, SAMPLERS
from hbeo.report import tables as T
from hbeo.rundir import RunDir

TITLE = "The paper's claims under each reading of the view protocol"
#: ``scripts/readings.sh``'s interpreter default, and the variable that restricts its settings.
SCRIPT, PY, METHODS = "scripts/readings.sh", ".venv/bin/python", "METHODS"
#: The project's main reading and the documentation's argument for it (docs/method.md, "Readings of the view
#: protocol"), quoted:
#: ``tests/test_readings_report.py`` checks every sentence is the page's.
MAIN = "so3"
ARGUMENT = ("The paper estimates a full 3-DOF pose (its 3-element axis-angle output), calls the objects' orientation "
            "unknown, and states no restriction on the viewpoints; uniform over SO(3) is the distribution that assumes "
            "nothing about orientation, and the only one of the four under which every 3-DOF pose the network can "
            "output is a pose it may be asked for. `upright` and `floor` are defensible readings of a robot's setting "
            "and are reported beside it, not instead of it.")
#: What a reading's file must share with the main reading's: with any main file, with that of its own setting.
SAME_RUN, SAME_SETTING = ("dataset_fingerprint", "model_sha256", "seed"), ("per_class", "views")
#: The request key of a setting's baseline file; a reading may use another fit (see the module docstring).
BASELINE = "baseline_sha256"
#: The script that evaluates the main reading's settings with a baseline fitted again on this machine.
REFIT_SCRIPT = "scripts/refit.py"
#: The statistics the note compares between two fits (those the claims read), and the mark of a refit cell.
REFIT_STATS, MARK = ("accuracy", "pose_mean", "edt_mean"), "†"


@dataclass
class Reading:
    """One reading's evaluations in a run folder: ``evals`` {(method, pose): metrics} of the files used,
    ``stale`` {(method, pose): which file there was not used, and why}, ``refit`` {(method, pose): (its baseline
    file's sha256, the main reading's)} of the files used with another fit of their baseline."""
    sampler: str
    main: bool
    evals: dict = field(default_factory=dict)
    stale: dict = field(default_factory=dict)
    refit: dict = field(default_factory=dict)

    @property
    def missing(self) -> list[tuple]:
        """The settings of :data:`~hbeo.evaluation.protocol.EVALUATIONS` without a usable file."""
        return [k for k in EVALUATIONS if k not in self.evals]


def _read(path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def main_sampler(plain: dict) -> str | None:
    """The reading the main files ``plain`` ({(method, pose): metrics}) record: the model's training sampler;
    None when none records one. ValueError when they disagree."""
    found = {m["sampler"] for m in plain.values() if m.get("sampler")}
    if len(found) > 1:
        raise ValueError(f"the run's eval_<method>_<pose>.json files record different samplers {sorted(found)}")
    return found.pop() if found else None


def _stale(m: dict, sampler: str, ref: dict | None, same_setting: bool) -> str | None:
    """Why metrics ``m`` found under reading ``sampler`` cannot be compared with the main reading's ``ref``."""
    if m.get("sampler") != sampler:
        return f"records sampler {m.get('sampler')!r}"
    a, b = m.get("request") or {}, (ref or {}).get("request") or {}
    for key in SAME_RUN + (SAME_SETTING if same_setting else ()):
        if key in a and key in b and a[key] != b[key]:
            return f"another {key.replace('_', ' ')} ({a[key]}; the main reading's: {b[key]})"
    return None


def run_readings(run, settings=EVALUATIONS) -> list[Reading]:
    """Every reading of :data:`~hbeo.render.poses.SAMPLERS` with what ``run`` holds of ``settings`` under it,
    the main reading (its plain files) first, then the others in that order."""
    run = RunDir.of(run)
    plain = {k: m for k in settings if (m := _read(run.evaluation(*k))) is not None}
    main = main_sampler(plain)
    ref_any = plain.get(T.PLAYERS[0]) or next(iter(plain.values()), None)
    out = [Reading(main, True, plain)] if main else []
    for s in SAMPLERS:
        if s == main:
            continue
        r = Reading(s, False)
        for k in settings:
            path = run.evaluation(*k, s)
            if (m := _read(path)) is None:
                continue
            why = _stale(m, s, plain.get(k, ref_any), k in plain)
            if why:
                r.stale[k] = f"`{path.name}`: {why}"
            else:
                r.evals[k] = m
        _other_fits(r, plain, run)
        out.append(r)
    return out


def _baseline(m: dict | None):
    return ((m or {}).get("request") or {}).get(BASELINE)


def _other_fits(r: Reading, plain: dict, run: RunDir) -> None:
    """Of ``r``'s files, those whose baseline file is another than the main reading's file of the same setting:
    into ``r.refit`` when every file of that baseline under the reading shares it, else into ``r.stale``."""
    other = {k: (a, b) for k, m in r.evals.items()
             if (a := _baseline(m)) is not None and (b := _baseline(plain.get(k))) is not None and a != b}
    fits: dict = {}                     # each baseline's files under the reading, before any is set aside
    for k, m in r.evals.items():
        fits.setdefault(k[0], set()).add(_baseline(m))
    for k, (a, b) in other.items():
        if len(fits[k[0]]) == 1:
            r.refit[k] = (a, b)
        else:
            del r.evals[k]
            r.stale[k] = (f"`{run.evaluation(*k, r.sampler).name}`: another baseline sha256 ({a}; the main reading's: "
                          f"{b}) than this reading's other {k[0]} files")


def refit_folder(run, sha: str):
    """The folder of ``run`` that holds the main reading's evaluations made with the baseline file of sha256
    ``sha`` (another fit; :data:`REFIT_SCRIPT`), under the main files' names."""
    return RunDir.of(run).path / f"refit-{sha}"


def _agreement(k, ref: dict, other: dict | None, sha: str) -> str:
    """How the main reading's file ``ref`` of setting ``k`` and ``other`` (the same setting with the baseline fit
    ``sha``, or None) agree, query by query: the class answers that differ and paired contrasts (other minus ref)."""
    if other is None:
        return f"{LABELS.get(k, k)}: not evaluated with that fit"
    why = next((f"another {key.replace('_', ' ')}" for key in SAME_RUN + SAME_SETTING
                if (other.get("request") or {}).get(key) != (ref.get("request") or {}).get(key)), None)
    if why or _baseline(other) != sha:
        return f"{LABELS.get(k, k)}: its file there is not comparable ({why or 'another baseline file'})"
    r, q = ref["per_query"], other["per_query"]
    mine = {(o, v): (p, e) for o, v, p, e in zip(r["object"], r["view"], r["pred"], r["edt"])}
    shared = [(mine[o, v], (p, e)) for o, v, p, e in zip(q["object"], q["view"], q["pred"], q["edt"])
              if (o, v) in mine]
    if not shared:
        return f"{LABELS.get(k, k)}: its file there shares no query with the main reading's"
    same = sum(a[0] == b[0] for a, b in shared)
    moved = max((abs(float(a[1]) - float(b[1])) for a, b in shared), default=0.0)
    stats = [s for s in REFIT_STATS if not (s == "accuracy" and ref.get("given_class"))
             and not (s == "pose_mean" and k[1] == "known")]
    est = paired.contrast_pair(other, ref, stats)
    parts = []
    for s, e in est.items():
        scale, unit = paired.SHOW[s][1:]
        parts.append(f"{paired.NAMES[s]} {_g(scale * e.value)} [{_g(scale * e.low)}, {_g(scale * e.high)}]"
                     f"{' points' if unit == ' %' else unit}")
    return (f"{LABELS.get(k, k)}: the same class on {same:,} of {len(shared):,} queries, a query's EDT e′ moved by "
            f"at most {_g(moved)}; " + ", ".join(parts) + f" ({len(shared):,} pairs, {est[stats[0]].n_objects} objects)")


def _g(x: float) -> str:
    """Two significant digits, no minus zero: differences between two fits are often tiny."""
    return f"{float(x) + 0.0:.2g}"


def refit_note(readings: list[Reading], man: dict, run) -> list[str]:
    """The note under the claims table on the readings that use another fit of a baseline (:attr:`Reading.refit`):
    which fit, why it differs, and how it agrees with the main reading's on the main reading's queries."""
    fits: dict = {}
    for r in readings:
        for k, pair in r.refit.items():
            fits.setdefault(pair, {}).setdefault(k, []).append(r.sampler)
    plain = next((r.evals for r in readings if r.main), {})
    lines = []
    for (sha, main_sha), keys in fits.items():
        where = sorted({s for v in keys.values() for s in v}, key=SAMPLERS.index)
        folder = refit_folder(run, sha)
        rd = RunDir(folder)
        text = (f"{MARK} Under {', '.join(f'`{s}`' for s in where)}, {_labels(keys)} use another fit of "
                f"{', '.join(sorted({k[0].upper() for k in keys}))}'s baseline file (sha256 {sha}; the main reading's: "
                f"{main_sha}). A fit of the same training grids, recipe and seed made again can differ in its last "
                f"bits (VBPCA's subspace and the class densities scikit-learn's EM fits in it need not be "
                f"bit-identical on another CPU or BLAS); the hash does not say how far. ")
        if not folder.is_dir():
            text += (f"That fit is not yet compared with the main reading's on the main reading's queries (run "
                     f"`{PY} {REFIT_SCRIPT} {man.get('profile') or 'PROFILE'} {man.get('dataset') or 'DATASET'} "
                     f"{os.path.relpath(RunDir.of(run).path, config.REPO_ROOT)}` on a machine that fits it so).")
        else:
            text += (f"On the main reading's queries, that fit against the main reading's (`{folder.name}/`, that "
                     f"fit minus the main reading's, 95 % paired intervals over objects): "
                     + "; ".join(_agreement(k, plain[k], _read(rd.evaluation(*k)), sha) for k in keys
                                 if k in plain) + ".")
        lines += [text, ""]
    return lines


def command(man: dict, run, sampler: str, methods=()) -> str:
    """The ``scripts/readings.sh`` line that evaluates ``methods`` (all when empty) of ``run`` under ``sampler``."""
    where = os.path.relpath(RunDir.of(run).path, config.REPO_ROOT)
    only = f'{METHODS}="{" ".join(f"{m}:{p}" for m, p in methods)}" ' if methods else ""
    return (f"`{only}bash {SCRIPT} {man.get('profile') or 'PROFILE'} {man.get('dataset') or 'DATASET'} {where} "
            f"{PY} {sampler}`")


def _name(s: Reading) -> str:
    return f"`{s.sampler}`" + (" (main)" if s.main else "")


def _labels(keys) -> str:
    return ", ".join(LABELS.get(k, f"{k[0]} ({k[1]})") for k in keys)


def claims_table(readings: list[Reading], man: dict, run) -> pd.DataFrame:
    """The claims (rows: each of :data:`hbeo.report.tables.PLAYERS` playing HBEO in each claim of
    :data:`hbeo.evaluation.paired.CLAIMS`) under each reading with a file (a column each): the verdict,
    the contrast, both statistics and the pairs, or *not evaluated* and the command that evaluates it."""
    shown = [r for r in readings if r.evals]
    judged = {r.sampler: T.claims(r.evals) for r in shown}
    rows = []
    for p in T.PLAYERS:
        ran = [r.evals[p] for r in shown if p in r.evals]
        who = label(ran[0]) if ran else LABELS[p]
        for i, c in enumerate(paired.CLAIMS):
            row = {"claim (paper)": c.text, "HBEO played by": who}
            for r in shown:
                cl = judged[r.sampler]
                if (p[0], i) in cl.index:
                    j = cl.loc[(p[0], i)]
                    mark = f" {MARK}" if any(k in r.refit for k in T.claim_methods(c, p)) else ""
                    row[_name(r)] = (f"**{j['verdict']}**{mark}: contrast {j['contrast (claim: < 0)']}; "
                                     f"{j['ours (95 % CI)']}; {j['pairs']} pairs, {j['objects']} objects")
                else:
                    need = [k for k in T.claim_methods(c, p) if k not in r.evals]
                    row[_name(r)] = f"not evaluated (run {command(man, run, r.sampler, need)})"
            rows.append(row)
    return pd.DataFrame(rows)


def accuracy_block(r: Reading, man: dict, run) -> list[str]:
    """Table I under reading ``r``: accuracy and class-mean accuracy with intervals of each classifying
    setting (:data:`~hbeo.evaluation.protocol.TABLE1`) it holds, as ``05_accuracy_ci`` shows them, and the
    settings it lacks."""
    have = [r.evals[k] for k in TABLE1 if k in r.evals]
    lines = [f"**{_name(r)}**", ""]
    if have:
        acc = paired.estimates(paired.PairedBootstrap(have), ["accuracy", "class_accuracy"], keys=TABLE1)
        lines += [T.to_markdown(paired.wide(acc)), ""]
    refit = [k for k in TABLE1 if k in r.refit]
    if refit:
        lines += [f"{MARK} {_labels(refit)}: another fit of the baseline (the note under the claims table).", ""]
    need = [k for k in TABLE1 if k not in r.evals]
    if need:
        lines += [f"Not evaluated: {_labels(need)} (run {command(man, run, r.sampler, need)}).", ""]
    return lines


def _files_line(r: Reading, man: dict, run) -> str:
    """``- `floor` — what it draws. What the run holds under it, what it lacks and the command for that."""
    text = f"- {_name(r)} — {SAMPLER_HELP[r.sampler]}. "
    if not r.evals:
        text += f"Not evaluated (run {command(man, run, r.sampler)})"
    else:
        files = ("`eval_<method>_<pose>.json`" if r.main else f"`eval_<method>_<pose>_{r.sampler}.json`")
        text += f"{len(r.evals)} of {len(EVALUATIONS)} settings ({files}: {_labels(r.evals)})"
        if r.refit:
            text += f"; with another fit of the baseline ({MARK}, the note under the claims table): {_labels(r.refit)}"
        if r.missing:
            text += f"; not evaluated: {_labels(r.missing)} (run {command(man, run, r.sampler, r.missing)})"
    if r.stale:
        text += "; not used: " + "; ".join(r.stale.values())
    return text + "."


def section(run, man: dict) -> list[str]:
    """The lines of the section :data:`TITLE` of ``REPRODUCTION.md`` for ``run`` (``man``: its manifest)."""
    readings = run_readings(run)
    main = next((r.sampler for r in readings if r.main), None)
    if main is None:
        says = ("The run's main reading (the model's training sampler) is not recorded: "
                + ("its `eval_<method>_<pose>.json` files record no sampler." if any(
                    RunDir.of(run).evaluation(*k).exists() for k in EVALUATIONS) else
                   "it holds no `eval_<method>_<pose>.json` yet."))
    elif main == MAIN:
        says = (f"**The main reading is `{MAIN}`**, the model's training sampler: every section above is under it. "
                f"It was fixed before any result under another reading was seen, and is never chosen by which "
                f"reading matches the paper's figures (docs/method.md, *Readings of the view protocol*). {ARGUMENT}")
    else:
        says = (f"**This run's main reading is `{main}`**, its model's training sampler: every section above is "
                f"under it. The project's main reading is `{MAIN}` (docs/method.md, *Readings of the view protocol*): "
                f"{ARGUMENT}")
    lines = [f"## {TITLE}", "",
             "The paper's views are \"multiple random viewpoints\"; each sampler of `hbeo.render.poses.SAMPLERS` "
             "is one reading of those words. " + says, "",
             "Under one reading every method scores the same images; the readings share the objects and each "
             "view's random stream, not the images, so readings are compared per object, not per image. "
             "Verdicts and intervals as in the claims section above. Each reading, and the run's files under it:", ""]
    lines += [_files_line(r, man, run) for r in readings]
    shown = [r for r in readings if r.evals]
    if not any(not r.main for r in shown):
        return lines + ["", "No other reading is evaluated: the claims and Table I under the main reading are the "
                            "sections above." if shown else "No reading is evaluated yet.", ""]
    lines += ["", T.to_markdown(claims_table(readings, man, run)), ""]
    lines += refit_note(readings, man, run)
    lines += ["Table I under each reading: accuracy and class-mean accuracy (%) of each classifying setting "
              "(95 % intervals over test objects):", ""]
    for r in shown:
        lines += accuracy_block(r, man, run)
    return lines
