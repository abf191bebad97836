"""The README's model table (hbeo.report.model_table): generated from committed metrics files
only, validation and test side by side, class-mean accuracy first, seeds' spread, issue 29's targets;
the committed README carries exactly the generated blocks."""
import json
from pathlib import Path

import numpy as np
import pytest

from hbeo.errors import DataError
from hbeo.report.model_table import (BEGIN, END, TARGETS_BEGIN, TARGETS_END, model_table, replace_block,
                                     targets_table, write_model_table)
from hbeo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
#: 3 objects x 2 views: a and b of class x, c of class y
OBJECTS, VIEWS, CLASSES = ["a", "a", "b", "b", "c", "c"], [0, 1, 0, 1, 0, 1], ["x", "x", "x", "x", "y", "y"]


def _metrics(split, pred, pose=(10, 50, 20, 100, 5, 170), sym=(10, 5, 20, 100, 5, 10), iou=0.6, ms=5.0,
             old=False, edt=200.0, empty=(False,) * 6, **top):
    """A metrics dict whose top-level figures follow its per_query columns; ``old``: a file from before
    class_mean_accuracy and within_30_sym (they must then come from per_query)."""
    pose, sym, pred = np.array(pose, float), np.array(sym, float), list(pred)
    cls, correct = np.array(CLASSES), np.array(CLASSES) == np.array(pred)
    m = {"split": split, "dataset": "toy", "views": 2, "seed": 0, "sampler": "so3", "noise": False, "n_objects": 3,
         "n_queries": 6, "method": "hbeo", "pose": "3dof", "rolls": 1, "verify": None,
         "accuracy": float(correct.mean()),
         "class_mean_accuracy": float(np.mean([correct[cls == c].mean() for c in ("x", "y")])),
         "pose_error_deg": {"median": float(np.median(pose)), "within_30": float((pose < 30).mean()),
                            "within_30_sym": float((sym < 30).mean())},
         "completion": {"iou": iou, "edt": edt}, "runtime_ms": {"mean_per_query": ms},
         "per_query": {"object": OBJECTS, "view": VIEWS, "class": CLASSES, "pred": pred, "pose_deg": pose.tolist(),
                       "pose_sym_deg": sym.tolist(), "iou": [iou] * 6, "empty": list(empty), "ms": [ms] * 6}}
    if old:
        del m["class_mean_accuracy"], m["pose_error_deg"]["within_30_sym"]
    m.update(top)
    return m


#: class x 3/4, y 1/2: class mean 62.5 %, accuracy 66.7 %, lowest class y 50.0 %
HBEO = ["x", "x", "x", "y", "y", "x"]
ALL_X = ["x", "x", "x", "x", "x", "x"]                     # class mean 50.0 %, accuracy 66.7 %
ONE_Y_WRONG = ["x", "x", "x", "x", "y", "x"]               # class mean 75.0 %, accuracy 83.3 %


def _write(d: Path, files: dict, rows: list) -> None:
    for name, m in files.items():
        (d / name).write_text(json.dumps(m))
    RunDir(d).model_rows.write_text(json.dumps(rows))


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.split("|")[1:-1]]


def _run(tmp_path, **kw):
    files = {"v1.json": _metrics("val", ONE_Y_WRONG, old=True),
             "t1.json": _metrics("test", HBEO, empty=(True, False, False, True, False, False)),
             "v2.json": _metrics("val", ALL_X), "vv.json": _metrics("val", ONE_Y_WRONG),
             "tv.json": _metrics("test", ONE_Y_WRONG, pose=(10, 50, 20, 100, 5, 170), iou=0.5, ms=60.0, rolls=4,
                                 verify={"classes": 1}),
             "b.json": _metrics("test", ONE_Y_WRONG, pose=[0.0] * 6, sym=[0.0] * 6, iou=0.7, ms=14.0, edt=160.0,
                                method="beo", rolls=None)}
    files["b.json"]["pose"] = "known"
    files.update(kw.pop("files", {}))
    rows = [{"label": "A", "val": "v1.json", "test": "t1.json", "chosen": False, "target_role": "hbeo"},
            {"label": "B", "val": "v2.json", "test": None, "chosen": False, "note": "tried"},
            {"label": "V", "val": "vv.json", "test": "tv.json", "chosen": True, "target_role": "hbeo+verify"},
            {"label": "BEO", "val": None, "test": "b.json", "chosen": False, "target_role": "beo-known"}]
    for i, extra in kw.pop("rows", {}).items():
        rows[i].update(extra)
    _write(tmp_path, files, rows)
    return rows


def test_table_rows_come_from_the_named_files(tmp_path):
    rows = _run(tmp_path)
    table = model_table(tmp_path)
    lines = table.splitlines()
    assert len(lines) == 5                                   # the reference row is the targets table's only
    head = _cells(lines[0])
    assert head[:5] == ["configuration", "chosen on validation", "class mean (val / test)",
                        "class mean over seeds, mean ± sd (n) (val / test)", "accuracy (val / test)"]
    assert head[5:9] == ["lowest class (val / test)", "within 30°, raw (val / test)",
                         "within 30°, modulo symmetry (val / test)", "IoU (val / test)"]
    a = _cells(lines[2])
    # class mean first, not the overall accuracy: val (an old file, from per_query) 75.0 %, test 62.5 % [interval]
    assert a[:2] == ["A", "no"] and a[2].startswith("75.0 % / 62.5 % [") and a[2].endswith("]")
    assert a[3] == "–" and a[4].startswith("83.3 % / 66.7 % [")
    assert a[5] == "y 50.0 % / y 50.0 %"                                                   # the lowest class
    assert a[6].startswith("50.0 % / 50.0 % [") and a[7].startswith("83.3 % / 83.3 % [")  # raw, modulo symmetry
    assert a[8].startswith("0.600 / 0.600 [") and a[9] == "5.0 / 5.0" and a[10] == "6 / 6"
    assert lines[3].startswith("| B (tried) | no | 50.0 % / – | – | 66.7 % / – | y 0.0 % / – |")
    readme = tmp_path / "README.md"
    targets = targets_table(tmp_path)
    readme.write_text(f"intro\n{BEGIN}\nold\n{END}\nmid\n{TARGETS_BEGIN}\nx\n{TARGETS_END}\nrest\n")
    write_model_table(tmp_path, readme)
    assert readme.read_text() == f"intro\n{BEGIN}\n{table}{END}\nmid\n{TARGETS_BEGIN}\n{targets}{TARGETS_END}\nrest\n"
    assert RunDir(tmp_path).model_table.read_text() == table + "\n" + targets
    # a test file in the validation column, or a missing file, is refused with the file named
    rows[1]["val"] = "t1.json"
    RunDir(tmp_path).model_rows.write_text(json.dumps(rows))
    with pytest.raises(DataError, match="t1.json.*split 'test'"):
        model_table(tmp_path)
    rows[1]["val"] = "nope.json"
    RunDir(tmp_path).model_rows.write_text(json.dumps(rows))
    with pytest.raises(DataError, match="nope.json"):
        model_table(tmp_path)
    # models.json itself: missing, not JSON, not a list, a row that is not an object: the file is named
    path = RunDir(tmp_path).model_rows
    for text, why in (("[{", "not valid JSON"), ('{"label": "a"}', "a JSON object, not a JSON list"),
                      ('[{"label": "a"}, 3]', "row 1 is a number")):
        path.write_text(text)
        with pytest.raises(DataError, match=f"models.json.*{why}"):
            model_table(tmp_path)
    path.unlink()
    with pytest.raises(DataError, match="models.json.*cannot read the model-table rows.*experiment table"):
        model_table(tmp_path)
    with pytest.raises(ValueError, match="one generated block"):
        replace_block("no block", table)


def test_seeds_spread_is_the_class_mean_over_every_seed(tmp_path):
    """Seed 0's file and two more: class means 62.5, 75.0, 50.0 %: mean 62.5, sample sd 12.5."""
    _run(tmp_path, files={"t1-s1.json": _metrics("test", ONE_Y_WRONG), "t1-s2.json": _metrics("test", ALL_X),
                          "v1-s1.json": _metrics("val", ALL_X)},
         rows={0: {"test_seeds": ["t1-s1.json", "t1-s2.json"]}, 2: {"val_seeds": ["v1-s1.json"]}})
    lines = model_table(tmp_path).splitlines()
    assert _cells(lines[2])[3] == "– / 62.5 ± 12.5 % (3)"
    assert _cells(lines[2])[2].startswith("75.0 % / 62.5 % [")            # the seed-0 figure stays beside it
    assert _cells(lines[4])[3] == "62.5 ± 17.7 % (2) / –"                  # 75.0 and 50.0: sd 17.68
    assert _cells(lines[3])[3] == "–"


def test_a_baseline_row_shows_its_test_figures_and_seeds_without_a_validation_file(tmp_path):
    """Another method's row (``baseline``): no validation file (it holds out its own objects), its test figures and
    their spread over training seeds; a model row without a validation file stays refused."""
    cnn = {f"c{i}.json": _metrics("test", p, method="voxcnn", rolls=None) for i, p in enumerate((HBEO, ONE_Y_WRONG, ALL_X))}
    rows = _run(tmp_path, files=cnn)
    rows.append({"label": "CNN", "val": None, "test": "c0.json", "chosen": False, "baseline": True,
                 "test_seeds": ["c1.json", "c2.json"]})
    RunDir(tmp_path).model_rows.write_text(json.dumps(rows))
    cnn = _cells(model_table(tmp_path).splitlines()[-1])
    assert cnn[:2] == ["CNN", "baseline"] and cnn[2].startswith("– / 62.5 % [") and cnn[3] == "– / 62.5 ± 12.5 % (3)"
    assert cnn[-1] == "– / 6"
    del rows[-1]["baseline"]
    RunDir(tmp_path).model_rows.write_text(json.dumps(rows))
    with pytest.raises(DataError, match="'CNN' has no validation metrics file"):
        model_table(tmp_path)


@pytest.mark.parametrize("change,why", [
    ({"views": 1}, "views 1, not 2"),
    ({"seed": 3}, "seed 3, not 0"),
    ({"request": {"per_class": 1, "views": 2, "seed": 0}}, "request per_class 1, not None"),
    ({"request": {"per_class": None, "views": 2, "seed": 7}}, "request seed 7, not 0"),
    ({"per_query_objects": ["a", "a", "b", "b", "d", "d"]}, r"other \(object, view\) queries"),
])
def test_seeds_files_not_paired_with_the_row_are_refused(tmp_path, change, why):
    seed = _metrics("test", ONE_Y_WRONG)
    own = _metrics("test", HBEO, request={"per_class": None, "views": 2, "seed": 0})
    if "per_query_objects" in change:
        seed["per_query"]["object"] = change.pop("per_query_objects")
    seed.update(change)
    _run(tmp_path, files={"t1.json": own, "t1-s1.json": seed}, rows={0: {"test_seeds": ["t1-s1.json"]}})
    with pytest.raises(DataError, match=rf"t1-s1.json: not paired with t1.json \(row 'A'\): {why}"):
        model_table(tmp_path)
    # a paired file (same queries, another model's answers) is taken
    _run(tmp_path, files={"t1.json": own, "t1-s1.json": _metrics("test", ONE_Y_WRONG, request=own["request"])},
         rows={0: {"test_seeds": ["t1-s1.json"]}})
    row = _cells(model_table(tmp_path).splitlines()[2])
    assert row[2].startswith("75.0 % / 62.5 % [") and row[3] == "– / 68.8 ± 8.8 % (2)"


def test_seeds_lists_that_repeat_a_file_or_lack_the_row_s_file_are_refused(tmp_path):
    _run(tmp_path, rows={0: {"test_seeds": ["t1.json"]}})
    with pytest.raises(DataError, match="repeats a file"):
        model_table(tmp_path)
    _run(tmp_path, files={"v2-s1.json": _metrics("test", HBEO)}, rows={1: {"test_seeds": ["v2-s1.json"]}})
    with pytest.raises(DataError, match="test_seeds but no test file"):
        model_table(tmp_path)


def _target_rows(table: str) -> dict[str, list[str]]:
    return {c[0]: c[1:] for c in map(_cells, table.splitlines()[2:])}


def test_each_target_met_or_missed_with_its_gap(tmp_path):
    _run(tmp_path)
    t = _target_rows(targets_table(tmp_path))
    assert targets_table(tmp_path).splitlines()[0] == \
        "| measure | target | hbeo (`t1.json`) | hbeo+verify (`tv.json`) | beo-known (`b.json`) |"
    # one pass against BEO with known pose (75.0 %, read from b.json), and the stretch bar
    assert t["class-mean accuracy, HBEO one pass"] == [
        "≥ BEO with known pose on the same views (75.0 %, `b.json`); stretch ≥ 81.8 %",
        "62.5 %: missed by 12.5 points; stretch 81.8 %: missed by 19.3 points", "–", "75.0 %"]
    assert t["class-mean accuracy with the project's extensions"] == [
        "≥ 81.8 %", "–", "75.0 %: missed by 6.8 points", "75.0 %"]
    assert t["lowest class"] == ["≥ 55.0 %", "y 50.0 %: missed by 5.0 points", "y 50.0 %: missed by 5.0 points",
                                 "y 50.0 %"]
    assert t["pose within 30°, raw"] == ["≥ 65.0 %", "50.0 %: missed by 15.0 points",
                                         "50.0 %: missed by 15.0 points", "100.0 %"]
    assert t["pose within 30°, modulo symmetry"] == ["≥ 80.0 %", "83.3 %: met", "83.3 %: met", "100.0 %"]
    assert t["completion IoU"] == ["≥ 0.550", "0.600: met", "0.500: missed by 0.050", "0.700"]
    # mean e' against 1.25 x BEO's (160, b.json): 200 met; empty completions: t1 has two, tv none
    assert t["completion, mean EDT e′"] == [
        "≤ 1.25 × BEO with known pose on the same views (160, `b.json`)", "200: met", "–", "160"]
    assert t["empty completions"] == ["≤ 0", "2: missed by 2", "0: met", "0"]
    assert t["ms per query (2-core CPU)"] == ["≤ 10.0 (hbeo), ≤ 50.0 (hbeo+verify)", "5.0: met",
                                              "60.0: missed by 10.0 ms", "14.0"]


def test_targets_columns_keep_their_order_whatever_the_rows_order(tmp_path):
    """A new reference's rows are added after the BEO row (their specs come after the BEO row's): the columns stay
    one pass, extended, then the unjudged reference, and each keeps its own cells."""
    rows = _run(tmp_path)
    before = targets_table(tmp_path)
    RunDir(tmp_path).model_rows.write_text(json.dumps(rows[::-1]))
    assert targets_table(tmp_path) == before
    assert before.splitlines()[0].endswith("| hbeo (`t1.json`) | hbeo+verify (`tv.json`) | beo-known (`b.json`) |")


def test_the_one_pass_bar_is_read_from_the_reference_file(tmp_path):
    """A weaker BEO file lowers the bar: the same HBEO figure then meets it; no reference row, no bar."""
    weak = _metrics("test", ALL_X, method="beo", rolls=None)
    weak["pose"] = "known"
    rows = _run(tmp_path, files={"b.json": weak})
    t = _target_rows(targets_table(tmp_path))
    assert t["class-mean accuracy, HBEO one pass"][:2] == [
        "≥ BEO with known pose on the same views (50.0 %, `b.json`); stretch ≥ 81.8 %",
        "62.5 %: met; stretch 81.8 %: missed by 19.3 points"]
    RunDir(tmp_path).model_rows.write_text(json.dumps(rows[:3]))
    with pytest.raises(DataError, match="needs the 'beo-known' row"):
        targets_table(tmp_path)


def test_target_rows_must_be_what_their_role_says(tmp_path):
    """hbeo is one network pass (a 4-roll file is refused); the reference must be BEO with known pose and
    score the same queries as the judged rows."""
    _run(tmp_path, files={"t1.json": _metrics("test", HBEO, rolls=4)})
    with pytest.raises(DataError, match="t1.json: role 'hbeo' is HBEO's one network pass.*rolls 4"):
        targets_table(tmp_path)
    _run(tmp_path, files={"b.json": _metrics("test", ONE_Y_WRONG, method="beo")})
    with pytest.raises(DataError, match="b.json: role 'beo-known' is BEO with known pose"):
        targets_table(tmp_path)
    other = _metrics("test", ONE_Y_WRONG, method="beo", rolls=None, views=1)
    other["pose"] = "known"
    _run(tmp_path, files={"b.json": other})
    with pytest.raises(DataError, match="t1.json: not paired with the reference b.json: views 2, not 1"):
        targets_table(tmp_path)


def test_the_committed_run_and_docs_carry_the_generated_model_table():
    """The committed models.json (the specs' rows: tests/test_experiments.py) gives the run's committed
    model_table.md, and the model and targets tables live in the documentation's experiments page (README.md links
    to it)."""
    run = ROOT / "results" / "cpu-modelnet10-vox30"
    table, targets = model_table(run), targets_table(run)
    assert table + "\n" + targets == RunDir(run).model_table.read_text(), \
        f"{RunDir(run).model_table} is stale: python -m hbeo report --model-table --run results/cpu-modelnet10-vox30"
    text = (ROOT / "docs" / "experiments.md").read_text()
    assert replace_block(text, table) == text, \
        "docs/experiments.md's model table is stale: python -m hbeo report --model-table --run " \
        "results/cpu-modelnet10-vox30 --readme docs/experiments.md"
    assert replace_block(text, targets, begin=TARGETS_BEGIN, end=TARGETS_END) == text, \
        "docs/experiments.md's targets table is stale: python -m hbeo report --model-table --run " \
        "results/cpu-modelnet10-vox30 --readme docs/experiments.md"
