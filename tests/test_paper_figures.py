"""The figures of notebooks 05-07 and the summary tables behind them, on tiny hand-made metrics dicts:
one colour per method, the right "better" direction per metric, legends outside the data, empty
completions counted apart, medians and interquartile ranges from the per-query columns."""
import matplotlib

matplotlib.use("Agg")

import matplotlib.colors as mcolors  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
import pytest  # noqa: E402

from hbeo.conventions import CLASSES  # noqa: E402
from hbeo.evaluation import method  # noqa: E402
from hbeo.report import figures, paper_figures as pf, tables  # noqa: E402
from hbeo.subspace.metrics import edt_error, iou, naive_error  # noqa: E402

KEYS = [("hbeo", "3dof"), ("beo", "known"), ("beo", "1dof"), ("beo", "3dof"), ("icp", "3dof"), ("voxcnn", "known"),
        figures.CLASS_MEAN, figures.HBEO_VERIFY]


def metrics(method, pose, edt, naive, io, ms, pose_deg=None, verify=None, empty_fraction=None, baseline=None):
    """A metrics dict with the per-query columns given (classes cycled) and summary fields from them."""
    n = len(edt)
    cls = [CLASSES[i % len(CLASSES)] for i in range(n)]
    pose_deg = list(pose_deg if pose_deg is not None else np.linspace(5, 150, n))
    empty = (np.asarray(io) == 0) & (np.asarray(naive) == 0)
    q = {"object": [f"o{i}" for i in range(n)], "view": [0] * n, "class": cls, "pred": cls, "pose_deg": pose_deg,
         "pose_sym_deg": [min(p, 180 - p) for p in pose_deg], "edt": list(edt), "naive": list(naive), "iou": list(io),
         "ms": list(ms)}
    m = {"method": method, "pose": pose, "verify": verify, "given_class": False, "n_queries": n, "accuracy": 1.0,
         "classes": list(CLASSES), "per_query": q,
         "completion": {"edt": float(np.mean(edt)), "naive": float(np.mean(naive)), "iou": float(np.mean(io)),
                        "empty_fraction": float(empty.mean()) if empty_fraction is None else empty_fraction},
         "runtime_ms": {"mean_per_query": float(np.mean(ms)), "median_per_query": float(np.median(ms))},
         "pose_error_deg": {"mean": float(np.mean(pose_deg))}}
    if baseline is not None:
        m["completion_baseline"] = {"predicted_class": baseline}
    return m


@pytest.fixture
def evals():
    """HBEO with one empty completion of four (the last: IoU 0 and naive e exactly 0), BEO without."""
    hbeo = metrics("hbeo", "3dof", edt=[100, 200, 300, 5000], naive=[0.5, 0.2, -0.1, 0.0], io=[0.6, 0.4, 0.0, 0.0],
                   ms=[1, 2, 3, 4, 100][:4], pose_deg=[10, 20, 30, 170],
                   baseline={"edt": 900.0, "naive": 0.05, "iou": 0.25})
    beo = metrics("beo", "known", edt=[50, 60, 70, 80], naive=[0.6, 0.5, 0.4, 0.3], io=[0.9, 0.8, 0.7, 0.6],
                  ms=[10, 20, 30, 40], pose_deg=[0, 0, 0, 0])
    icp = metrics("icp", "3dof", edt=[400, 500, 600, 700], naive=[0.1, 0.0, -0.2, -0.3], io=[0.3, 0.2, 0.1, 0.05],
                  ms=[90, 100, 110, 120], pose_deg=[5, 60, 120, 175])
    ver = metrics("hbeo-verify", "3dof", edt=[90, 150, 250, 400], naive=[0.5, 0.3, 0.1, 0.0], io=[0.7, 0.5, 0.3, 0.1],
                  ms=[20, 25, 30, 35], pose_deg=[3, 6, 9, 12], verify={"tau": 1})
    return [hbeo, ver, beo, icp]


def test_one_distinct_colour_per_method():
    colors = [figures.method_color(k) for k in KEYS]
    assert len(set(colors)) == len(KEYS)                          # every method key covered, all distinct
    assert figures.OTHER_COLOR not in colors                        # no key falls back to the default
    assert figures.method_color(figures.CLASS_MEAN) != figures.method_color(("hbeo", "3dof"))
    assert len(set(figures.METHOD_COLORS.values())) == len(figures.METHOD_COLORS)
    # the paper's shade is the same hue, lighter
    dark, light = (np.array(mcolors.to_rgb(figures.method_color(("beo", "1dof"), s))) for s in ("dark", "light"))
    assert np.all(light >= dark) and light.sum() > dark.sum() + 0.5
    assert np.allclose(light, dark + 0.5 * (1 - dark), atol=1 / 255)
    with pytest.raises(ValueError):
        figures.method_color(("hbeo", "3dof"), "medium")


def test_metrics_and_table_rows_find_their_colour(evals):
    hbeo, ver, beo, icp = evals
    assert figures.method_key(hbeo) == ("hbeo", "3dof") and figures.method_key(beo) == ("beo", "known")
    assert figures.method_key(ver) == figures.HBEO_VERIFY
    assert figures.method_key({**hbeo, "verify": {"tau": 1}}) == figures.HBEO_VERIFY     # verify on the hbeo key
    assert figures.method_color(hbeo) == figures.METHOD_COLORS[("hbeo", "3dof")]
    for key, name in method.LABELS.items():                         # every table label maps back to its key
        want = {"class_mean": figures.CLASS_MEAN, "hbeo-verify": figures.HBEO_VERIFY}.get(key[0], key)
        assert pf.row_key(name) == want, name
    assert pf.row_key(method.label(ver)) == figures.HBEO_VERIFY
    assert pf.row_key("3dshapenets (known), reported only") == ("3dshapenets", "known")
    assert pf.row_key("BEO", "1dof") == ("beo", "1dof")              # Table I's reported rows


def test_better_directions_follow_the_metric_definitions():
    t = np.zeros((30, 30, 30), bool)
    t[8:22, 8:22, 8:22] = True
    worse = np.roll(t, 3, axis=0)
    assert edt_error(t, t) == 0 < edt_error(t, worse)              # e': an error, 0 is perfect
    assert naive_error(t, t) == 1 > naive_error(t, worse)          # e = 1 - |o - o^|/|o|: 1 is perfect
    assert iou(t, t) == 1 > iou(t, worse)
    assert pf.BETTER["edt"] == pf.LOWER == "↓ lower is better"
    assert pf.BETTER["naive"] == pf.HIGHER == "↑ higher is better"
    assert pf.BETTER["iou"] == pf.HIGHER and pf.BETTER["pose_deg"] == pf.LOWER and pf.BETTER["ms"] == pf.LOWER


def _figures(evals):
    cs = tables.completion_summary(evals)
    t2 = tables.table2(evals, tables.paper_table("table2_runtime"))
    t1 = pd.DataFrame([{"source": "reported", "setting": "known", "method": "BEO", **{c: 50.0 for c in CLASSES}},
                       {"source": "reproduced", "setting": "known", "method": method.label(evals[2]),
                        **{c: 70.0 for c in CLASSES}}])
    hw = {"cpu": "Test CPU", "cores": 2, "gpu": None, "torch_threads": 2}
    return {"pose": pf.pose_errors([evals[0], evals[1], evals[3]]), "completion": pf.completion_bars(cs, evals),
            "runtime": pf.runtime_bars(t2, hw), "per_class": pf.per_class_bars(t1)}



def test_the_runtime_legend_names_the_machine_the_evaluations_record(evals):
    """The legend names the machine the files were timed on, not the one making the figure (``hw``)."""
    t2 = tables.table2(evals, tables.paper_table("table2_runtime"))
    here = {"cpu": "Here CPU", "cores": 16, "gpu": "Some GPU", "torch_threads": 16}
    there = {"cpu": "There CPU", "cores": 2, "gpu": None, "torch_threads": 2}

    def legend(files):
        fig = pf.runtime_bars(t2, here, files)
        return " ".join(t.get_text() for leg in fig.legends for t in leg.get_texts())

    assert "2-core CPU, no GPU, torch threads 2" in legend([dict(m, hardware=there) for m in evals])
    mixed = [dict(m, hardware=there if i else dict(there, cpu="Other CPU")) for i, m in enumerate(evals)]
    assert "several machines" in legend(mixed) and "16-core" not in legend(mixed)
    assert "several machines" in legend(evals)                       # files that do not record one
    assert "16-core CPU, Some GPU, torch threads 16" in legend(())

def test_figures_label_every_panel_and_keep_the_legend_off_the_data(evals):
    for name, fig in _figures(evals).items():
        fig.canvas.draw()
        r = fig.canvas.get_renderer()
        assert len(fig.legends) == 1, name                         # one figure legend ...
        box = fig.legends[0].get_window_extent(r)
        for ax in fig.axes:
            assert not box.overlaps(ax.get_window_extent(r)), name  # ... outside every panel
            assert not ax.get_legend(), name                       # and none inside a panel
            assert ax.get_title() and ax.get_xlabel(), name
        assert fig.axes[0].get_ylabel(), name
        plt.close(fig)


def test_figures_use_the_method_colours_and_direction_labels(evals):
    figs = _figures(evals)
    comp = figs["completion"].axes
    assert "lower is better" in comp[0].get_xlabel() and "lower is better" in comp[0].get_title()
    assert "higher is better" in comp[1].get_xlabel() and "higher is better" in comp[2].get_xlabel()
    assert "lower" not in comp[1].get_xlabel() + comp[1].get_title()         # naive e: higher is better
    assert comp[0].get_xscale() == "log"
    assert "1 of 4 completions empty" in figs["completion"].get_suptitle()
    ticks = [t.get_text() for t in comp[0].get_yticklabels()]
    assert "n=4, 1 empty" in ticks[0] and "(mean only)" in ticks[1]            # HBEO, then its class-mean row
    boxes = [p for p in comp[0].patches if p.get_facecolor()[3] > 0]
    assert mcolors.to_hex(boxes[0].get_facecolor(), keep_alpha=False) == figures.method_color(("hbeo", "3dof"))
    pose = figs["pose"].axes[0]
    bodies = [c for c in pose.collections if isinstance(c, PolyCollection)]
    assert [mcolors.to_hex(b.get_facecolor()[0], keep_alpha=False) for b in bodies] == \
        [figures.method_color(k) for k in (("hbeo", "3dof"), figures.HBEO_VERIFY, ("icp", "3dof"))]
    assert "lower is better" in pose.get_ylabel()
    run = figs["runtime"].axes[0]
    bars = [p for p in run.patches if p.get_width() > 0]
    assert bars[0].get_width() == pytest.approx(0.0025)                        # HBEO median of 1-4 ms
    assert mcolors.to_hex(bars[0].get_facecolor(), keep_alpha=False) == figures.method_color(("hbeo", "3dof"))
    assert bars[1].get_width() == pytest.approx(0.01)                          # the paper's HBEO mean, light
    assert mcolors.to_hex(bars[1].get_facecolor(), keep_alpha=False) == figures.method_color(("hbeo", "3dof"), "light")
    assert run.get_xscale() == "log"
    for fig in figs.values():
        plt.close(fig)


def test_completion_summary_counts_empty_completions_apart(evals):
    cs = tables.completion_summary(evals).set_index("method")
    h = cs.loc["HBEO (3-DOF)"]
    assert h["empty completions"] == 1
    assert h["EDT e' median"] == pytest.approx(250) and h["EDT e' p25"] == pytest.approx(175)
    assert h["EDT e' p75"] == pytest.approx(1475)
    assert h["EDT e' mean"] == pytest.approx(1400)                             # the empty one inflates the mean
    assert h["EDT e' mean, non-empty"] == pytest.approx(200) and h["EDT e' median, non-empty"] == pytest.approx(200)
    assert h["IoU median"] == pytest.approx(0.2) and h["naive e median"] == pytest.approx(0.1)
    assert cs.loc["BEO (known pose)", "empty completions"] == 0
    assert cs.loc["ICP (3-DOF, true class)", "empty completions"] == 0           # naive 0 alone is not empty
    mean = cs.loc["class mean shape (HBEO's class)"]
    assert mean["EDT e' mean"] == 900 and np.isnan(mean["EDT e' median"])       # no per-query scores: mean only
    assert list(cs.index).count("class mean shape (HBEO's class)") == 1         # not again for the verify run
    bad = [{**evals[0], "completion": {**evals[0]["completion"], "empty_fraction": 0.5}}]
    with pytest.raises(ValueError, match="empty"):                             # disagrees with the metrics
        tables.completion_summary(bad)


def test_completion_summary_uses_an_empty_column_and_baseline_scores_when_given(evals):
    h = evals[0]
    q = {**h["per_query"], "empty": [False, False, True, True], "baseline_edt": [1, 2, 3, 4],
         "baseline_naive": [0.1, 0.2, 0.0, 0.4], "baseline_iou": [0.3, 0.3, 0.0, 0.3]}
    m = {**h, "per_query": q, "completion": {**h["completion"], "empty_fraction": 0.5}}
    cs = tables.completion_summary([m]).set_index("method")
    assert cs.loc["HBEO (3-DOF)", "empty completions"] == 2
    assert cs.loc["HBEO (3-DOF)", "EDT e' mean, non-empty"] == pytest.approx(150)
    assert cs.loc["class mean shape (HBEO's class)", "EDT e' median"] == pytest.approx(2.5)
    assert cs.loc["class mean shape (HBEO's class)", "empty completions"] == 1


def test_table2_gives_median_and_iqr_from_per_query_times(evals):
    evals[0]["per_query"]["ms"] = [1, 2, 3, 4, 100]
    evals[0]["n_queries"] = 5
    t2 = tables.table2(evals, tables.paper_table("table2_runtime")).set_index("method")
    h = t2.loc["HBEO (3-DOF)"]
    assert (h["median (s)"], h["p25 (s)"], h["p75 (s)"]) == pytest.approx((0.003, 0.002, 0.004))
    assert h["mean (s)"] == pytest.approx(0.022) and h["paper: mean (s)"] == pytest.approx(0.01)
    b = t2.loc["BEO (known pose)"]
    assert (b["median (s)"], b["p25 (s)"], b["p75 (s)"]) == pytest.approx((0.025, 0.0175, 0.0325))
    assert b["paper: mean (s)"] == pytest.approx(1.13)
    assert np.isnan(t2.loc[method.label(evals[1]), "paper: mean (s)"])     # HBEO + verify: not the paper's method
    assert t2.loc["3dshapenets (known), reported only", "paper: mean (s)"] == pytest.approx(3.57)
    assert t2.loc["beo (3dof), reported only", "paper: mean (s)"] == pytest.approx(3529.88)


def test_table2_note_records_the_hardware():
    note = tables.table2_note({"cpu": "Test CPU 9000", "cores": 16, "gpu": "NVIDIA H100", "torch_threads": 8})
    assert "Test CPU 9000" in note and "16 cores" in note and "NVIDIA H100" in note and "torch threads: 8" in note
    assert "median" in note and "GTX 1070" in note
    assert "GPU: none" in tables.table2_note({"cpu": "c", "cores": 2, "gpu": None, "torch_threads": 1})


def test_table2_note_names_the_machines_that_timed_the_evaluations():
    """The times come from the evaluation files, each made where it ran: the note names their machines (rows of
    each when they differ), and says which files did not record one, not the machine the table is made on."""
    here = {"cpu": "Here CPU", "cores": 2, "gpu": None, "torch_threads": 2}
    a, b = {**here, "cpu": "EPYC"}, {**here, "cpu": "Xeon", "cores": 4}
    hbeo = {"method": "hbeo", "pose": "3dof", "hardware": a}
    beo = {"method": "beo", "pose": "3dof", "hardware": a}
    note = tables.table2_note(here, [hbeo, beo])
    assert "Timed on: EPYC, 2 cores" in note and "Here CPU" not in note and "(HBEO" not in note
    note = tables.table2_note(here, [hbeo, {**beo, "hardware": b}])
    assert "EPYC, 2 cores, GPU: none, torch threads: 2 (HBEO (3-DOF))" in note and "Xeon, 4 cores" in note
    old = {k: v for k, v in beo.items() if k != "hardware"}
    note = tables.table2_note(here, [hbeo, old])
    assert "(HBEO (3-DOF))" in note and "Not recorded for BEO (3-DOF" in note and "made on Here CPU" in note


def test_pose_summary_reports_median_iqr_and_the_paper_mean(evals):
    ps = tables.pose_summary(evals).set_index("method")
    h = ps.loc["HBEO (3-DOF)"]
    assert (h["median (°)"], h["p25 (°)"], h["p75 (°)"]) == pytest.approx((25, 17.5, 65))
    assert h["mean (°, the paper's statistic)"] == pytest.approx(57.5)
    assert h["median mod. symmetry (°)"] == pytest.approx(15)                # 10, 20, 30, 10
    assert h["share < 30° (%)"] == pytest.approx(50)
    assert "BEO (known pose)" not in ps.index
    stats = [c for c in ps.columns if c not in ("queries", "share < 30° (%)")]
    assert all(c.split()[0] in ("median", "p25", "p75", "mean") for c in stats)


def test_the_completion_gallery_titles_an_empty_completion():
    """A blank panel says why it is blank: the empty completion's title says so, a filled one's does not."""
    g = np.zeros((30, 30, 30), bool)
    g[10:20, 10:20, 10:20] = True
    s = {"depth": np.ones((6, 8)), "class": "chair", "truth": g, "hbeo": g, "beo": np.zeros_like(g),
         "hbeo_class": "chair", "beo_class": "table"}
    fig = pf.completion_gallery([s])
    titles = [a.get_title() for a in fig.axes]
    plt.close(fig)
    assert titles[2] == "HBEO: chair" and titles[3] == "BEO known pose: table\n(empty completion)"


def test_the_verified_label_names_rolls_only_when_the_answers_averaged_rolls(evals):
    ver = evals[1]
    assert method.label({**ver, "rolls": 4}) == "HBEO + rolls + verify (3-DOF, ours)"
    assert method.label({**ver, "rolls": 1}) == "HBEO + verify (3-DOF, ours)"     # a model without rotation bins
    assert pf.row_key(method.label({**ver, "rolls": 1})) == figures.HBEO_VERIFY
