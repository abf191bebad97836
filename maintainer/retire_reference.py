"""Retire a reference run's model-table files before its regenerated run lands (as c6ffddb did by hand).

The run folder keeps only files of its own model (hbeo.rundir.RunDir.history). When `make reproduce` is about to
replace ``model.hbeo``, the files that scored the old one move to ``docs/history/<run>/`` under a new stem, so that
the new run's files (same names: ``eval_hbeo_3dof.json``, ``eval_val-ref.json``, ...) never overwrite them:

- ``eval_{val,test}-OLD*.json``                -> ``eval_{val,test}-NEW*.json``
- ``eval_hbeo_3dof.json``, ``eval_hbeo-verify_3dof.json`` (the run's own test files)
                                              -> ``eval_test-NEW.json``, ``eval_test-NEW-verify-run.json``
- ``*_vs_OLD*.json``, ``flips_*-OLD.json``       -> the same names with NEW
- ``eval_val-ens3-*.json`` (the old recipe's seeds averaged) -> unchanged names
- ``train_model/``, ``train_model-sS/``         -> ``train_model_NEW/``, ``train_model_NEW-sS/``

``models.json``'s rows follow (their file fields and every file name in their text); the rows of the old
reference (labels starting ``reference``) are relabelled ``previous reference (LABEL)``, are no longer chosen and
give up their ``target_role`` (the targets table judges the new reference's rows; the roles are printed so they
can be given to them). File names in README.md and benchmarks/README.md are rewritten the same way, a path
``results/<run>/NAME`` becoming ``docs/history/<run>/NEW``; there, and in the rows' text, the run's own generic
names (``eval_hbeo_3dof.json``, ``train_model/``), which the new run's files take over, stay.
scripts/model_table.sh, whose commands write through ``$R``, is left to be edited by hand. Moves use ``git mv``;
``--dry-run`` prints the plan and changes nothing.

Usage: python scripts/retire_reference.py --old ref --new bal30 \\
           --label "tag repro-cpu-2026-11-26-bal, commit aa98863" [--run results/cpu-modelnet10-vox30] [--dry-run]
"""
import argparse
import json
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from hbeo.rundir import RunDir  # noqa: E402
from hbeo.storage import atomic_text, json_text  # noqa: E402

TEXT_FILES = ("README.md", "benchmarks/README.md")
#: the run's own test files (notebooks 05/06), renamed when retired
OWN = ("eval_hbeo_3dof.json", "eval_hbeo-verify_3dof.json")
FILE_FIELDS, SEED_FIELDS = ("val", "test"), ("val_seeds", "test_seeds")


def plan(run: Path, old: str, new: str) -> dict[str, str]:
    """Old name -> new name (relative to the run folder / its history folder) of every file to retire."""
    moves = {}
    for p in sorted(run.iterdir()):
        n = p.name
        m = re.fullmatch(rf"eval_(val|test)-{re.escape(old)}((?:-[\w-]+)?)\.json", n)
        if m:
            moves[n] = f"eval_{m[1]}-{new}{m[2]}.json"
        elif re.fullmatch(rf"[\w-]+_vs_{re.escape(old)}(_[\w]+)?\.json|flips_[\w]+-{re.escape(old)}\.json", n):
            moves[n] = n.replace(f"_vs_{old}", f"_vs_{new}").replace(f"-{old}.json", f"-{new}.json")
        elif re.fullmatch(r"eval_val-ens3-[\w-]+\.json", n):
            moves[n] = n
        elif p.is_dir() and (n == "train_model" or re.fullmatch(r"train_model-s\d+", n)):
            moves[n] = f"train_model_{new}{n[len('train_model'):]}"
    for own, stem in zip(OWN, (f"eval_test-{new}.json", f"eval_test-{new}-verify-run.json")):
        if (run / own).exists():
            moves[own] = stem
    return moves


def rename_in_text(text: str, moves: dict[str, str], run: str = "") -> str:
    """Every retired file name in ``text`` replaced by its new one (whole names only, longest first); with
    ``run`` (the run folder's name), a path ``results/RUN/NAME`` becomes ``docs/history/RUN/NEW``."""
    for a in sorted(moves, key=len, reverse=True):
        if run:
            text = text.replace(f"results/{run}/{a}", f"docs/history/{run}/{moves[a]}")
        if moves[a] != a:
            text = re.sub(rf"(?<![\w-]){re.escape(a)}(?![\w.-])", moves[a], text)
    return text


def named_in_text(moves: dict[str, str]) -> dict[str, str]:
    """The moves whose old names are the retired model's own (its stem in them): a text's mention of the run's
    generic names (``eval_hbeo_3dof.json``, ``train_model/``) means whatever run holds them and stays."""
    return {a: b for a, b in moves.items() if a not in OWN and not a.startswith("train_model")}


def retire_rows(rows: list[dict], moves: dict[str, str], label: str) -> tuple[list[dict], dict[str, str]]:
    """models.json rows with retired file names (file fields: every move; text: :func:`named_in_text`) and the
    old reference's rows relabelled; and the target roles given up (row label -> role)."""
    roles = {}
    out = []
    text_moves = named_in_text(moves)
    for r in rows:
        r = {k: (moves.get(v, v) if k in FILE_FIELDS else [moves.get(x, x) for x in v] if k in SEED_FIELDS
                 else rename_in_text(v, text_moves) if isinstance(v, str) else v) for k, v in r.items()}
        if r["label"].startswith("reference"):
            if "target_role" in r:
                roles[r["label"]] = r.pop("target_role")
            r["label"] = f"previous reference ({label}){r['label'][len('reference'):]}"
            r["chosen"] = False
        out.append(r)
    return out, roles


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default="results/cpu-modelnet10-vox30")
    ap.add_argument("--old", default="ref")
    ap.add_argument("--new", required=True)
    ap.add_argument("--label", required=True, help="what identifies the retired run, e.g. its tag and commit")
    ap.add_argument("--dry-run", action="store_true")
    a = ap.parse_args(argv)
    rd = RunDir(ROOT / a.run)
    run, hist, table = rd.path, rd.history, rd.model_rows
    if not table.is_file():
        print(f"{run}: not a run folder with a models.json", file=sys.stderr)
        return 1
    moves = plan(run, a.old, a.new)
    clash = [b for b in moves.values() if (hist / b).exists()]
    if clash:
        print(f"{hist}: already holds {', '.join(clash)}; choose another --new", file=sys.stderr)
        return 1
    for src, dst in moves.items():
        print(f"{a.run}/{src} -> docs/history/{run.name}/{dst}")
    rows, roles = retire_rows(json.loads(table.read_text()), moves, a.label)
    for lab, role in roles.items():
        print(f"target role {role!r} given up by: {lab[:90]}")
    if a.dry_run:
        return 0
    hist.mkdir(parents=True, exist_ok=True)
    for src, dst in moves.items():
        subprocess.run(["git", "mv", str(run / src), str(hist / dst)], check=True, cwd=ROOT)
    atomic_text(table, json_text(rows, indent=1, ensure_ascii=False) + "\n")
    text_moves = named_in_text(moves)
    for f in TEXT_FILES:
        p = ROOT / f
        t = p.read_text()
        t2 = rename_in_text(t, text_moves, run.name)
        if t2 != t:
            atomic_text(p, t2)
            print(f"renamed file names in {f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
