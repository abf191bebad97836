"""The user documentation speaks of the project only: no issue numbers, no work briefs, no maintainer scripts'
step ids, no talk of working sessions, no dated work log (who ran what when) and no tags (a clone has none: the
docs cite commits). The history of measurements and choices lives in docs/history/, which this test
leaves alone.

Scanned: README.md, docs/ (but docs/history/ and what a docs build writes: _build/, _api/,
_notebooks/), every notebook's cells (markdown and code), paper/, results/README.md and benchmarks/README.md.
A failure names the file, the line (for a notebook: the cell and its line) and the rule it breaks."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent

#: (rule, pattern): what user documentation never says
RULES: list[tuple[str, re.Pattern]] = [
    ("an issue number", re.compile(r"\bissues?\s*[#-]?\s*\d", re.I)),
    ("the work brief", re.compile(r"\bthe brief\b", re.I)),
    ("a maintainer script's name (model_table.sh)", re.compile(r"model_table\.sh")),
    ("a script step id (step 4q)", re.compile(r"\bsteps?\s+\d+[a-z]\b", re.I)),
    # the step ids of the maintainer's model-table script (1b, 1c, 2b, 4b ... 4r), standing alone: not in a
    # word, a number (1.4e), a format (%4d, {:.4f}) or a path
    ("a script step id (4k)", re.compile(r"(?<![\w.%:{/\\-])(?:1[a-c]|2[ab]|4[a-r])(?![\w/])")),
    ("talk of a working session", re.compile(r"\bsessions?\b", re.I)),
    ("a date (a work log: the docs cite commits)", re.compile(r"\b20\d\d-[01]\d-[0-3]\d\b")),
    ("a clock time (a work log)", re.compile(r"\b\d{1,2}:\d\d(?:\s*[–-]\s*\d{1,2}:\d\d)?\s*UTC\b")),
    ("a tag (a clone has none: cite the commit)",
     re.compile(r"\btags?\s+`[^`]+`|\bgit (?:checkout|switch) [\w.-]*-20\d\d")),
]
#: the rules a path may break: a file or folder of the history may carry a date in its name
PATH_EXEMPT = ("a date (a work log: the docs cite commits)",)
#: the word around a match, to tell a path (it holds a "/") from prose
_TOKEN_END = " \t`'\"()[]<>,;"
#: words that make "session" something else than a working session (a process's, a Python prompt's)
OTHER_SESSIONS = re.compile(r"\b(?:process|interactive|python|ipython|jupyter|kernel|ssh|login|terminal|tmux|dask"
                            r"|shell|browser|notebook)\s+$", re.I)
#: file kinds read as text
TEXT = {".md", ".rst", ".txt", ".py", ".ipynb", ".csv", ".json", ".toml", ".cfg", ".html"}
#: docs/ paths left alone: the history, and what a docs build writes
DOCS_SKIPPED = ("history", "_build", "_api", "_notebooks", "__pycache__")


def documents(root: Path = ROOT) -> list[Path]:
    """The files the rules apply to (those that exist)."""
    out = [root / "README.md", root / "results" / "README.md", root / "benchmarks" / "README.md"]
    out += sorted((root / "notebooks").glob("*.ipynb"))
    out += sorted(p for p in (root / "paper").rglob("*") if p.is_file() and p.suffix in TEXT)
    docs = root / "docs"
    out += sorted(p for p in docs.rglob("*") if p.is_file() and p.suffix in TEXT
                  and p.relative_to(docs).parts[0] not in DOCS_SKIPPED)
    return [p for p in out if p.is_file()]


def lines_of(path: Path) -> list[tuple[str, str]]:
    """(where, text) per line: ``12`` for a text file, ``cell 3 line 4`` for a notebook's cell."""
    if path.suffix == ".ipynb":
        cells = json.loads(path.read_text(encoding="utf-8"))["cells"]
        return [(f"cell {i} ({c['cell_type']}) line {j}", line)
                for i, c in enumerate(cells, 1)
                for j, line in enumerate("".join(c.get("source", "")).splitlines(), 1)]
    return [(str(i), line) for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)]


def _token(text: str, start: int, end: int) -> str:
    """The word of ``text`` that holds ``text[start:end]``, up to spaces, quotes, brackets and backticks."""
    while start > 0 and text[start - 1] not in _TOKEN_END:
        start -= 1
    while end < len(text) and text[end] not in _TOKEN_END:
        end += 1
    return text[start:end]


def problems(text: str) -> list[str]:
    """The rules ``text`` (one line) breaks, each with what matched."""
    found = []
    for rule, pattern in RULES:
        for m in pattern.finditer(text):
            if rule.startswith("talk of a working session") and OTHER_SESSIONS.search(text[:m.start()]):
                continue
            if rule in PATH_EXEMPT and "/" in _token(text, m.start(), m.end()):
                continue
            found.append(f"{rule}: {m.group(0)!r}")
    return found


def findings(root: Path = ROOT) -> list[str]:
    out = []
    for path in documents(root):
        for where, text in lines_of(path):
            out += [f"{path.relative_to(root)}:{where}: {p}" for p in problems(text)]
    return out


@pytest.mark.parametrize("text, rule", [
    ("closes issue 29 item 4", "issue"), ("see Issue #30", "issue"), ("the issue-5 runs", "issue"),
    ("As the brief asks", "brief"), ("scripts/model_table.sh 4q", "model_table.sh"),
    ("then step 4k", "step id"), ("(Step 4m)", "step id"), ("the wider layers (4k) and 60 epochs (4l)", "step id"),
    ("4l's last clause", "step id"), ("in the next session", "session"), ("This session did not measure it", "session"),
    ("over two sessions", "session"), ("Measured 2026-11-22", "date"), ("(13:45–14:00 UTC)", "clock"),
    ("commit `78a8306b86`, tag `repro-cpu-2026-12-01-e60`", "tag"), ("at repro-cpu-2026-12-01-e60", "date"),
    ("198 min (2026-12-02)", "date"),
])
def test_the_rules_catch_work_log_language(text, rule):
    assert any(rule in p for p in problems(text)), (text, problems(text))


@pytest.mark.parametrize("text", [
    "`--rotation 6d`: the continuous 6-D rotation output", "agree to ~1e-7 in depth", "{x:.4f} and %4d",
    "a 3D ShapeNets grid", "5k–50k-face meshes", "an issue tracker (README, 'Bad input')",
    "in an interactive session",
    "its own process session", "commit `78a8306b86`, clean tree", "9.45e+03 ms", "conv2d, 1e-4",
    "the log: `docs/history/cpu-modelnet10-vox30/determinism-2026-11-27/`",
])
def test_the_rules_leave_project_language_alone(text):
    assert not problems(text), problems(text)


def test_user_docs_speak_of_the_project_only():
    found = findings()
    assert not found, (f"{len(found)} lines of the user documentation speak of the work rather than the project "
                       "(move logs to docs/history/, cite commits):\n" + "\n".join(found))
