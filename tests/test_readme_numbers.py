"""Every figure in the README and in paper/REPRODUCTION.md comes from a committed file.

- ``paper/REPRODUCTION.md`` is exactly what :func:`hbeo.report.reproduction_md.reproduction_text` writes from the
  committed reference run, and every file it links to is committed;
- the README's generated blocks (summary, subspace, model and targets tables) are exactly what the run's
  files give (the model and targets tables: ``tests/test_model_table.py``);
- outside generated blocks and code, the README quotes no result figure by hand: every percentage, angle or
  0.xx figure in its prose is a setting (checked against the code where the code holds it) or traced to the
  committed file that measured it (the figure must appear there).
"""
import re
from pathlib import Path

import pytest

from hbeo.report import reproduction_md as report
from hbeo.report.model_table import BEGIN, END
from hbeo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
RUN = RunDir(ROOT / "results" / "cpu-modelnet10-vox30")
README = ROOT / "README.md"


def _settings() -> dict[str, str]:
    """Figures in the README's prose that are settings, not results: figure -> what it is (checked below)."""
    return {"63°": "the Kinect-like camera's horizontal field of view", "60 %": "VBPCA's variance fraction",
            "10 %": "the validation fraction", "0.45": "verify's min_agreement", "14°": "rotation-bin spacing",
            "10°": "rotation-bin target smoothing", "40°": "rotation-bin decoding window", "95 %": "interval level",
            "30°": "the within-30° threshold", "180°": "a front-back flip",
            "170°": "predict's largest field of view", "90 %": "predict's in-view share", "15°": "a benchmark threshold",
            "0.001": "the default depth scale (metres per stored unit)"}


#: Figures in the README's prose measured elsewhere: figure -> the committed file that holds it.
TRACED = {"53 %": "benchmarks/README.md", "89 %": "benchmarks/README.md", "0.98": "benchmarks/README.md",
          "0.83": "benchmarks/README.md", "34.2 %": "docs/history/gpu-lease-modelnet10-vox30/lease-2026-11-26/README.md"}
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


def test_readme_prose_quotes_no_result_by_hand():
    found = set(m.group(0) for m in FIGURE.finditer(_prose(README.read_text())))
    unexplained = found - set(_settings()) - set(TRACED)
    assert not unexplained, (f"figures typed into the README outside generated blocks: {sorted(unexplained)}; "
                             f"generate them from a committed file, or trace them in {__file__}")
    for fig, source in TRACED.items():
        assert fig in (ROOT / source).read_text(), f"{fig} is not in {source}"


def test_the_lint_catches_a_typed_figure():
    assert FIGURE.findall(_prose("HBEO reaches 73.7 % and a 25.8° median, IoU 0.446.\n")) == ["73.7 %", "25.8°",
                                                                                            "0.446"]
    assert FIGURE.findall(_prose(f"{report.SUMMARY_BEGIN}\n73.7 %\n{report.SUMMARY_END}\n")) == []


@pytest.mark.parametrize("begin,end,fn", report.README_BLOCKS)
def test_readme_blocks_are_what_the_committed_run_gives(begin, end, fn):
    text = README.read_text()
    assert text.count(begin) == 1 and text.count(end) == 1
    block = text[text.index(begin) + len(begin):text.index(end)]
    assert block == "\n" + fn(RUN), "stale block: run python -m hbeo report --run RUN --readme README.md"
    assert BEGIN in text and END in text                          # the model table (checked in test_model_table)


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
    assert "uses the paper's recipe" in ci and "chosen on validation" not in ci
    assert "view 0 of the first 1 and all test objects" in ci                # ci: ICP on every test object
