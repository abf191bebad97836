"""The model table's rows of the regenerated reference run (issue 29 item 5), added to models.json when it lands.

Run in the checkout after `python scripts/retire_reference.py` moved the previous reference's files and relabelled
its rows, and after the new run's files were copied into the run folder (scripts/reference_run.sh step 4). Adds
three rows before the last one (the 3-D CNN baseline's, which stays last): one network pass (``target_role``
``hbeo``: the run's own test file), 4 rolls, and 4 rolls + verify (``hbeo+verify``: the run's own file). The seeds
columns are the same recipe trained alone with training seeds 1 and 2 (scripts/model_table.sh 4l's
``train_seeds``: ``eval_val-e60-s1/-s2.json``; only seed 2 has test files), scored on the same views. Every file
a row names must exist; rows already there (a label starting ``reference `model.hbeo```) are refused.

Usage: python scripts/reference_rows.py [--run results/cpu-modelnet10-vox30] [--commit SHA] [--tag TAG]
"""
import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from hbeo.storage import atomic_text, json_text  # noqa: E402

RECIPE = ("class-balanced sampling + rotation bins + roll augmentation + voxel loss, shared layers (1024, 512, 512), "
          "60 epochs")


def rows(tag: str, commit: str) -> list[dict]:
    made = (f"made by `make reproduce PROFILE=cpu DATASET=modelnet10-vox30` from a clean clone at tag {tag} (commit "
            f"{commit}) over two sessions: notebooks 01-04 in the first, 05-08 in the second from the first's "
            f"committed products (scripts/reference_stage.sh; manifest.json holds each notebook's wall time and "
            f"commit)")
    return [
        {"label": f"reference `model.hbeo`: {RECIPE}, trained by the reference run (notebook 04)",
         "val": "eval_val-ref.json", "test": "eval_hbeo_3dof.json", "chosen": True,
         "note": ("one network pass: the paper's HBEO inference. The recipe chosen on validation: class-balanced "
                  "sampling (scripts/model_table.sh 2b), the wider shared layers (4k) and 60 epochs (4l), each by a "
                  "rule fixed before its result; " + made + ". Training seeds 1 and 2: 4l's trainings of the same "
                  "recipe alone (`python -m hbeo train --dataset modelnet10-vox30 --profile cpu --fc 1024,512,512 "
                  "--epochs 60 --seed S`; logs in train_model_e60-sS/, model files not committed), scored on the "
                  "same views; seed 1 has no test file (its model file was lost before one was made)"),
         "command": "make reproduce PROFILE=cpu DATASET=modelnet10-vox30", "target_role": "hbeo",
         "val_seeds": ["eval_val-e60-s1.json", "eval_val-e60-s2.json"], "test_seeds": ["eval_test-e60-s2.json"]},
        {"label": "reference, averaged over 4 camera rolls (`--rolls 4`)",
         "val": "eval_val-ref-rolls4.json", "test": "eval_test-ref-rolls4.json", "chosen": True,
         "note": "the roll count chosen on validation with the previous reference (4 of 4, 8, 16); seed 2's test "
                 "file with 4 rolls beside (no validation files of seeds 1 and 2 with 4 rolls)",
         "test_seeds": ["eval_test-e60-s2-rolls4.json"]},
        {"label": "reference, 4 rolls + verify (`--rolls 4 --verify`, the defaults chosen in verify_sweep.csv)",
         "val": "eval_val-ref-verify.json", "test": "eval_hbeo-verify_3dof.json", "chosen": True,
         "target_role": "hbeo+verify"},
    ]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default="results/cpu-modelnet10-vox30")
    ap.add_argument("--commit", help="the run's commit (default: its manifest's)")
    ap.add_argument("--tag", help="the run's tag (default: its manifest's)")
    a = ap.parse_args(argv)
    run = Path(a.run)
    man = json.loads((run / "manifest.json").read_text())
    table = run / "models.json"
    old = json.loads(table.read_text())
    if any(r["label"].startswith("reference `model.hbeo`") for r in old):
        print(f"{table}: it has reference rows already (retire the previous reference first: "
              f"scripts/retire_reference.py)", file=sys.stderr)
        return 1
    if not old or not old[-1]["label"].startswith("3-D CNN"):
        print(f"{table}: its last row is not the 3-D CNN baseline's", file=sys.stderr)
        return 1
    new = rows(a.tag or man["git_tag"], (a.commit or man["git_commit"])[:7])
    missing = [f for r in new for f in [r["val"], r["test"], *r.get("val_seeds", []), *r.get("test_seeds", [])]
               if not (run / f).is_file()]
    if missing:
        print(f"{run}: missing {', '.join(missing)}", file=sys.stderr)
        return 1
    atomic_text(table, json_text(old[:-1] + new + old[-1:], indent=1, ensure_ascii=False) + "\n")
    print(f"{table}: {len(new)} rows added before the last")
    return 0


if __name__ == "__main__":
    sys.exit(main())
