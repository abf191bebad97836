"""hbeo.report.compare: two run folders' tables agree unless a cell that is not a timing differs."""
import subprocess
import sys
from pathlib import Path

import pytest

from hbeo.report.compare import is_timing, table_differences

ROOT = Path(__file__).resolve().parent.parent

TABLE2 = """| method | queries | median (s) | paper: mean (s) |
| --- | ---: | ---: | ---: |
| HBEO (3-DOF) | 2721 | {t} | 0.01 |

Seconds per query. Wall time {w} min.
"""


def _run(d: Path, t="0.0037", w="12.5", acc="0.721", ms="5.6", paper="0.01") -> Path:
    d.mkdir()
    (d / "07_table2.md").write_text(TABLE2.format(t=t, w=w).replace("| 0.01 |", f"| {paper} |"))
    (d / "05_table1.csv").write_text(f"method,accuracy,ms\nhbeo,{acc},{ms}\n")
    return d


@pytest.mark.parametrize("header, timing", [("median (s)", True), ("mean (s)", True), ("ms", True),
                                            ("ms/query (val / test)", True), ("ms_per_query", True),
                                            ("images/s (this run)", True), ("wall_s", True), ("time_utc", True),
                                            ("paper: mean (s)", False), ("queries", False), ("class mean", False),
                                            ("mean (°, the paper's statistic)", False), ("IoU", False)])
def test_timing_columns_are_the_measured_times(header, timing):
    assert is_timing(header) is timing


def test_runs_differing_only_in_timings_agree(tmp_path):
    a = _run(tmp_path / "a")
    b = _run(tmp_path / "b", t="0.0051", w="14.0", ms="7.9")
    assert table_differences(a, b) == []


def test_every_other_difference_is_named(tmp_path):
    a = _run(tmp_path / "a")
    b = _run(tmp_path / "b", acc="0.722", paper="0.02")
    (b / "06_claims.md").write_text("x\n")
    diffs = table_differences(a, b)
    assert any(d.startswith("05_table1.csv: row 1, 'accuracy': 0.721 vs 0.722") for d in diffs), diffs
    assert any(d.startswith("07_table2.md: line 3") and "0.02" in d for d in diffs), diffs   # the paper's time is compared
    assert f"06_claims.md: only in {b}" in diffs and len(diffs) == 3


def test_the_script_exits_by_the_verdict(tmp_path):
    a, b = _run(tmp_path / "a"), _run(tmp_path / "b", acc="0.5")
    script = [sys.executable, str(ROOT / "scripts" / "compare_runs.py")]
    assert subprocess.run(script + [str(a), str(a)], capture_output=True).returncode == 0
    r = subprocess.run(script + [str(a), str(b)], capture_output=True, text=True)
    assert r.returncode == 1 and "accuracy" in r.stdout
    r = subprocess.run(script + [str(a), str(tmp_path / "nothing")], capture_output=True, text=True)
    assert r.returncode == 2 and "nothing: not a run folder" in r.stderr and "Traceback" not in r.stderr
