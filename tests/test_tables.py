"""Tables from evaluation metrics (synthetic metrics from hbeo.evaluation.evaluate.summarize)."""
import copy

import numpy as np
import pandas as pd
import pytest

from hbeo.evaluation import protocol
from hbeo.report import tables
from hbeo.conventions import CLASSES
from hbeo.evaluation.evaluate import summarize
from hbeo.rotations import uniform_so3


def fake_metrics(method, pose, accuracy, pose_err_deg, iou_shift=0, given=False, n=40, seed=0):
    """Metrics of n queries over all classes with the given accuracy and a fixed pose error."""
    rng = np.random.default_rng(seed)
    from scipy.spatial.transform import Rotation
    truth = np.zeros((30, 30, 30), bool)
    truth[8:22, 8:22, 8:22] = True
    pred_grid = np.roll(truth, iou_shift, axis=0)
    R = uniform_so3(n, rng)
    tilt = Rotation.from_euler("x", pose_err_deg, degrees=True).as_matrix()
    rows = []
    for i in range(n):
        c = CLASSES[i % len(CLASSES)]
        ok = i < round(accuracy * n)
        rows.append({"class": c, "pred": c if ok else CLASSES[(i + 1) % len(CLASSES)], "R_true": R[i],
                     "R_pred": R[i] @ tilt, "grid": pred_grid, "truth": truth, "ms": 5.0,
                     "mean_pred": truth.astype(np.float32) * 0.6, "mean_true": truth.astype(np.float32) * 0.6})
    m = summarize(rows, CLASSES, "procedural", "test", 1, 0, "so3", False, n)
    return {"method": method, "pose": pose, "given_class": given, **m}


@pytest.fixture(scope="module")
def _evals():
    """Built once (~1 s); each test gets its own copy."""
    return [fake_metrics("hbeo", "3dof", 0.8, 20), fake_metrics("beo", "known", 0.7, 0, iou_shift=2),
            fake_metrics("beo", "1dof", 0.5, 30, iou_shift=3), fake_metrics("beo", "3dof", 1.0, 60, given=True),
            fake_metrics("icp", "3dof", 1.0, 90, given=True), fake_metrics("voxcnn", "known", 0.6, 0, iou_shift=1)]


@pytest.fixture
def evals(_evals):
    return copy.deepcopy(_evals)


def test_table1_has_reproduced_and_reported_rows_and_skips_given_class(evals):
    t = tables.table1(evals, tables.paper_table("table1_classification"))
    rep = t[t.source == "reproduced"]
    assert set(rep.method) == {"HBEO (3-DOF)", "BEO (known pose)", "BEO (1-DOF)",
                               "3-D CNN on partial grid (known pose)"}      # given-class settings left out
    assert rep.set_index("method").loc["HBEO (3-DOF)", "total"] == pytest.approx(80)
    paper = t[t.source == "reported"].set_index("method")
    assert paper.loc["HBEO", "total"] == 81.8 and paper.loc["3DShapeNets", "total"] == 54.4
    assert list(t.setting.unique()) == ["known", "1dof", "3dof"]            # paper order
    md = tables.to_markdown(t)
    assert md.count("\n") == len(t) + 1 and "| reported |" in md
    assert md.splitlines()[-1].endswith("| 80.0 | 40 |")              # query counts stay integers


def test_pose_completion_runtime_tables(evals):
    ps = tables.pose_summary(evals).set_index("method")
    assert ps.loc["HBEO (3-DOF)", "mean (°, the paper's statistic)"] == pytest.approx(20, abs=1e-3)
    assert ps.loc["ICP (3-DOF, true class)", "median (°)"] == pytest.approx(90, abs=1e-3)
    assert ps.loc["ICP (3-DOF, true class)", "p25 (°)"] == pytest.approx(90, abs=1e-3)
    assert "BEO (known pose)" not in ps.index
    cs = tables.completion_summary(evals).set_index("method")
    assert cs.loc["HBEO (3-DOF)", "IoU median"] == 1.0 and cs.loc["BEO (known pose)", "IoU median"] < 1.0
    assert cs.loc["HBEO (3-DOF)", "empty completions"] == 0
    assert "class mean shape (HBEO's class)" in cs.index
    t2 = tables.table2(evals, tables.paper_table("table2_runtime")).set_index("method")
    assert t2.loc["HBEO (3-DOF)", "median (s)"] == pytest.approx(0.005)
    assert t2.loc["HBEO (3-DOF)", "paper: mean (s)"] == pytest.approx(0.01)
    assert t2.loc["BEO (1-DOF)", "paper: mean (s)"] == pytest.approx(672.97)
    assert "3dshapenets (known), reported only" in t2.index


def test_markdown_formats_missing_values():
    md = tables.to_markdown(pd.DataFrame({"a": ["x", "y"], "b": [1.25, np.nan]}))
    assert md.splitlines()[2] == "| x | 1.2 |" and md.splitlines()[3] == "| y | – |"


def test_eval_per_class_follows_the_profile():
    from hbeo import config
    assert protocol.eval_per_class("ci", "hbeo", "3dof") == 3                 # the profile's test split
    assert protocol.eval_per_class("ci", "beo", "3dof") == 1                  # BEO's search sees fewer
    assert protocol.eval_per_class("ci", "beo", "1dof") == 3
    assert protocol.eval_per_class("cpu", "beo", "1dof") is None              # cpu: every test object
    assert protocol.eval_plan("cpu", "hbeo", "3dof") == (None, 3)             # three paired views each
    assert protocol.eval_plan("cpu", "beo", "3dof") == (10, 1)                # the searches: view 0 of 10/class
    assert protocol.eval_plan("cpu", "icp", "3dof") == (10, 1)
    assert protocol.eval_per_class("full", "beo", "3dof") == 5
    assert protocol.eval_per_class("full", "hbeo", "3dof") is None            # all there is
    more = config.get_profile("ci", beo_3dof_test_per_class=50)
    assert protocol.eval_per_class(more, "beo", "3dof") == 3                  # never more than the split


def test_worse_than_chance_names_the_evaluations(evals):
    assert tables.worse_than_chance(evals) == []
    bad = fake_metrics("beo", "1dof", 0.1, 30)                                # 4 of 40 right, 10 classes
    assert tables.worse_than_chance([*evals, bad]) == ["BEO (1-DOF)"]


def test_tables_written_into_the_run_feed_the_report(evals, tmp_path):
    from hbeo.report.reproduction_md import write_reproduction
    from hbeo.rundir import RunDir
    run = RunDir(tmp_path / "run").create()
    t1 = tables.table1(evals, tables.paper_table("table1_classification"))
    assert tables.TABLE1 == "05_table1"                                      # the committed runs' file names
    paths = tables.save_table(t1, run, tables.TABLE1, note="\n\nnote\n")
    assert paths == (run.table("05_table1"), run.table("05_table1", "md"))
    assert pd.read_csv(run.table("05_table1")).shape == t1.shape
    assert run.table("05_table1", "md").read_text() == tables.to_markdown(t1) + "\n\nnote\n"
    tables.save_table(t1, run, "wide", markdown=t1.head(1))                 # the Markdown can show another view
    assert run.table("wide", "md").read_text() == tables.to_markdown(t1.head(1))
    assert not list(run.path.glob(".*.tmp"))                                 # written through temporary names
    out = write_reproduction(run, tmp_path / "paper" / "REPRODUCTION.md")
    text = out.read_text()
    assert tables.to_markdown(t1) in text
    assert "*(missing: 06_pose.md" in text and "*(missing: 06_pose_error.png)*" in text
    (run.path / "06_pose_error.png").write_bytes(b"png")
    assert "](../run/06_pose_error.png)" in write_reproduction(run, out).read_text()     # linked once it exists
    assert "## Deviations from the paper" in text


def test_the_resolution_line_comes_from_the_studys_files_or_is_absent(tmp_path):
    import json as _json
    from hbeo.report import reproduction_md as md
    assert md._resolution_line(tmp_path) == []                    # no study: no line
    for i, (_, f, paired) in enumerate(md.RESOLUTION_FILES):
        (tmp_path / f).write_text(_json.dumps({"class_mean_accuracy": 0.7 - 0.01 * i}))
        if paired:
            (tmp_path / paired).write_text(_json.dumps({"contrasts": {"class_accuracy": {
                "value": -0.01 * i, "low": -0.03, "high": 0.004, "n_objects": 397}}}))
    (line,) = md._resolution_line(tmp_path)
    assert "80×60 70.0 %" in line and "120×90 69.0 % (-1.0 points [-3.0, +0.4], 397 objects)" in line
    assert "160×120 68.0 % (-2.0 points" in line
    (tmp_path / md.RESOLUTION_FILES[2][2]).unlink()               # one paired file missing: no line
    assert md._resolution_line(tmp_path) == []


def test_the_report_names_the_command_that_makes_its_run_folder(tmp_path, monkeypatch):
    """REPRODUCTION.md's command: make reproduce (with SEED for a seed other than 0) for the default folder, else
    reproduce --out with the folder; its first paragraph names the training seed."""
    from hbeo.report.provenance import reproduce_command
    from hbeo.rundir import RunDir
    monkeypatch.setenv("HBEO_RESULTS", str(tmp_path))
    how = ("cpu", "modelnet10-vox30")
    seed1 = RunDir(tmp_path / "cpu-modelnet10-vox30-seed1")
    assert reproduce_command(seed1, *how, 1) == "make reproduce PROFILE=cpu DATASET=modelnet10-vox30 SEED=1"
    assert reproduce_command(RunDir(tmp_path / "cpu-modelnet10-vox30"), *how, 0) == \
        "make reproduce PROFILE=cpu DATASET=modelnet10-vox30"
    other = reproduce_command(RunDir(tmp_path / "elsewhere"), *how, 1)
    assert other.startswith("python -m hbeo reproduce --profile cpu --dataset modelnet10-vox30 --seed 1 --fresh --out ")
    assert other.endswith("elsewhere")
