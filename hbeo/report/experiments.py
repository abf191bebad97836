"""Experiments as data: one TOML file per row of a run's model table, and the runner that lists, runs and
tabulates them (``python -m hbeo experiment list | run NAME [--dry-run] | table``).

A spec is ``experiments/<run folder>/<NN>-<name>.toml``: the folder names the run (``results/<run folder>/``), ``NN``
is the row's place in the model table, ``name`` what ``run`` takes. Its keys::

    name = "fc1024"                       # the file's name after "NN-"
    question = "..."                      # what the experiment asks
    status = "chosen"                     # one of STATUSES
    rule = "..."                          # the rule written before its result (or why there is none)
    needs = ["bal30"]                     # experiments whose models or metrics files its commands read
    seeds = { training = [0, 1, 2], views = 0 }
    profile = { batch_size = 64, ... }    # profile fields no flag sets: a run refuses if the profile changed
    [commands]                            # exact command lines, every option the profile decides written out
    train = [...]; val = [...]; test = [...]; compare = [...]
    [writes]                              # files the commands write, repository-relative
    val = [...]; test = [...]; other = [...]
    [row]                                 # the model-table row (hbeo.report.model_table): label, val, test,
    label = "..."                         # note, command, target_role, val_seeds, test_seeds; ``chosen``
                                          # and ``baseline`` follow from the status

TOML because the specs are written by hand and read by people: comments, multi-line strings for the rules,
no quoting of keys, and Python reads it with the standard library (:mod:`tomllib`), so nothing is added to
the dependencies and nothing a spec holds can run code. ``models.json`` (:attr:`hbeo.rundir.RunDir.model_rows`)
is generated from the specs (:func:`model_rows`, :func:`write_table`), never edited.

:func:`load` refuses a malformed spec with :class:`~hbeo.errors.DataError` naming the file and the problem;
:func:`run` runs a spec's commands in order (``python`` is this interpreter), refusing first when a model or
metrics file a command reads is missing (naming the experiment that makes it) or when the profile no longer
has the settings the spec was made with.

May import: foundation, :mod:`hbeo.report.model_table`.
"""
from __future__ import annotations

import re
import shlex
import subprocess
import sys
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from hbeo import config
from hbeo.errors import DataError, HBEOError
from hbeo.rundir import RunDir
from hbeo.storage import atomic_text, json_text

#: The repository's specs.
EXPERIMENTS = config.REPO_ROOT / "experiments"
#: status -> what it means; ``chosen`` in the row is True for the first two, ``baseline`` for ``baseline``.
STATUSES = {
    "reference": "the reference run's own model (or its extension), evaluated once on the test split",
    "chosen": "chosen on validation by its rule; the test split evaluated once",
    "superseded": "chosen or in use at its time, replaced since by a later row",
    "not chosen": "its rule was not met, or it was measured beside a rule: no test evaluation",
    "baseline": "another method, shown for its spread over training seeds",
    "paper": "the paper's method as written, beside the chosen recipe: trained once, the validation objects and the "
             "test split evaluated once each; no choice rests on it",
    "bar": "a reference figure for the targets table, not a model-table row",
    "pending": "its rule written and committed before any result; not yet run or not finished: no table row (its "
               "test commands, where it has any, run only once it is chosen or is the paper's row)",
}
CHOSEN = ("reference", "chosen")
PHASES = ("train", "val", "test", "compare")
WRITES = ("val", "test", "other")
#: the row's keys, in models.json's order (``chosen`` and ``baseline`` come from the status)
ROW_KEYS = ("label", "val", "test", "chosen", "note", "command", "target_role", "val_seeds", "test_seeds", "baseline")
ROLES = ("hbeo", "hbeo+verify", "beo-known")
_TOP = {"name": str, "question": str, "status": str, "rule": str, "needs": list, "seeds": dict, "profile": dict,
        "commands": dict, "writes": dict, "row": dict}
_REQUIRED = ("name", "question", "status", "rule", "seeds", "commands", "writes", "row")
_FILE = re.compile(r"^(\d{2})-([a-z0-9][a-z0-9.-]*)\.toml$")
#: options of the scripts a command may run whose values are files the command reads
_INPUT_OPTIONS = ("--model", "--ensemble")


@dataclass(frozen=True)
class Experiment:
    """One spec, checked (:func:`load`)."""

    path: Path
    order: int
    name: str
    question: str
    status: str
    rule: str
    needs: tuple[str, ...]
    seeds: dict
    profile: dict
    commands: dict[str, tuple[str, ...]]
    writes: dict[str, tuple[str, ...]]
    row: dict

    @property
    def run_name(self) -> str:
        """The run folder's name (the spec's folder)."""
        return self.path.parent.name

    @property
    def repo(self) -> Path:
        """Where the commands run and the paths point from: the folder above ``experiments/``."""
        return self.path.parent.parent.parent

    @property
    def run(self) -> RunDir:
        return RunDir(self.repo / "results" / self.run_name)

    def model_row(self) -> dict:
        """The ``models.json`` row: the ``[row]`` fields in :data:`ROW_KEYS` order, ``chosen`` from the status,
        ``baseline`` for a baseline."""
        r = {**self.row, "chosen": self.status in CHOSEN}
        r.setdefault("val", None)
        r.setdefault("test", None)
        if self.status == "baseline":
            r["baseline"] = True
        return {k: r[k] for k in ROW_KEYS if k in r}

    def row_files(self) -> list[tuple[str, str]]:
        """(split, file name) of every metrics file the row shows."""
        out = [(s, self.row[s]) for s in ("val", "test") if self.row.get(s)]
        return out + [(s, n) for s in ("val", "test") for n in self.row.get(f"{s}_seeds", [])]

    def where(self, name: str) -> Path:
        """A row file's path: in the run folder, else (a model the run no longer holds) its history folder."""
        run = self.run
        here = run.path / name
        hist = self.repo / "docs" / "history" / run.path.name / name
        return hist if not here.exists() and hist.exists() else here

    def all_commands(self) -> list[tuple[str, str]]:
        return [(phase, c) for phase in PHASES for c in self.commands.get(phase, ())]


# ---------------------------------------------------------------------------------------------- reading

def _fail(path: Path, problem: str):
    raise DataError(path, f"malformed experiment spec: {problem}")


def _strings(path: Path, where: str, value, allow_empty: bool = True) -> tuple[str, ...]:
    if not isinstance(value, list) or not all(isinstance(x, str) and x.strip() for x in value):
        _fail(path, f"{where} must be a list of non-empty strings")
    if not allow_empty and not value:
        _fail(path, f"{where} is empty")
    return tuple(value)


def command_argv(command: str, path: Path | None = None) -> list[str]:
    """A spec's command line as arguments, ``python`` replaced by this interpreter; only ``python -m hbeo ...``
    and ``python PATH.py ...`` (a script of the repository) are commands."""
    try:
        argv = shlex.split(command)
    except ValueError as err:
        _fail(path, f"command {command!r}: {err}")
    ok = len(argv) >= 2 and argv[0] == "python" and (
        (argv[1] == "-m" and len(argv) >= 4 and argv[2] == "hbeo") or (argv[1].endswith(".py") and "/" in argv[1]
                                                                        and not argv[1].startswith("/")))
    if not ok:
        _fail(path, f"command {command!r}: a command is `python -m hbeo SUBCOMMAND ...` or `python DIR/SCRIPT.py ...`")
    return [sys.executable, *argv[1:]]


def _option(argv: list[str], name: str) -> list[str]:
    return [argv[i + 1] for i, a in enumerate(argv[:-1]) if a == name] + \
        [a.split("=", 1)[1] for a in argv if a.startswith(name + "=")]


def _subcommand(argv: list[str]) -> str | None:
    return argv[3] if argv[1:3] == ["-m", "hbeo"] else None


def load(path) -> Experiment:
    """Read and check one spec; :class:`DataError` naming the file and the problem when it is malformed."""
    path = Path(path)
    m = _FILE.match(path.name)
    if not m:
        _fail(path, "the file name must be NN-NAME.toml (NN: the row's two-digit place in the model table; NAME in "
                    "lower case, digits, '.' and '-')")
    try:
        spec = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as err:
        _fail(path, f"not valid TOML ({err})")
    except OSError as err:
        raise DataError(path, f"cannot read the experiment spec ({err.strerror or err})") from None
    unknown = sorted(set(spec) - set(_TOP))
    if unknown:
        _fail(path, f"unknown key(s) {', '.join(unknown)}; a spec has {', '.join(_TOP)}")
    missing = [k for k in _REQUIRED if k not in spec]
    if missing:
        _fail(path, f"missing key(s) {', '.join(missing)}")
    for k, typ in _TOP.items():
        if k in spec and not isinstance(spec[k], typ):
            _fail(path, f"{k} must be a {'string' if typ is str else 'table' if typ is dict else 'list'}")
    if spec["name"] != m[2]:
        _fail(path, f"name {spec['name']!r} is not the file's name after its number ({m[2]!r})")
    for k in ("question", "rule"):
        if not spec[k].strip():
            _fail(path, f"{k} is empty (a rule with none written says so and why)")
    if spec["status"] not in STATUSES:
        _fail(path, f"status {spec['status']!r}; expected one of {', '.join(STATUSES)}")
    needs = _strings(path, "needs", spec.get("needs", []))
    seeds = spec["seeds"]
    train = seeds.get("training")
    if set(seeds) != {"training", "views"} or not isinstance(train, list) or \
            not all(isinstance(s, int) and s >= 0 for s in train) or not isinstance(seeds.get("views"), int):
        _fail(path, "seeds must be { training = [whole numbers >= 0], views = WHOLE NUMBER }")
    profile = spec.get("profile", {})
    known = config.get_profile("cpu").to_dict()
    if set(profile) - set(known):
        _fail(path, f"profile names unknown field(s) {', '.join(sorted(set(profile) - set(known)))}")
    commands, writes = spec["commands"], spec["writes"]
    if set(commands) - set(PHASES):
        _fail(path, f"[commands] has {', '.join(sorted(set(commands) - set(PHASES)))}; its lists are {', '.join(PHASES)}")
    if set(writes) - set(WRITES):
        _fail(path, f"[writes] has {', '.join(sorted(set(writes) - set(WRITES)))}; its lists are {', '.join(WRITES)}")
    commands = {p: _strings(path, f"commands.{p}", commands.get(p, [])) for p in PHASES}
    writes = {w: _strings(path, f"writes.{w}", writes.get(w, [])) for w in WRITES}
    for w in ("val", "test"):
        for f in writes[w]:
            if not f.endswith(".json") or f.startswith("/") or ".." in Path(f).parts:
                _fail(path, f"writes.{w}: {f!r} is not a repository-relative metrics file (.json)")
    for phase, c in [(p, c) for p in PHASES for c in commands[p]]:
        argv = command_argv(c, path)
        if _subcommand(argv) == "evaluate":
            out = _option(argv, "--out")
            split = (_option(argv, "--split") or ["test"])[0]
            if not out or out[0] not in writes.get(split, ()):
                _fail(path, f"commands.{phase}: {c!r} writes {out[0] if out else 'no --out'}, which writes.{split} "
                            f"does not list")
    if spec["status"] == "not chosen" and (commands["test"] or writes["test"]):
        _fail(path, "status 'not chosen' with test commands or files: the test split is evaluated for chosen rows only")
    row = _check_row(path, spec["row"], spec["status"])
    exp = Experiment(path, int(m[1]), spec["name"], spec["question"].strip(), spec["status"], spec["rule"].strip(),
                     needs, {"training": list(train), "views": seeds["views"]}, dict(profile),
                     commands, writes, row)
    return exp


def _check_row(path: Path, row: dict, status: str) -> dict:
    for k in ("chosen", "baseline"):
        if k in row:
            _fail(path, f"row.{k} follows from the status; remove it")
    unknown = sorted(set(row) - set(ROW_KEYS))
    if unknown:
        _fail(path, f"row has unknown key(s) {', '.join(unknown)}; a row has {', '.join(ROW_KEYS[:3] + ROW_KEYS[4:-1])}")
    if not isinstance(row.get("label"), str) or not row["label"].strip():
        _fail(path, "row.label must be a non-empty string")
    for k in ("val", "test", "note", "command", "target_role"):
        if k in row and not (isinstance(row[k], str) and row[k].strip()):
            _fail(path, f"row.{k} must be a non-empty string (leave it out for none)")
    for k in ("val_seeds", "test_seeds"):
        if k in row:
            _strings(path, f"row.{k}", row[k], allow_empty=False)
    if "target_role" in row and row["target_role"] not in ROLES:
        _fail(path, f"row.target_role {row['target_role']!r}; expected one of {', '.join(ROLES)}")
    if (status == "bar") != (row.get("target_role") == "beo-known"):
        _fail(path, "status 'bar' goes with row.target_role 'beo-known', and only with it")
    if not row.get("val") and status not in ("baseline", "bar"):
        _fail(path, "row.val is missing: every configuration is compared on the validation objects")
    return dict(row)


def load_all(root=None) -> list[Experiment]:
    """Every spec under ``root`` (default :data:`EXPERIMENTS`), by run folder and place; checks that names are
    unique, places unique within a run folder, ``needs`` name specs that exist, and every file a row shows is
    written by its spec or one it needs."""
    root = Path(root or EXPERIMENTS)
    if not root.is_dir():
        raise DataError(root, "no experiments folder")
    stray = [p for p in sorted(root.glob("*/*")) if p.suffix == ".toml" and not _FILE.match(p.name)]
    if stray:
        load(stray[0])
    exps = sorted((load(p) for p in root.glob("*/*.toml")), key=lambda e: (e.run_name, e.order, e.name))
    by_name: dict[str, Experiment] = {}
    for e in exps:
        if e.name in by_name:
            raise DataError(e.path, f"malformed experiment spec: name {e.name!r} is also {by_name[e.name].path}'s")
        by_name[e.name] = e
    for a, b in zip(exps, exps[1:]):
        if (a.run_name, a.order) == (b.run_name, b.order):
            raise DataError(b.path, f"malformed experiment spec: place {b.order:02d} is also {a.path.name}'s")
    for e in exps:
        for n in e.needs:
            if n not in by_name:
                raise DataError(e.path, f"malformed experiment spec: needs {n!r}, which no spec is named")
        written = {Path(f).name for x in (e, *(by_name[n] for n in e.needs)) for w in ("val", "test")
                   for f in x.writes[w]}
        for split, f in e.row_files():
            if f not in written:
                raise DataError(e.path, f"malformed experiment spec: row shows {f} ({split}), which neither writes.val "
                                        f"/ writes.test nor a spec it needs lists")
    return exps


def find(name: str, root=None) -> tuple[Experiment, list[Experiment]]:
    """The spec named ``name`` (or ``NN-name``), and all of them."""
    exps = load_all(root)
    for e in exps:
        if name in (e.name, e.path.stem):
            return e, exps
    raise HBEOError(f"no experiment named {name!r} (python -m hbeo experiment list shows them)")


# ---------------------------------------------------------------------------------------------- the three verbs

def listing(root=None) -> str:
    """Per run folder, one line per spec (model-table row): place, name, status, how many of the metrics files
    the row shows exist, and the start of its rule."""
    lines, run = [], None
    for e in load_all(root):
        if e.run_name != run:
            run = e.run_name
            lines.append(f"{run}: the rows of results/{run}/models.json")
        files = e.row_files()
        have = sum(e.where(f).exists() for _, f in files)
        rule = " ".join(e.rule.split())
        lines.append(f"  {e.order:02d} {e.name:<20} {e.status:<11} files {have}/{len(files)}"
                     f"{'' if have == len(files) else ' MISSING'}  rule: {rule[:80]}{'…' if len(rule) > 80 else ''}")
    return "\n".join(lines)


def profile_changes(exp: Experiment) -> list[str]:
    """How the profiles the spec's commands use differ from its ``profile`` table (empty: they agree)."""
    out = []
    for _, c in exp.all_commands():
        argv = command_argv(c, exp.path)
        for name in _option(argv, "--profile")[:1]:
            now = config.get_profile(name).to_dict()
            for k, v in exp.profile.items():
                have = list(now[k]) if isinstance(now[k], tuple) else now[k]
                if have != v:
                    out.append(f"profile {name}'s {k} is {have!r}, the spec was made with {v!r}")
    return sorted(set(out))


def _inputs(argv: list[str]) -> list[str]:
    """Files a command reads that another experiment makes: models, and a paired contrast's two metrics files."""
    files = [v for o in _INPUT_OPTIONS for v in _option(argv, o)]
    if argv[1].endswith("paired_contrast.py"):
        files += [a for a in argv[2:4] if a.endswith(".json")]
    return files


def _models_made(argv: list[str]) -> list[str]:
    """The model file a ``train`` or ``reproduce`` command writes (repository-relative), if it names its folder."""
    sub, out = _subcommand(argv), _option(argv, "--out")
    if sub not in ("train", "reproduce") or not out:
        return []
    return [f"{out[0].rstrip('/')}/{(_option(argv, '--name') or ['model.hbeo'])[0] if sub == 'train' else 'model.hbeo'}"]


def _rooted(argv: list[str], repo: Path) -> list[str]:
    """``argv`` as it runs: a leading ``python`` is the Python running hbeo now (``sys.executable``, so a spec runs
    in hbeo's own environment whatever ``python`` the shell's PATH finds), and a relative ``--out`` of an hbeo
    command is made absolute under ``repo``: every path of a spec is taken from the repository's top folder,
    whatever the command does with a relative one."""
    out = list(argv)
    if out and out[0] == "python":
        out[0] = sys.executable
    if _subcommand(argv) is None:
        return out
    for i, a in enumerate(out[:-1]):
        if a == "--out" and not Path(out[i + 1]).is_absolute():
            out[i + 1] = str(repo / out[i + 1])
    return out


def run(name: str, root=None, dry_run: bool = False, echo: Callable[[str], None] = print) -> list[Path]:
    """Run experiment ``name``'s commands in order (train, val, test, compare) in the repository; with ``dry_run``
    only print them. Returns the files its ``[writes]`` lists. Refuses before running anything when the profile
    changed (:func:`profile_changes`), and before each command when a file it reads is missing."""
    exp, exps = find(name, root)
    echo(f"# {exp.path.relative_to(exp.repo)}: {exp.status}; {' '.join(exp.question.split())}")
    changes = profile_changes(exp)
    if changes and not dry_run:
        raise HBEOError(f"{exp.path}: the commands would not reproduce the row: " + "; ".join(changes))
    for c in changes:
        echo(f"# warning: {c}")
    makers = {Path(f).name: e.name for e in exps for w in WRITES for f in e.writes[w]}
    makers.update({m: e.name for e in exps for _, c in e.all_commands() for m in _models_made(command_argv(c))})
    for phase, c in exp.all_commands():
        echo(f"[{phase}] {c}")
        if dry_run:
            continue
        argv = command_argv(c, exp.path)
        for f in _inputs(argv):
            if not (exp.repo / f).exists():
                who = makers.get(f) or makers.get(Path(f).name)
                made = f"it is made by experiment {who} (python -m hbeo experiment run {who})" if who else \
                    "no experiment's commands make it"
                raise HBEOError(f"{exp.repo / f}: missing; {exp.name} reads it ({phase} command {c!r}); {made}")
        done = subprocess.run(_rooted(argv, exp.repo), cwd=exp.repo)
        if done.returncode:
            raise HBEOError(f"{exp.path}: {phase} command failed (exit status {done.returncode}): {c}")
    written = [exp.repo / f for w in WRITES for f in exp.writes[w]]
    if not dry_run:
        missing = [str(p) for p in written if not p.exists()]
        if missing:
            raise HBEOError(f"{exp.path}: the commands ran but did not write {', '.join(missing)}")
        echo(f"# {exp.name}: wrote {len(written)} file(s); python -m hbeo experiment table regenerates the model table")
    return written


def model_rows(exps: list[Experiment], run_name: str) -> list[dict]:
    """The ``models.json`` rows of run folder ``run_name``: one per spec, in place order; ``pending`` specs
    (registered, not yet run) have no row."""
    return [e.model_row() for e in exps if e.run_name == run_name and e.status != "pending"]


def rows_text(rows: list[dict]) -> str:
    """``models.json``'s text: one-space indent, UTF-8 as is, a final newline."""
    return json_text(rows, indent=1, ensure_ascii=False) + "\n"


#: the generated block of the registered rows not yet run (:func:`pending_table`)
PENDING_BEGIN = "<!-- pending-rows: generated by `python -m hbeo experiment table --readme FILE`; do not edit -->"
PENDING_END = "<!-- /pending-rows -->"


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def pending_table(exps: list[Experiment], run_name: str) -> str:
    """Markdown: the ``pending`` specs of run folder ``run_name`` (registered with their rules, not yet run, so
    without a model-table row), each with its question, its rule and the command that runs it."""
    rows = [e for e in exps if e.run_name == run_name and e.status == "pending"]
    if not rows:
        return "Every registered row has run.\n"
    lines = ["| row | question | rule (committed before any result) | runs with |", "| --- | --- | --- | --- |"]
    lines += [f"| {e.order:02d} `{e.name}` | {_cell(e.question)} | {_cell(e.rule)} | "
              f"`python -m hbeo experiment run {e.name}` |" for e in rows]
    return "\n".join(lines) + "\n"


def write_table(root=None, readme=None) -> list[Path]:
    """For each run folder with specs: ``models.json`` generated from them, then the model and targets tables
    (:func:`hbeo.report.model_table.write_model_table`; with ``readme``, its generated blocks as well, and the
    block of registered rows not yet run (:func:`pending_table`) where it has one). Returns the files written."""
    from hbeo.report.model_table import replace_block, write_model_table
    exps = load_all(root)
    out = []
    for run_name in sorted({e.run_name for e in exps}):
        run = next(e for e in exps if e.run_name == run_name).run
        run.path.mkdir(parents=True, exist_ok=True)
        atomic_text(run.model_rows, rows_text(model_rows(exps, run_name)))
        out += [run.model_rows, write_model_table(run, readme)]
        if readme is not None and PENDING_BEGIN in Path(readme).read_text():
            text = replace_block(Path(readme).read_text(), pending_table(exps, run_name), str(readme),
                                 PENDING_BEGIN, PENDING_END)
            atomic_text(Path(readme), text)
    return out
