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


def test_a_speed_claims_measured_cells_and_the_run_path_are_not_differences(tmp_path):
    """Two runs of one command: a claim about speed states measured times (and may flip its verdict with them);
    reports name their own run folder. Neither is a difference; the claim's accuracy rows still are."""
    head = "claim (paper),HBEO played by,ours (95 % CI),contrast (claim: < 0),pairs,objects,verdict\n"
    speed = '"HBEO is faster than BEO (100x)",HBEO,"HBEO: {h} ms; BEO: 912 [867, 987] ms","{c}",50,50,{v}\n'
    acc = 'HBEO classifies better,HBEO,"HBEO: 19.3 [17.0, 21.5] % error","{a}",1500,500,fails\n'
    for name, h, c, v, a in (("a", "5.47 [5.12, 5.74]", "-3.65 [-4.61, -3.2]", "holds", "10.7 [8.3, 13.1]"),
                             ("b", "6.01 [5.5, 6.4]", "-2.9 [-3.3, 0.1]", "inconclusive", "10.7 [8.3, 13.1]"),
                             ("c", "5.47 [5.12, 5.74]", "-3.65 [-4.61, -3.2]", "holds", "10.8 [8.3, 13.1]")):
        d = tmp_path / name
        d.mkdir()
        (d / "06_claims.csv").write_text(head + speed.format(h=h, c=c, v=v) + acc.format(a=a))
        (d / "REPRODUCTION.md").write_text(f"# Reproduction\n\nRun folder: `{d}`; see {d}/06_claims.md\n")
    assert table_differences(tmp_path / "a", tmp_path / "b") == []
    diffs = table_differences(tmp_path / "a", tmp_path / "c")
    assert diffs == ["06_claims.csv: row 2, 'contrast (claim: < 0)': 10.7 [8.3, 13.1] vs 10.8 [8.3, 13.1]"], diffs
