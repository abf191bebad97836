"""Retire a reference run's model-table files and specs before its regenerated run lands.

The run folder keeps only files of its own model (hbeo.rundir.RunDir.history). When `make reproduce` is about to
replace ``model.hbeo``, the files that scored the old one move to ``docs/history/<run>/`` under a new stem, so that
the new run's files (same names: ``eval_hbeo_3dof.json``, ``eval_val-ref.json``, ...) never overwrite them:

- ``eval_{val,test}-OLD*.json``                -> ``eval_{val,test}-NEW*.json``
- ``eval_hbeo_3dof.json``, ``eval_hbeo-verify_3dof.json`` (the run's own test files)
                                              -> ``eval_test-NEW.json``, ``eval_test-NEW-verify-run.json``
- ``*_vs_OLD*.json``, ``flips_*-OLD.json``       -> the same names with NEW
- ``eval_val-ens3-*.json`` (the old recipe's seeds averaged) -> unchanged names
- ``train_model/``, ``train_model-sS/``         -> ``train_model_NEW/``, ``train_model_NEW-sS/``

The run's experiment specs (``experiments/<run>/NN-NAME.toml``, hbeo.report.experiments) follow: every retired
file name in them (a path ``results/<run>/NAME`` becoming ``docs/history/<run>/NEW``; in the rows' text the run's
own generic names, ``eval_hbeo_3dof.json`` and ``train_model/``, which the new run's files take over, stay), the
specs named OLD or OLD-* renamed NEW, NEW-* (file and ``name``; ``needs`` everywhere), and the old reference's
specs (status ``reference``) made ``superseded``, their labels ``previous reference (LABEL) ...``, their
``target_role`` given up (printed, for the new reference's specs). Their ``[commands]`` still train and evaluate
through the run's ``model.hbeo`` and ``reproduce``: edit them by hand to train the retired recipe under its own
model name with every flag of its day (as ``11-bal30.toml`` does), then write the new reference's specs and run
``python -m hbeo experiment table``. File names in README.md and benchmarks/README.md are rewritten the same way.
Moves use ``git mv``; ``--dry-run`` prints the plan and changes nothing.

Usage: python maintainer/retire_reference.py --old ref --new bal30 \\
           --label "commit aa98863" [--run results/cpu-modelnet10-vox30] [--dry-run]
"""
import argparse
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from hbeo.rundir import RunDir  # noqa: E402
from hbeo.storage import atomic_text  # noqa: E402

TEXT_FILES = ("README.md", "benchmarks/README.md")
#: the run's own test files (notebooks 05/06), renamed when retired
OWN = ("eval_hbeo_3dof.json", "eval_hbeo-verify_3dof.json")


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


def spec_renames(names, old: str, new: str) -> dict[str, str]:
    """Spec name -> its name after the retirement, for the specs named OLD or OLD-*."""
    return {n: new + n[len(old):] for n in names if n == old or n.startswith(old + "-")}


def retire_spec(text: str, moves: dict[str, str], renames: dict[str, str], run: str, label: str
                ) -> tuple[str, str | None]:
    """A spec's text after the retirement (see the module docstring), and the target role it gave up (or None)."""
    out = []
    for line in text.splitlines(keepends=True):
        if line.startswith(("name = ", "needs = ")):
            line = re.sub(r'"([^"]*)"', lambda m: f'"{renames.get(m[1], m[1])}"', line)
        out.append(line)
    text = "".join(out)
    for own in OWN:
        if own in moves:
            text = re.sub(rf'^(val|test) = "{re.escape(own)}"$', lambda m: f'{m[1]} = "{moves[own]}"', text, flags=re.M)
            text = text.replace(f'"results/{run}/{own}"', f'"docs/history/{run}/{moves[own]}"')
    text = rename_in_text(text, named_in_text(moves), run)
    role = None
    if re.search(r'^status = "reference"$', text, re.M):
        text = re.sub(r'^status = "reference"$', 'status = "superseded"', text, flags=re.M)
        prefix = "previous reference (" + label.replace("\\", "\\\\").replace('"', '\\"') + ")"
        text = re.sub(r'^(label = (?:"""\\\n\s*|"))reference', lambda m: m[1] + prefix, text, count=1, flags=re.M)
        m = re.search(r'^target_role = "([^"]+)"\n', text, re.M)
        if m:
            role, text = m[1], text[:m.start()] + text[m.end():]
    return text, role


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--run", default="results/cpu-modelnet10-vox30")
    ap.add_argument("--old", default="ref")
    ap.add_argument("--new", required=True)
    ap.add_argument("--label", required=True, help="what identifies the retired run, e.g. its commit")
    ap.add_argument("--dry-run", action="store_true")
    a = ap.parse_args(argv)
    rd = RunDir(ROOT / a.run)
    run, hist = rd.path, rd.history
    specs_dir = ROOT / "experiments" / run.name
    specs = sorted(specs_dir.glob("*.toml"))
    if not run.is_dir() or not specs:
        print(f"{run}: not a run folder with experiment specs in {specs_dir}", file=sys.stderr)
        return 1
    moves = plan(run, a.old, a.new)
    clash = [b for b in moves.values() if (hist / b).exists()]
    if clash:
        print(f"{hist}: already holds {', '.join(clash)}; choose another --new", file=sys.stderr)
        return 1
    names = {s: s.stem.split("-", 1)[1] for s in specs}
    renames = spec_renames(names.values(), a.old, a.new)
    taken = set(names.values()) & set(renames.values())
    if taken:
        print(f"{specs_dir}: specs named {', '.join(sorted(taken))} exist already; choose another --new", file=sys.stderr)
        return 1
    for src, dst in moves.items():
        print(f"{a.run}/{src} -> docs/history/{run.name}/{dst}")
    new_texts = {}
    for s in specs:
        text, role = retire_spec(s.read_text(encoding="utf-8"), moves, renames, run.name, a.label)
        n = names[s]
        target = s.with_name(s.name.replace(n, renames[n], 1)) if n in renames else s
        new_texts[s] = (target, text)
        if target != s:
            print(f"{s.relative_to(ROOT)} -> {target.relative_to(ROOT)}")
        if role:
            print(f"target role {role!r} given up by {target.relative_to(ROOT)}")
    if a.dry_run:
        return 0
    hist.mkdir(parents=True, exist_ok=True)
    for src, dst in moves.items():
        subprocess.run(["git", "mv", str(run / src), str(hist / dst)], check=True, cwd=ROOT)
    for s, (target, text) in new_texts.items():
        if target != s:
            subprocess.run(["git", "mv", str(s), str(target)], check=True, cwd=ROOT)
        atomic_text(target, text)
    text_moves = named_in_text(moves)
    for f in TEXT_FILES:
        p = ROOT / f
        t = p.read_text()
        t2 = rename_in_text(t, text_moves, run.name)
        if t2 != t:
            atomic_text(p, t2)
            print(f"renamed file names in {f}")
    print("next: edit the retired specs' [commands] (they still use the run's model.hbeo and reproduce), write the "
          "new reference's specs, then python -m hbeo experiment table --readme README.md (maintainer/README.md)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
