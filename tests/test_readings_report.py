"""REPRODUCTION.md's section on the paper's claims under each reading of the view protocol
(hbeo.report.readings), the claims table built from one reading's evaluations (hbeo.report.tables.claims),
and scripts/readings.sh's METHODS restriction; on tiny synthetic run folders."""
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from hbeo.evaluation import paired
from hbeo.evaluation.protocol import EVALUATIONS
from hbeo.report import readings, reproduction_md as report, tables as T
from hbeo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
CLS = ["chair", "desk", "sofa"]
MAN = {"profile": "ci", "dataset": "procedural"}
REQUEST = {"dataset_fingerprint": "d0", "model_sha256": "m0", "seed": 0, "per_class": None, "views": 2,
           "baseline_sha256": None}


def fake(method, pose, sampler="so3", right=True, pose_deg=10.0, edt=100.0, ms=5.0, **request):
    """Metrics of ``method``/``pose`` under ``sampler``: 4 objects per class x 2 views, all right or all wrong."""
    objects = [(c, f"{c}_{i:04d}") for c in CLS for i in range(4)]
    q = {k: [] for k in ("object", "view", "class", "pred", "pose_deg", "pose_sym_deg", "edt", "naive", "iou",
                         "empty", "ms")}
    for c, o in objects:
        for v in range(2):
            for k, x in (("object", o), ("view", v), ("class", c), ("pred", c if right else "other"),
                         ("pose_deg", pose_deg), ("pose_sym_deg", 0.0), ("edt", edt), ("naive", 0.1), ("iou", 0.5),
                         ("empty", False), ("ms", ms)):
                q[k].append(x)
    return {"method": method, "pose": pose, "given_class": pose == "3dof" and method in ("beo", "icp"),
            "verify": None, "sampler": sampler, "per_query": q, "request": {**REQUEST, **request}}


def write(run: RunDir, m: dict, sampler=None) -> Path:
    path = run.evaluation(m["method"], m["pose"], sampler)
    path.write_text(json.dumps(m))
    return path


CHEAP = (("hbeo", "3dof"), ("beo", "known"), ("voxcnn", "known"))


@pytest.fixture
def run(tmp_path):
    """A run folder: every setting under the main reading (so3), HBEO the best classifier; under ``floor``
    only the cheap settings, HBEO the worst; under ``upright`` one file of another model; nothing under sphere."""
    run = RunDir(tmp_path / "run").create()
    run.manifest.write_text(json.dumps(MAN))
    for k in EVALUATIONS:
        write(run, fake(*k, right=k[0].startswith("hbeo") or k[1] == "3dof"))
    for k in CHEAP:
        write(run, fake(*k, "floor", right=k[0] != "hbeo"), "floor")
    write(run, fake("hbeo", "3dof", "upright", model_sha256="another"), "upright")
    return run


def _section(run) -> str:
    return "\n".join(readings.section(run, MAN))


def test_the_section_lists_each_reading_with_its_files(run):
    text = _section(run)
    assert "**The main reading is `so3`**, the model's training sampler" in text
    assert f"). {len(EVALUATIONS)} of {len(EVALUATIONS)} settings (`eval_<method>_<pose>.json`" in text
    assert text.count("\n- `") == 4                                        # each reading listed once
    floor = next(line for line in text.splitlines() if line.startswith("- `floor` — "))
    assert floor.startswith("- `floor` — camera uniform on the upper hemisphere (above the floor) + uniform roll (3 DOF). "
                            "3 of 7 settings (`eval_<method>_<pose>_floor.json`: HBEO (3-DOF), "
                            "BEO (known pose), 3-D CNN on partial grid (known pose))")
    assert 'not evaluated: HBEO + rolls + verify (3-DOF, ours), BEO (1-DOF), BEO (3-DOF, true class), ICP' in floor
    assert re.search(r'\(run `METHODS="hbeo-verify:3dof beo:1dof beo:3dof icp:3dof" bash scripts/readings\.sh ci '
                     r'procedural \S+ \.venv/bin/python floor`\)\.$', floor), floor
    upright = next(line for line in text.splitlines() if line.startswith("- `upright` — "))
    assert "no roll (2 DOF). Not evaluated (run `bash scripts/readings.sh ci procedural " in upright
    assert "not used: `eval_hbeo_3dof_upright.json`: another model sha256 (another; the main reading's: m0)" in upright
    assert re.search(r"- `sphere` — .*\. Not evaluated \(run `bash scripts/readings\.sh .* sphere`\)\.", text)
    header = next(line for line in text.splitlines() if line.startswith("| claim (paper) |"))
    assert header == "| claim (paper) | HBEO played by | `so3` (main) | `floor` |"        # readings with files only


def test_verdicts_are_computed_per_reading_and_missing_files_are_marked(run):
    t = readings.claims_table(readings.run_readings(run), MAN, run)
    assert len(t) == len(T.PLAYERS) * len(paired.CLAIMS)                   # every claim, none vanishes
    first = t.iloc[0]                                                      # HBEO classifies better than BEO known
    assert first["claim (paper)"] == paired.CLAIMS[0].text and first["HBEO played by"] == "HBEO (3-DOF)"
    assert first["`so3` (main)"].startswith("**holds**: contrast -100.0 [-100.0, -100.0]; HBEO (3-DOF): 0.0")
    assert first["`floor`"].startswith("**fails**: contrast 100.0 [100.0, 100.0]; HBEO (3-DOF): 100.0")
    assert first["`floor`"].endswith("24 pairs, 12 objects")
    one_dof = t.iloc[2]                                                    # needs BEO 1-DOF, not run under floor
    assert one_dof["`so3` (main)"].startswith("**")
    assert re.fullmatch(r'not evaluated \(run `METHODS="beo:1dof" bash scripts/readings\.sh ci procedural \S+ '
                        r'\.venv/bin/python floor`\)', one_dof["`floor`"])
    verify = t.iloc[len(paired.CLAIMS)]                                    # HBEO + verify playing HBEO
    assert verify["HBEO played by"] == "HBEO + rolls + verify (3-DOF, ours)"
    assert 'METHODS="hbeo-verify:3dof" bash' in verify["`floor`"]
    assert T.to_markdown(t).count("not evaluated") == sum(
        any(k not in dict.fromkeys(CHEAP) for k in T.claim_methods(c, p)) for p in T.PLAYERS for c in paired.CLAIMS)


def test_table1_block_per_reading_shows_what_is_there_and_marks_the_rest(run):
    text = _section(run)
    floor = text[text.index("**`floor`**"):]
    assert "| HBEO (3-DOF) | 12 | 24 | 0.0 [0.0, 0.0] | 0.0 [0.0, 0.0] |" in floor
    assert "| BEO (known pose) | 12 | 24 | 100.0 [100.0, 100.0] | 100.0 [100.0, 100.0] |" in floor
    assert "Not evaluated: HBEO + rolls + verify (3-DOF, ours), BEO (1-DOF) (run `METHODS=\"hbeo-verify:3dof " \
           "beo:1dof\" bash" in floor
    main = text[text.index("**`so3` (main)**"):text.index("**`floor`**")]
    assert "| HBEO (3-DOF) | 12 | 24 | 100.0 [100.0, 100.0] |" in main and "Not evaluated" not in main
    assert "**`upright`**" not in text and "**`sphere`**" not in text      # no files: listed above, no block


def test_no_section_change_when_only_the_main_reading_exists(run, monkeypatch):
    """Other readings' files change the new section only: the rest of REPRODUCTION.md (the main reading's
    content) is the same text with or without them, and with the main reading alone the section adds no table."""
    full = report.reproduction_text(run, run.path / "R.md")
    for p in run.path.glob("eval_*_*_*.json"):
        p.unlink()
    alone = report.reproduction_text(run, run.path / "R.md")

    def outside(text):
        start = text.index(f"## {readings.TITLE}")
        return text[:start] + text[text.index("\n## ", start + 1) + 1:]
    assert outside(full) == outside(alone) and full != alone
    section = alone[alone.index(f"## {readings.TITLE}"):]
    section = section[:section.index("\n## ", 1)]
    assert "| claim (paper) |" not in section and "**`so3` (main)**" not in section
    assert "No other reading is evaluated: the claims and Table I under the main reading are the sections above." \
        in section
    monkeypatch.setattr(readings, "section", lambda run, man: [])
    assert outside(alone) == report.reproduction_text(run, run.path / "R.md")   # the section only adds itself


def test_a_missing_or_broken_reading_never_fails_the_report(tmp_path):
    run = RunDir(tmp_path / "run").create()
    text = _section(run)                                                   # no evaluation at all
    assert "main reading (the model's training sampler) is not recorded: it holds no" in text
    assert "No reading is evaluated" in text
    write(run, {**fake("hbeo", "3dof"), "sampler": None})                  # a file older than the readings
    assert "its `eval_<method>_<pose>.json` files record no sampler" in _section(run)
    write(run, fake("hbeo", "3dof"))
    write(run, fake("beo", "3dof", "floor"), "floor")                      # no classifying setting under floor
    run.evaluation("hbeo", "3dof", "sphere").write_text("{not json")       # unreadable: as if missing
    write(run, fake("beo", "known", "so3"), "upright")                     # a file that records another reading
    text = _section(run)
    assert "Not evaluated: HBEO (3-DOF), HBEO + rolls + verify (3-DOF, ours), BEO (known pose)" in text
    assert re.search(r"- `sphere` — .*\. Not evaluated \(run `bash scripts/readings\.sh ci procedural \S+ "
                     r"\.venv/bin/python sphere`\)\.", text)
    assert "not used: `eval_beo_known_upright.json`: records sampler 'so3'" in text
    write(run, fake("beo", "known", "upright"))                            # the main files disagree on their sampler
    with pytest.raises(ValueError, match="different samplers"):
        readings.run_readings(run)


def test_the_main_reading_argument_is_the_readme_s():
    """The section quotes the documentation's argument for the main reading (docs/method.md, *Readings of the
    view protocol*), sentence by sentence; it adds none."""
    readme = " ".join((ROOT / "docs" / "method.md").read_text().split())
    section = readme[readme.index("**The main reading is `so3`**"):]
    sentences = [s.strip() for s in re.split(r"(?<=\.) ", readings.ARGUMENT) if s.strip()]
    assert len(sentences) == 2
    for s in sentences:
        assert s[0].lower() + s[1:] in section or s in section, s


def test_readings_sh_takes_only_known_settings_and_the_report_s_commands_are_its(run, tmp_path):
    out = subprocess.run(["bash", str(ROOT / "scripts" / "readings.sh"), "ci", "procedural", str(tmp_path / "new"),
                          sys.executable, "floor"], env={"METHODS": "beo:known beo:5dof", "PATH": "/usr/bin:/bin"},
                         capture_output=True, text=True)
    assert out.returncode == 2 and "METHODS names beo:5dof" in out.stderr and "icp:3dof" in out.stderr
    assert not (tmp_path / "new").exists()                                 # refused before anything ran
    for cmd in re.findall(r'METHODS="([^"]*)" bash', _section(run)):
        assert all(tuple(s.split(":")) in EVALUATIONS for s in cmd.split())


def _refit_run(tmp_path) -> RunDir:
    """Every setting under so3 with BEO's baseline b0; BEO known and 1-DOF under floor with another fit, b1."""
    run = RunDir(tmp_path / "run").create()
    run.manifest.write_text(json.dumps(MAN))
    for k in EVALUATIONS:
        write(run, fake(*k, right=k[0].startswith("hbeo") or k[1] == "3dof",
                        baseline_sha256="b0" if k[0] == "beo" else None))
    write(run, fake("hbeo", "3dof", "floor"), "floor")
    for pose in ("known", "1dof"):
        write(run, fake("beo", pose, "floor", right=False, baseline_sha256="b1"), "floor")
    return run


def test_a_reading_with_another_fit_of_the_baseline_is_used_marked_and_compared(tmp_path):
    """BEO files under a reading that all record another baseline file (the same recipe fitted on another CPU) are
    used and marked; the note compares that fit with the main reading's on the main queries, once the run's
    refit-<sha>/ folder holds them (scripts/refit.py), query by query."""
    run = _refit_run(tmp_path)
    r = {x.sampler: x for x in readings.run_readings(run)}["floor"]
    assert r.refit == {("beo", "known"): ("b1", "b0"), ("beo", "1dof"): ("b1", "b0")} and not r.stale
    text = _section(run)
    floor = next(line for line in text.splitlines() if line.startswith("- `floor` — "))
    assert "with another fit of the baseline (†, the note under the claims table): BEO (known pose), BEO (1-DOF)" \
        in floor
    t = readings.claims_table(readings.run_readings(run), MAN, run)
    assert t.iloc[0]["`floor`"].startswith("**holds** †: contrast")           # HBEO vs BEO known: another fit
    assert "†" not in t.iloc[0]["`so3` (main)"]
    note = next(line for line in text.splitlines() if line.startswith("† Under `floor`, BEO (known pose), BEO (1-DOF)"))
    assert "(sha256 b1; the main reading's: b0). A fit of the same training grids" in note
    assert re.search(r"run `\.venv/bin/python scripts/refit\.py ci procedural \S+` on a machine", note)
    assert "† BEO (known pose), BEO (1-DOF): another fit of the baseline" in text[text.index("**`floor`**"):]
    # the refit folder: BEO known with the other fit on the main queries, one answer in 24 changed
    folder = readings.refit_folder(run, "b1")
    folder.mkdir()
    known = fake("beo", "known", right=False, baseline_sha256="b1")
    known["per_query"]["pred"][0] = known["per_query"]["class"][0]
    known["per_query"]["edt"][:2] = [130.0, 130.0]
    write(RunDir(folder), known)
    note = next(line for line in _section(run).splitlines() if line.startswith("† Under `floor`"))
    assert "On the main reading's queries, that fit against the main reading's (`refit-b1/`" in note
    assert ("BEO (known pose): the same class on 23 of 24 queries, a query's EDT e′ moved by at most 30; accuracy 4.2 [" in note
            and "mean EDT e′ (lower is better) 2.5 [" in note and "(24 pairs, 12 objects)" in note)
    assert "mean pose error" not in note.split("BEO (1-DOF)")[0]              # known pose: no pose statistic
    assert "BEO (1-DOF): not evaluated with that fit" in note
    write(RunDir(folder), fake("beo", "1dof", baseline_sha256="b1", model_sha256="m9"))
    note = next(line for line in _section(run).splitlines() if line.startswith("† Under `floor`"))
    assert "BEO (1-DOF): its file there is not comparable (another model sha256)" in note
    other = fake("beo", "1dof", baseline_sha256="b1")
    other["per_query"]["object"] = [f"x{i}" for i in range(len(other["per_query"]["object"]))]
    write(RunDir(folder), other)
    note = next(line for line in _section(run).splitlines() if line.startswith("† Under `floor`"))
    assert "BEO (1-DOF): its file there shares no query with the main reading's" in note


def test_a_reading_mixing_fits_of_one_baseline_uses_only_the_main_reading_s(tmp_path):
    run = _refit_run(tmp_path)
    write(run, fake("beo", "known", "floor", baseline_sha256="b0"), "floor")
    r = {x.sampler: x for x in readings.run_readings(run)}["floor"]
    assert ("beo", "known") in r.evals and not r.refit
    assert r.stale == {("beo", "1dof"): "`eval_beo_1dof_floor.json`: another baseline sha256 (b1; the main "
                                        "reading's: b0) than this reading's other beo files"}
    assert "†" not in _section(run)
    # two other fits, neither the main reading's: every file of that baseline is set aside, whatever the order
    write(run, fake("beo", "known", "floor", baseline_sha256="b2"), "floor")
    r = {x.sampler: x for x in readings.run_readings(run)}["floor"]
    assert not r.refit and set(r.stale) == {("beo", "known"), ("beo", "1dof")}


def test_refit_script_refuses_a_run_without_the_main_reading_s_files(tmp_path):
    """scripts/refit.py compares with the run's main evaluations: without them it stops before fitting anything."""
    run = RunDir(tmp_path / "run").create()
    write(run, fake("beo", "known"))
    out = subprocess.run([sys.executable, str(ROOT / "scripts" / "refit.py"), "ci", "procedural", str(run.path)],
                         capture_output=True, text=True)
    assert out.returncode == 2 and f"{run.evaluation('beo', '1dof')}: missing" in out.stderr, out.stderr
    assert sorted(p.name for p in run.path.iterdir()) == ["eval_beo_known.json"]      # nothing written
