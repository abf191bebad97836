"""Experiments as data (hbeo.report.experiments, python -m hbeo experiment): every model-table row is a spec in
experiments/, models.json and the model table are generated from the specs, a malformed spec is refused with
the file named, and run prints or runs the spec's pinned commands."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from hbeo.errors import DataError, HBEOError
from hbeo.report import experiments as ex
from hbeo.report.model_table import BEGIN, END
from hbeo.rundir import RunDir

ROOT = Path(__file__).resolve().parents[1]
RUN = ROOT / "results" / "cpu-modelnet10-vox30"


def cli(*args):
    return subprocess.run([sys.executable, "-m", "hbeo", "experiment", *args], capture_output=True, text=True,
                          cwd=ROOT)


# ---------------------------------------------------------------------------------------------- the committed specs

def test_list_shows_a_spec_for_every_models_json_row():
    rows = json.loads(RunDir(RUN).model_rows.read_text())
    exps = [e for e in ex.load_all() if e.run_name == RUN.name]
    assert [e.model_row()["label"] for e in exps if e.status != "pending"] == [r["label"] for r in rows]
    lines = ex.listing().splitlines()
    assert lines[0].startswith("cpu-modelnet10-vox30:")
    listed = [line.split()[:3] for line in lines[1:]]
    assert [(n, name) for n, name, _ in listed] == [(f"{e.order:02d}", e.name) for e in exps]
    for line, e in zip(lines[1:], exps):     # a pending spec (registered, not run) may miss its files
        assert f" {e.status} " in line and "rule: " in line and ("MISSING" not in line or e.status == "pending"), line
    assert {e.status for e in exps} - {"pending"} == set(ex.STATUSES) - {"pending"}


def test_generated_models_json_is_the_committed_one():
    exps = ex.load_all()
    assert ex.rows_text(ex.model_rows(exps, RUN.name)) == RunDir(RUN).model_rows.read_text(), \
        "models.json is not what the specs give: python -m hbeo experiment table"


def test_every_committed_command_parses_and_pins_the_profile_s_options():
    """Each `python -m hbeo` command of a committed spec is a valid command line, and every train command writes
    out the options whose defaults come from the profile."""
    from hbeo.cli import _join_list_values, build_parser
    parser = build_parser()
    pinned = ("--out", "--rotation", "--shape-loss", "--class-balance", "--fc", "--epochs", "--views", "--data",
              "--seed", "--name")
    for e in ex.load_all():
        for phase, c in e.all_commands():
            argv = ex.command_argv(c)
            if argv[1:3] != ["-m", "hbeo"]:
                assert (ROOT / argv[1]).is_file(), f"{e.path.name}: {argv[1]} is not a script of the repository"
                continue
            args = parser.parse_args(_join_list_values(argv[3:]))
            if args.command == "train":
                missing = [o for o in pinned if o not in argv]
                assert not missing and args.augment_roll is not None, f"{e.path.name}: {c} leaves {missing} to the profile"


def test_dry_run_prints_the_pinned_commands_and_runs_nothing():
    lines = []
    out = ex.run("fc1024", dry_run=True, echo=lines.append)
    assert lines[0].startswith("# experiments/cpu-modelnet10-vox30/21-fc1024.toml: chosen;")
    train = [x for x in lines if x.startswith("[train] ")]
    assert len(train) == 3 and all("--fc 1024,512,512 --epochs 30 " in x and "--class-balance sampler" in x
                                   for x in train)
    assert [x.split("--seed ")[1].split()[0] for x in train] == ["0", "1", "2"]
    assert any(x.startswith("[test] python -m hbeo evaluate --model results/cpu-modelnet10-vox30/model_fc1024.hbeo ")
               and x.endswith("--out results/cpu-modelnet10-vox30/eval_test-fc1024.json") for x in lines)
    assert ROOT / "results/cpu-modelnet10-vox30/eval_val-fc1024.json" in out
    # the rows made under the old profile pin it: (512, 256, 256), 30 epochs
    r = cli("run", "11-bal30", "--dry-run")
    assert r.returncode == 0, r.stderr
    assert "--fc 512,256,256 --epochs 30 --views 20 --data memory --seed 1 --name model_bal30-s1.hbeo" in r.stdout


def test_the_cli_lists_and_refuses_an_unknown_name():
    r = cli("list")
    assert r.returncode == 0 and "  27 ref " in r.stdout
    r = cli("run", "no-such-experiment", "--dry-run")
    assert r.returncode == 2 and "no experiment named 'no-such-experiment'" in r.stderr


# ---------------------------------------------------------------------------------------------- malformed specs

GOOD = """name = "tiny"
status = "not chosen"
question = "Does it run?"
rule = "None: a test."
seeds = { training = [0], views = 0 }

[commands]
train = ["python -m hbeo train --dataset procedural --profile ci --out results/ci-tiny --name model_tiny.hbeo"]
val = ["python -m hbeo evaluate --model results/ci-tiny/model_tiny.hbeo --dataset procedural --split val --out results/ci-tiny/eval_val-tiny.json"]

[writes]
val = ["results/ci-tiny/eval_val-tiny.json"]

[row]
label = "tiny"
val = "eval_val-tiny.json"
"""


def _specs(tmp_path, text=GOOD, name="00-tiny.toml", run="ci-tiny"):
    d = tmp_path / "experiments" / run
    d.mkdir(parents=True, exist_ok=True)
    (d / name).write_text(text)
    return tmp_path / "experiments", d / name


def test_a_good_tiny_spec_loads(tmp_path):
    root, _ = _specs(tmp_path)
    (e,) = ex.load_all(root)
    assert e.name == "tiny" and e.repo == tmp_path and e.run.path == tmp_path / "results" / "ci-tiny"
    assert e.model_row() == {"label": "tiny", "val": "eval_val-tiny.json", "test": None, "chosen": False}


def test_a_pending_spec_has_no_row(tmp_path):
    root, path = _specs(tmp_path, GOOD.replace('"not chosen"', '"pending"'))
    exps = ex.load_all(root)
    assert [e.status for e in exps] == ["pending"] and ex.model_rows(exps, "ci-tiny") == []
    assert "pending" in ex.listing(root) and "MISSING" in ex.listing(root)


def test_a_pending_spec_is_listed_with_its_rule_in_the_readme_block(tmp_path):
    root, path = _specs(tmp_path, GOOD.replace('"not chosen"', '"pending"'))
    (e,) = ex.load_all(root)
    table = ex.pending_table([e], "ci-tiny")
    assert table.count("\n") == 3 and f"`{e.name}`" in table and " ".join(e.rule.split()) in table
    assert "python -m hbeo experiment run tiny" in table
    assert ex.pending_table([e], "another-run") == "Every registered row has run.\n"
    readme = tmp_path / "doc.md"
    readme.write_text(f"a\n{BEGIN}\n{END}\n{ex.PENDING_BEGIN}\nold\n{ex.PENDING_END}\nb\n")
    ex.write_table(root, readme)
    assert f"{ex.PENDING_BEGIN}\n{table}{ex.PENDING_END}" in readme.read_text() and "old" not in readme.read_text()


def test_a_pipe_in_a_rule_does_not_split_its_cell():
    assert ex._cell("a | b\n  c") == "a \\| b c"


def test_the_docs_list_the_pending_rows():
    text = (ROOT / "docs" / "experiments.md").read_text()
    block = text[text.index(ex.PENDING_BEGIN) + len(ex.PENDING_BEGIN) + 1:text.index(ex.PENDING_END)]
    assert block == ex.pending_table(ex.load_all(), RUN.name), \
        "docs/experiments.md's pending rows are stale: python -m hbeo experiment table --readme docs/experiments.md"


@pytest.mark.parametrize("change,problem", [
    (lambda t: t.replace('label = "tiny"', 'label = "tiny'), "not valid TOML"),
    (lambda t: "colour = 1\n" + t, "unknown key.s. colour"),
    (lambda t: t.replace('rule = "None: a test."\n', ""), "missing key.s. rule"),
    (lambda t: t.replace('"not chosen"', '"maybe"'), "status 'maybe'"),
    (lambda t: t.replace('name = "tiny"', 'name = "small"'), "name 'small' is not the file's name"),
    (lambda t: t + "chosen = true\n", "row.chosen follows from the status"),
    (lambda t: t.replace("--out results/ci-tiny/eval_val-tiny.json", "--out results/ci-tiny/other.json"),
     "writes results/ci-tiny/other.json, which writes.val does not list"),
    (lambda t: t.replace('"python -m hbeo train', '"bash -c train'), "a command is `python -m hbeo"),
    (lambda t: t.replace("[writes]", '[writes]\ntest = ["results/ci-tiny/eval_test-tiny.json"]'),
     "the test split is evaluated for chosen rows only"),
    (lambda t: t.replace('val = "eval_val-tiny.json"', 'val = "eval_val-other.json"'),
     "row shows eval_val-other.json"),
    (lambda t: t.replace("seeds = {", 'needs = ["nobody"]\nseeds = {'), "needs 'nobody', which no spec is named"),
    (lambda t: t.replace("views = 0", 'views = "zero"'), "seeds must be"),
    (lambda t: t.replace("[row]", "[row]\ntarget_role = \"best\""), "target_role 'best'"),
    (lambda t: t.replace("seeds = {", "profile = { colour = 1 }\nseeds = {"), "profile names unknown field"),
])
def test_a_malformed_spec_is_refused_naming_the_file(tmp_path, change, problem):
    root, path = _specs(tmp_path, change(GOOD))
    with pytest.raises(DataError, match=problem) as err:
        ex.load_all(root)
    assert str(err.value).startswith(f"{path}: malformed experiment spec: ")


def test_bad_file_names_and_clashes_are_refused(tmp_path):
    root, _ = _specs(tmp_path, name="tiny.toml")
    with pytest.raises(DataError, match=r"tiny.toml: malformed experiment spec: the file name must be NN-NAME.toml"):
        ex.load_all(root)
    (root / "ci-tiny" / "tiny.toml").unlink()
    _specs(tmp_path)
    _specs(tmp_path, GOOD.replace('name = "tiny"', 'name = "tiny2"'), name="00-tiny2.toml")
    with pytest.raises(DataError, match="place 00 is also 00-tiny.toml's"):
        ex.load_all(root)


def test_the_cli_names_the_malformed_file_and_exits_2(tmp_path):
    root, path = _specs(tmp_path, GOOD.replace('"not chosen"', '"maybe"'))
    r = cli("list", "--experiments", str(root))
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: {path}: malformed experiment spec: status 'maybe'; expected one of " \
                               f"{', '.join(ex.STATUSES)}"


# ---------------------------------------------------------------------------------------------- refusing to run

def test_run_refuses_a_missing_input_naming_the_experiment_that_makes_it(tmp_path):
    root, _ = _specs(tmp_path)
    reader = """name = "reader"
status = "not chosen"
question = "Does it read?"
rule = "None: a test."
needs = ["tiny"]
seeds = { training = [0], views = 0 }

[commands]
val = ["python -m hbeo evaluate --model results/ci-tiny/model_tiny.hbeo --split val --out results/ci-tiny/r.json"]

[writes]
val = ["results/ci-tiny/r.json"]

[row]
label = "reader"
val = "r.json"
"""
    _specs(tmp_path, reader, name="01-reader.toml")
    with pytest.raises(HBEOError, match=r"model_tiny.hbeo: missing; reader reads it .* made by experiment tiny "
                                        r"\(python -m hbeo experiment run tiny\)"):
        ex.run("reader", root, echo=lambda s: None)
    assert not (tmp_path / "results").exists()


def test_run_refuses_when_the_profile_changed(tmp_path):
    root, path = _specs(tmp_path, GOOD.replace("seeds = {", "profile = { batch_size = 7 }\nseeds = {"))
    with pytest.raises(HBEOError, match=r"would not reproduce the row: profile ci's batch_size is 32, the spec was "
                                        r"made with 7"):
        ex.run("tiny", root, echo=lambda s: None)
    lines = []
    ex.run("tiny", root, dry_run=True, echo=lines.append)      # a dry run says so and prints the commands
    assert "# warning: profile ci's batch_size is 32, the spec was made with 7" in lines


# ---------------------------------------------------------------------------------------------- end to end

def test_a_spec_runs_in_the_python_running_hbeo_with_its_paths_from_the_top_folder(tmp_path):
    import sys
    argv = ["python", "-m", "hbeo", "evaluate", "--out", "results/x.json", "--model", "m.hbeo"]
    assert ex._rooted(argv, tmp_path) == [sys.executable, "-m", "hbeo", "evaluate", "--out",
                                          str(tmp_path / "results/x.json"), "--model", "m.hbeo"]
    other = ["python", "scripts/paired_contrast.py", "a.json", "--out", "c.json"]
    assert ex._rooted(other, tmp_path) == [sys.executable] + other[1:]      # not hbeo's: --out left as written
    assert ex._rooted(["bash", "x.sh"], tmp_path) == ["bash", "x.sh"]


@pytest.mark.slow
def test_a_tiny_spec_runs_at_the_ci_profile_and_tabulates(tmp_path, monkeypatch):
    """Train two steps, evaluate one view of one object per class on validation, then models.json and the table."""
    monkeypatch.setenv("HBEO_CACHE", str(tmp_path / "cache"))
    text = GOOD.replace("--name model_tiny.hbeo", "--epochs 1 --max-steps 2 --name model_tiny.hbeo --quiet")
    text = text.replace("--split val --out", "--split val --views 1 --seed 0 --per-class 1 --quiet --out")
    root, _ = _specs(tmp_path, text)
    written = ex.run("tiny", root, echo=lambda s: None)
    assert written == [tmp_path / "results/ci-tiny/eval_val-tiny.json"] and written[0].exists()
    assert json.loads(written[0].read_text())["split"] == "val"
    paths = ex.write_table(root)
    run = RunDir(tmp_path / "results" / "ci-tiny")
    assert paths == [run.model_rows, run.model_table]
    assert json.loads(run.model_rows.read_text()) == [{"label": "tiny", "val": "eval_val-tiny.json", "test": None,
                                                       "chosen": False}]
    assert "| tiny | no | " in run.model_table.read_text()
    assert not (ROOT / "results" / "ci-tiny").exists()             # every path taken from the spec's repository


def test_every_evaluate_command_gives_the_completion_rule_its_file_records():
    """Run again today, a spec's HBEO evaluation completes by the rule its committed file was made with: files made
    under the paper's rule (no ``completion_rule`` key) need ``--completion paper`` now that the default is the
    never-empty rule, and files made at an earlier default threshold pin it (``--completion-threshold``)."""
    import json
    from hbeo.cli import _completion, _join_list_values, build_parser
    from hbeo.model.completion_rule import DEFAULT, of_record, rule
    parser = build_parser()
    checked = 0
    for e in ex.load_all():
        for phase, c in e.all_commands():
            argv = ex.command_argv(c)
            if argv[1:3] != ["-m", "hbeo"] or argv[3] != "evaluate":
                continue
            args = parser.parse_args(_join_list_values(argv[3:]))
            out = ROOT / args.out
            if args.method != "hbeo" or not out.is_file():
                continue
            given = _completion(args)
            wants = rule(DEFAULT if given is None else given)
            made = of_record(json.loads(out.read_text()).get("completion_rule"))
            assert wants == made, f"{e.path.name}: {c}\n completes by {wants}, its file {args.out} by {made}"
            checked += 1
    assert checked > 20
