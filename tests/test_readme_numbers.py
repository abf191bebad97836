"""Every figure in the README, the documentation's pages and paper/REPRODUCTION.md comes from a committed file.

- ``paper/REPRODUCTION.md`` is exactly what :func:`hbeo.report.reproduction_md.reproduction_text` writes from the
  committed reference run, and every file it links to is committed;
- the generated blocks are exactly what the committed files give: the README's verdict and command table
  (``benchmarks/commands.json``), the docs' subspace figures, and the docs' model and targets tables
  (``tests/test_model_table.py``);
- outside generated blocks and code, the README and the docs' pages quote no result figure by hand: every
  percentage, angle or 0.xx figure in their prose is a setting (checked against the code where the code holds
  it) or traced to the committed file that measured it (the figure must appear there);
- the README stays a summary: at most :data:`README_WORDS` words.
"""
import re
from pathlib import Path

import pytest

from hbeo.report import readme, reproduction_md as report
from hbeo.report.model_table import BEGIN, END
from hbeo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
RUN = RunDir(ROOT / "results" / "cpu-modelnet10-vox30")
README = ROOT / "README.md"
#: The documentation's pages (``make docs``); ``docs/history/`` holds dated logs, not pages.
DOCS = sorted((ROOT / "docs").glob("*.md"))
#: The README's length limit, in words as ``wc -w`` counts them (whitespace-separated).
README_WORDS = 1500


def _settings() -> dict[str, str]:
    """Figures in the README's prose that are settings, not results: figure -> what it is (those the code holds
    are checked below; 14°, 15°, 30°, 180° and 0.001, mm to m, are definitions, derived or units)."""
    return {"63°": "the Kinect-like camera's horizontal field of view", "60 %": "VBPCA's variance fraction",
            "10 %": "the validation fraction", "0.45": "verify's min_agreement", "14°": "rotation-bin spacing",
            "10°": "rotation-bin target smoothing", "40°": "rotation-bin decoding window", "95 %": "interval level",
            "30°": "the within-30° threshold", "180°": "a front-back flip",
            "170°": "predict's largest field of view", "90 %": "predict's in-view share", "15°": "a benchmark threshold",
            "0.001": "the default depth scale (metres per stored unit)"}


#: Figures in the README's prose measured elsewhere: figure -> the committed file that holds it.
TRACED = {"53 %": "benchmarks/README.md", "89 %": "benchmarks/README.md", "0.98": "benchmarks/README.md",
          "0.83": "benchmarks/README.md", "34.2 %": "docs/history/gpu-lease-modelnet10-vox30/lease-2026-11-26/README.md",
          **dict.fromkeys(("88°", "11°", "82°", "14°", "74.8 %", "76.0 %", "0.15", "0.30"), "docs/history/recenter-at-inference-2026-12-06/README.md"),
          **dict.fromkeys(("80.7 %", "80.5 %"), "docs/history/quick-procedural-avx2-bbb78f2/README.md"),
          "65.0 %": "results/cpu-modelnet10-vox30/model_table.md"}
FIGURE = re.compile(r"(?<![\w.])(\d+(?:[.,]\d+)?\s?(?:%|°)|0\.\d{2,})")


def _prose(text: str) -> str:
    text = re.sub(r"<!-- (\S+):.*?<!-- /\1 -->", "", text, flags=re.S)      # generated blocks
    return re.sub(r"```.*?```", "", text, flags=re.S)                        # code


def test_settings_quoted_in_the_readme_are_the_code_s():
    import math
    from hbeo import conventions as C
    from hbeo.data.datasets import VAL_FRACTION
    from hbeo.run import VARIANCE
    from hbeo.model.verify import VerifyConfig
    from hbeo.evaluation.paired import LEVEL
    K = C.Intrinsics.kinect(640, 480)
    assert round(math.degrees(2 * math.atan(K.width / 2 / K.fx))) == 63
    assert VARIANCE == 0.6 and VAL_FRACTION == 0.1 and LEVEL == 0.95 and VerifyConfig().min_agreement == 0.45
    import inspect
    from hbeo.model.depthfile import FOV_RANGE_DEG
    from hbeo.model.viewcheck import MIN_COVERAGE
    from hbeo.model.network import HBEONet, NetConfig
    sigma = NetConfig().bin_sigma_deg
    assert sigma == 10 and "4.0 * self.cfg.bin_sigma_deg" in inspect.getsource(HBEONet.pose_matrix)   # 10°, 40°
    assert FOV_RANGE_DEG[1] == 170 and MIN_COVERAGE == 0.9


@pytest.mark.parametrize("page", [README, *DOCS], ids=lambda p: p.relative_to(ROOT).as_posix())
def test_prose_quotes_no_result_by_hand(page):
    found = set(m.group(0) for m in FIGURE.finditer(_prose(page.read_text())))
    unexplained = found - set(_settings()) - set(TRACED)
    assert not unexplained, (f"figures typed into {page.name} outside generated blocks: {sorted(unexplained)}; "
                             f"generate them from a committed file, or trace them in {__file__}")
    for fig, source in TRACED.items():
        assert fig in (ROOT / source).read_text(), f"{fig} is not in {source}"


def test_readme_is_a_summary():
    words = len(README.read_text().split())
    assert words <= README_WORDS, f"README.md has {words} words (wc -w), more than {README_WORDS}: move detail to docs/"


def test_the_lint_catches_a_typed_figure():
    assert FIGURE.findall(_prose("HBEO reaches 73.7 % and a 25.8° median, IoU 0.446.\n")) == ["73.7 %", "25.8°",
                                                                                            "0.446"]
    assert FIGURE.findall(_prose(f"{readme.SUMMARY_BEGIN}\n73.7 %\n{readme.SUMMARY_END}\n")) == []


#: Where each generated block lives: the README's verdict and command table, the method page's subspace figures.
BLOCK_HOME = {readme.SUMMARY_BEGIN: README, readme.COMMANDS_BEGIN: README,
              readme.SUBSPACE_BEGIN: ROOT / "docs" / "method.md"}


@pytest.mark.parametrize("begin,end,fn", readme.README_BLOCKS)
def test_generated_blocks_are_what_the_committed_files_give(begin, end, fn):
    holders = [p for p in [README, *DOCS] if begin in p.read_text()]
    assert holders == [BLOCK_HOME[begin]], f"{begin[:30]}...: in {holders}, expected in {BLOCK_HOME[begin]} alone"
    text = holders[0].read_text()
    assert text.count(begin) == 1 and text.count(end) == 1
    block = text[text.index(begin) + len(begin):text.index(end)]
    assert block == "\n" + fn(RUN), "stale block: run python -m hbeo report --run RUN --readme README.md"
    assert readme.block_files(README) == [README, *sorted((ROOT / "docs").glob("*.md"))]   # one command fills all


def test_the_verdict_sets_the_paper_beside_the_run():
    """The verdict's paper column is the paper's Table I row as a class mean (HBEO's total is one), the others'
    own totals beside; its first row is HBEO's class-mean accuracy."""
    text = readme.summary(RUN)
    rows = [r for r in text.splitlines() if r.startswith("| ")][2:]
    assert rows[0].startswith("| Table I, class-mean accuracy | HBEO (3-DOF) | 907 / 2721 |") and rows[0].endswith("| 81.8 % |")
    assert rows[1].endswith("| 74.0 % (total 76.3 %) |") and "in place of 3DShapeNets" in rows[3]
    assert "2 of 9 hold, 7 fail, 0 inconclusive" in text and "Over 3 training seeds (0, 1, 2" in text
    assert "tag" not in text                                       # commits, not tags



def test_the_verdict_counts_a_claim_about_time_from_two_machines_apart(tmp_path):
    """A run whose speed claim was timed on two machines (``paired.NOT_COMPARABLE``) says so in the counts."""
    import pandas as pd
    from hbeo.evaluation.paired import NOT_COMPARABLE
    from hbeo.report import tables as T
    ref = tmp_path / RUN.path.name
    ref.mkdir()
    for f in RUN.path.iterdir():
        (ref / f.name).symlink_to(f)
    claims = RUN.table(T.CLAIMS)
    (ref / claims.name).unlink()
    t = pd.read_csv(claims)
    t.loc[t["claim (paper)"].str.contains("faster"), "verdict"] = NOT_COMPARABLE
    t.to_csv(ref / claims.name, index=False)
    text = readme.summary(ref)
    assert "- HBEO (3-DOF): 1 of 9 hold, 7 fail, 0 inconclusive, 1 not comparable (timed on different machines)." \
        in text

def test_a_run_at_the_paper_s_scale_joins_the_verdict_under_the_reference_run_s_hbeo_rows(tmp_path):
    """Until a lease's run lands beside the reference run the verdict says the paper's scale has not run; once
    ``results/full-modelnet10-vox30/`` holds ``lease.json`` and HBEO's evaluation, each HBEO row gets its row."""
    import json
    import shutil
    ref = tmp_path / RUN.path.name
    ref.symlink_to(RUN.path)
    before = readme.summary(ref)
    assert "At the paper's scale (the `full` profile on one GPU" in before and "not yet run" in before
    full = tmp_path / readme.PAPER_SCALE
    full.mkdir()
    (full / "lease.json").write_text(json.dumps({"profile": "full", "images_seen": 12_902_400}))
    shutil.copyfile(RUN.evaluation("hbeo", "3dof"), RunDir(full).evaluation("hbeo", "3dof"))   # a stand-in
    after = readme.summary(ref)
    assert "not yet run" not in after
    rows = [r for r in after.splitlines() if r.startswith("| ")][2:]
    scaled = [i for i, r in enumerate(rows) if "at the paper's scale" in r]
    assert len(scaled) == 1 + len(readme.VERDICT_HBEO)                  # class mean, then pose and completion
    for i in scaled:                                                      # each under the reference run's HBEO row
        assert "| HBEO (3-DOF) |" in rows[i - 1] and "12.90 M image passes on one GPU" in rows[i]
        assert rows[i].split(" | ")[2:] == rows[i - 1].split(" | ")[2:]   # the stand-in: the same figures
    assert rows[scaled[0]].startswith("|  | HBEO (3-DOF) at the paper's scale")
    # a lease whose evaluation did not come back, evaluated at landing on a CPU (device_land.py --evaluate-here)
    (full / "lease.json").write_text(json.dumps({"profile": "full", "images_seen": 12_902_400,
                                                 "evaluated_here": "cpu: 2 cores"}))
    rows = [r for r in readme.summary(ref).splitlines() if "at the paper's scale" in r]
    assert len(rows) == len(scaled) and all("image passes on one GPU, evaluated on a CPU)" in r for r in rows)


def test_the_model_table_lives_in_the_docs_not_the_readme():
    """The long model and targets tables are generated into docs/experiments.md (checked there by
    test_model_table); the README only links to it."""
    from hbeo.report.model_table import TARGETS_BEGIN, TARGETS_END
    assert BEGIN not in README.read_text() and TARGETS_BEGIN not in README.read_text()
    page = (ROOT / "docs" / "experiments.md").read_text()
    assert all(page.count(marker) == 1 for marker in (BEGIN, END, TARGETS_BEGIN, TARGETS_END))


def test_the_command_table_is_the_data_file_s(tmp_path):
    """benchmarks/commands.json: every entry complete, a measured value only with its date and source, and the
    reference run's entry the run's own manifest figures; null renders as the entry's pending text."""
    import json
    entries = readme.command_entries()
    assert [e["command"].split(" --")[0] for e in entries][:3] == [
        "make test", "make reproduce", "make reproduce PROFILE=cpu DATASET=modelnet10-vox30"]
    ref = next(e for e in entries if e["command"] == "make reproduce PROFILE=cpu DATASET=modelnet10-vox30")
    man = json.loads(RUN.manifest.read_text())
    assert ref["wall_min"] == round(man["wall_time_total_s"] / 60) and ref["cores"] == man["hardware"]["cores"]
    assert "manifest.json" in ref["source"]
    data = {"commands": [{"command": "x", "data": "d", "wall_min": None, "cores": 2, "peak_mem_gib": 1.25,
                          "disk": None, "writes": "w", "measured": "2026-01-01", "source": "s"},
                         {"command": "y", "data": "d", "wall_min": None, "cores": None, "peak_mem_gib": None,
                          "disk": None, "writes": "w", "measured": None, "source": None, "pending": "not yet run"}]}
    (tmp_path / "c.json").write_text(json.dumps(data))
    rows = readme.command_table(tmp_path / "c.json").splitlines()
    assert rows[2] == "| `x` | d | to be measured | 2 | 1.2 GiB | to be measured | w |"
    assert rows[3] == "| `y` | d | not yet run | not yet run | not yet run | not yet run | w |"
    data["commands"][0]["source"] = None                     # a measured value without its source is refused
    (tmp_path / "c.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="x: a measured value needs its date"):
        readme.command_entries(tmp_path / "c.json")
    data["commands"][0]["source"] = "s"
    del data["commands"][1]["writes"]
    (tmp_path / "c.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="missing writes"):
        readme.command_entries(tmp_path / "c.json")


@pytest.mark.parametrize("where", ["paper", "run"])
def test_reproduction_md_is_generated_from_the_committed_run(where):
    """paper/REPRODUCTION.md and the run folder's own copy both equal the generator's output at HEAD."""
    out = ROOT / "paper" / "REPRODUCTION.md" if where == "paper" else RUN.path / "REPRODUCTION.md"
    fix = " --out paper/REPRODUCTION.md" if where == "paper" else ""
    assert out.read_text() == report.reproduction_text(RUN, out), \
        f"stale {out}: run python -m hbeo report --run results/cpu-modelnet10-vox30{fix}"
    for link in re.findall(r"\]\(([^)#]+)\)", out.read_text()):
        assert (out.parent / link).exists(), f"{out} links to a missing file: {link}"


def test_deviations_say_what_the_run_used(tmp_path):
    """The deviations are built from the run's manifest and dataset tables, never ModelNet10's facts typed
    into every run: the reference run's, and a procedural ci-sized run's."""
    import json
    import pandas as pd
    from hbeo import config
    text = "\n".join(report.deviations(json.loads(RUN.manifest.read_text()), RUN))
    assert "907 of 908 test grids: one is empty" in text and "2048 rotations" in text and "about 15° apart" in text
    run = RunDir(tmp_path / "run").create()
    counts = pd.DataFrame({"train": [6, 6], "test": [3, 3], "train (run)": [6, 6], "test (run)": [3, 3]},
                          index=pd.Index(["chair", "total"], name="class"))
    counts.to_csv(run.table("01_class_counts"))
    man = {"dataset": "procedural", "profile_settings": config.get_profile("ci").to_dict(),
           "training": {"model.hbeo": {"recipe": config.get_profile("ci").recipe.fit_kwargs()}}}
    ci = "\n".join(report.deviations(man, run))
    assert "907" not in ci and "ModelNet10 as" not in ci and "Procedural objects" in ci
    assert "6 training and 3 test objects" in ci and "400 rotations" in ci and "about 27° apart" in ci
    recipe = next(line for line in ci.splitlines() if line.startswith("- **Training recipe.**"))
    assert "uses the paper's recipe" in recipe and "chosen on validation" not in recipe
    # no HBEO evaluation in this folder: the completion line says so instead of naming a rule
    assert "This run's HBEO evaluation file is missing." in ci
    assert "view 0 of the first 1 and all test objects" in ci                # ci: ICP on every test object
