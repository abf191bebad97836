"""The README's model table (hbeo.report.model_table): generated from committed metrics files
only, validation and test side by side; the committed README carries exactly the generated block."""
import json
from pathlib import Path

import pytest

from hbeo.errors import DataError
from hbeo.report.model_table import (BEGIN, END, TARGETS_BEGIN, TARGETS_END, model_table, replace_block,
                                           targets_table, write_model_table)
from hbeo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]


def _metrics(split, acc, n):
    return {"split": split, "accuracy": acc, "n_queries": n, "pose_error_deg": {"median": 12.34, "within_30": 0.5},
            "completion": {"iou": 0.4567}, "runtime_ms": {"mean_per_query": 3.21}}


def test_table_rows_come_from_the_named_files(tmp_path):
    (tmp_path / "v1.json").write_text(json.dumps(_metrics("val", 0.75, 30)))
    test = _metrics("test", 0.7, 90)
    test["per_query"] = {"object": ["a", "a", "b"], "class": ["x", "x", "y"], "pred": ["x", "y", "y"],
                         "pose_deg": [10.0, 50.0, 20.0], "iou": [0.5, 0.7, 0.2], "edt": [10.0, 30.0, 50.0]}
    test["completion"]["edt"] = 30.0
    beo = _metrics("test", 0.8, 90)
    beo["per_query"] = {**test["per_query"], "edt": [20.0, 25.0, 40.0]}
    beo["completion"]["edt"] = 28.0
    (tmp_path / "b.json").write_text(json.dumps(beo))
    (tmp_path / "t1.json").write_text(json.dumps(test))
    (tmp_path / "v2.json").write_text(json.dumps(_metrics("val", 0.6, 30)))
    rows = [{"label": "A", "val": "v1.json", "test": "t1.json", "chosen": True, "target_role": "hbeo"},
            {"label": "B", "val": "v2.json", "test": None, "chosen": False, "note": "tried"},
            {"label": "BEO", "val": None, "test": "b.json", "chosen": False, "target_role": "beo-known"}]
    RunDir(tmp_path).model_rows.write_text(json.dumps(rows))
    table = model_table(tmp_path)
    lines = table.splitlines()
    assert len(lines) == 4                                   # the reference row is the targets table's only
    # test cells carry a 95 % interval over objects (from per_query; a and b resampled as units)
    cells = [c.strip() for c in lines[2].split("|")[1:-1]]
    assert cells[:2] == ["A", "yes"] and cells[2].startswith("75.0 % / 70.0 % [") and cells[2].endswith("]")
    assert cells[3].startswith("12.3° / 12.3° [") and cells[5].startswith("0.457 / 0.457 [")
    assert lines[2].endswith("| 30 / 90 |")
    assert lines[3].startswith("| B (tried) | no | 60.0 % / – |")
    readme = tmp_path / "README.md"
    targets = targets_table(tmp_path)
    assert "| class accuracy | ≥ 81.8 % with verify, ≥ 78 % alone | 70.0%: missed | 80.0% |" in targets
    assert "| pose error, raw median | ≤ 20° | 12.3°: met | 12.3° |" in targets and "| ms per query" in targets
    # EDT against the reference row (BEO, known pose): mean 30 vs 28 missed, median 30 vs 25 missed
    assert "| completion e′ (EDT), mean | below BEO's with known pose (same views) | 30: missed | 28 |" in targets
    assert "| completion e′ (EDT), median | below BEO's with known pose (same views) | 30: missed | 25 |" in targets
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
    with pytest.raises(ValueError, match="one generated block"):
        replace_block("no block", table)


def test_the_committed_readme_carries_the_generated_model_table():
    run = ROOT / "results" / "cpu-modelnet10-vox30"
    text = (ROOT / "README.md").read_text()
    assert replace_block(text, model_table(run)) == text, \
        "README's model table is stale: python -m hbeo report --model-table --run results/cpu-modelnet10-vox30 " \
        "--readme README.md"
    assert replace_block(text, targets_table(run), begin=TARGETS_BEGIN, end=TARGETS_END) == text, \
        "README's model table is stale: python -m hbeo report --model-table --run results/cpu-modelnet10-vox30 " \
        "--readme README.md"
