"""maintainer/retire_reference.py: which files of a retired reference move where, and how the experiment specs
(hence models.json) follow."""
import importlib.util
import tomllib
from pathlib import Path

SCRIPT = Path(__file__).resolve().parent.parent / "maintainer" / "retire_reference.py"


def _module():
    spec = importlib.util.spec_from_file_location("retire_reference", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _run(tmp_path):
    run = tmp_path / "cpu-x"
    run.mkdir()
    for n in ("eval_val-ref.json", "eval_val-ref-rolls4-s1.json", "eval_test-ref-s2.json", "eval_hbeo_3dof.json",
              "eval_hbeo-verify_3dof.json", "fc1024_vs_ref_val_rolls4.json", "flips_val-ref.json",
              "eval_val-ens3-rolls1.json", "eval_val-fc1024.json", "eval_val-reference.json", "eval_beo_known.json",
              "e60_vs_fc1024_val.json"):
        (run / n).write_text("{}")
    for d in ("train_model", "train_model-s1", "train_model_e60"):
        (run / d).mkdir()
    return run


def test_the_plan_moves_the_old_models_files_only(tmp_path):
    m = _module()
    moves = m.plan(_run(tmp_path), "ref", "bal30")
    assert moves == {
        "eval_val-ref.json": "eval_val-bal30.json", "eval_val-ref-rolls4-s1.json": "eval_val-bal30-rolls4-s1.json",
        "eval_test-ref-s2.json": "eval_test-bal30-s2.json", "eval_hbeo_3dof.json": "eval_test-bal30.json",
        "eval_hbeo-verify_3dof.json": "eval_test-bal30-verify-run.json",
        "fc1024_vs_ref_val_rolls4.json": "fc1024_vs_bal30_val_rolls4.json", "flips_val-ref.json": "flips_val-bal30.json",
        "eval_val-ens3-rolls1.json": "eval_val-ens3-rolls1.json",
        "train_model": "train_model_bal30", "train_model-s1": "train_model_bal30-s1"}
    # another model's files, a longer stem that starts like the old one, and the run's baselines stay


def test_text_and_rows_follow_but_the_runs_own_names_stay_in_text(tmp_path):
    m = _module()
    moves = m.plan(_run(tmp_path), "ref", "bal30")
    text = ("see eval_val-ref.json and results/cpu-x/flips_val-ref.json, not eval_val-reference.json; "
            "the run's eval_hbeo_3dof.json and train_model/ log")
    got = m.rename_in_text(text, m.named_in_text(moves), "cpu-x")
    assert got == ("see eval_val-bal30.json and docs/history/cpu-x/flips_val-bal30.json, not eval_val-reference.json; "
                   "the run's eval_hbeo_3dof.json and train_model/ log")
    spec = """name = "ref"
status = "reference"
question = "q"
rule = "r"
needs = ["other", "ref-rolls4"]
seeds = { training = [0], views = 0 }

[commands]
val = [
  "python -m hbeo evaluate --model results/cpu-x/model.hbeo --dataset d --split val --quiet --out results/cpu-x/eval_val-ref.json",
]

[writes]
val = [
  "results/cpu-x/eval_val-ref.json",
]
test = [
  "results/cpu-x/eval_hbeo_3dof.json",
]

[row]
label = \"\"\"\\
  reference `model.hbeo`, one pass\"\"\"
val = "eval_val-ref.json"
test = "eval_hbeo_3dof.json"
note = "against eval_hbeo_3dof.json of the run; fc1024_vs_ref_val_rolls4.json"
target_role = "hbeo"
val_seeds = ["eval_val-ref-rolls4-s1.json"]
"""
    renames = m.spec_renames(["ref", "ref-rolls4", "reference-like", "fc1024", "other"], "ref", "bal30")
    assert renames == {"ref": "bal30", "ref-rolls4": "bal30-rolls4"}
    out, role = m.retire_spec(spec, moves, renames, "cpu-x", "tag t")
    assert role == "hbeo" and "target_role" not in out
    doc = tomllib.loads(out)
    assert doc["name"] == "bal30" and doc["status"] == "superseded" and doc["needs"] == ["other", "bal30-rolls4"]
    assert doc["row"] == {"label": "previous reference (tag t) `model.hbeo`, one pass", "val": "eval_val-bal30.json",
                          "test": "eval_test-bal30.json", "val_seeds": ["eval_val-bal30-rolls4-s1.json"],
                          "note": "against eval_hbeo_3dof.json of the run; fc1024_vs_bal30_val_rolls4.json"}
    assert doc["writes"] == {"val": ["docs/history/cpu-x/eval_val-bal30.json"],
                             "test": ["docs/history/cpu-x/eval_test-bal30.json"]}
    assert doc["commands"]["val"][0].endswith("--out docs/history/cpu-x/eval_val-bal30.json")
    # another experiment's spec: its file names follow, its status and label stay
    other = spec.replace('status = "reference"', 'status = "chosen"').replace('name = "ref"', 'name = "fc1024"')
    out, role = m.retire_spec(other, moves, renames, "cpu-x", "tag t")
    doc = tomllib.loads(out)
    assert role is None and doc["status"] == "chosen" and doc["name"] == "fc1024"
    assert doc["row"]["label"] == "reference `model.hbeo`, one pass" and doc["row"]["val"] == "eval_val-bal30.json"
