"""Comparing two run folders' tables, the measured timings aside: does a run reproduce a committed one?

A run folder's tables are its ``*.csv`` and ``*.md`` files (:mod:`hbeo.report.tables` writes both;
``REPRODUCTION.md`` and ``model_table.md`` are Markdown too). Two runs of the same command on the same
kind of machine should agree in every cell except the ones that measure time on that machine: the
**timing columns**, whose header matches :data:`TIMING` (``median (s)``, ``mean (s)``, ``ms``,
``ms/query``, ``images/s (this run)``, ``wall_s``, ``time_utc``...; the paper's own reported times,
``paper: mean (s)``, are not measured and are compared). In Markdown, the cells of a table's timing
columns are dropped before comparing, and so is a prose line that states a measured time (``Reproduced
on: ...``-style lines are compared, since they name the machine, not a time). A row that states a measured time
per query in a cell (a claim about speed: ``5.47 [5.12, 5.74] ms``) has its figures, intervals and verdict
compared as ``<time>``; the run folder's own path, which reports name, is compared as ``<run>``.

:func:`table_differences` lists what differs (files one run lacks, rows, cells), with the file and the
column; ``scripts/compare_runs.py A B`` prints the list and exits 1 when it is not empty.

May import: foundation.
"""
from __future__ import annotations

import csv
import io
import re
from pathlib import Path

#: A column header that names a measured time or rate (not the paper's reported one).
TIMING = re.compile(r"^(?!paper)(?:.*\((?:s|ms)\)|.*\bms(?:\b|_).*|.*images/s.*|.*wall.*|time_utc|.*seconds.*)$", re.I)
#: A Markdown prose line that states a measured time (compared with its figures removed).
_TIME_IN_PROSE = re.compile(r"\d[\d.,]*\s*(?:min|s|ms|h)\b")
#: A cell that states a measured time per query (``5.47 [5.12, 5.74] ms``): its row is a timing row, whose numbers
#: and verdict (a claim about speed) are measured on the machine and compared as ``<time>``
_TIME_CELL = re.compile(r"[\d\]]\s*ms\b")
#: a timing row's cells that are measured: a figure, an interval, a verdict
_MEASURED_CELL = re.compile(r"^(?:-?[\d.,]+(?:\s*\[[-\d., ]+\])?|holds|fails|inconclusive)$")
#: The tables of a run folder.
PATTERNS = ("*.csv", "*.md")


def _timing_row(cells: list[str]) -> list[str]:
    """A table row with its measured cells as ``<time>`` when it is a timing row (:data:`_TIME_CELL`)."""
    if not any(_TIME_CELL.search(c) for c in cells):
        return cells
    return ["<time>" if _TIME_CELL.search(c) or _MEASURED_CELL.match(c.strip()) else c for c in cells]


def is_timing(header: str) -> bool:
    """Whether a column ``header`` names a measured time (:data:`TIMING`)."""
    return bool(TIMING.match(header.strip()))


def _csv_rows(text: str) -> list[list[str]]:
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        return rows
    keep = [i for i, h in enumerate(rows[0]) if not is_timing(h)]
    return [_timing_row([r[i] if i < len(r) else "" for i in keep]) for r in rows]


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _md_lines(text: str) -> list[str]:
    """The Markdown's lines with its tables' timing cells dropped and measured times in prose blanked."""
    out, keep = [], None
    for line in text.splitlines():
        if line.lstrip().startswith("|"):
            cells = _cells(line)
            if keep is None:                   # a table's header row
                keep = [i for i, h in enumerate(cells) if not is_timing(h)]
            out.append(" | ".join(_timing_row([cells[i] for i in keep if i < len(cells)])))
            continue
        keep = None
        out.append(_TIME_IN_PROSE.sub("<time>", line) if re.search(r"wall|took|time", line, re.I) else line)
    return out


def _lines(path: Path, run: Path) -> list:
    """The file's rows (CSV) or lines (Markdown), with the run folder's own path, as the reports write it
    (relative to the repository or absolute), replaced by ``<run>``: two runs in two folders name theirs."""
    import os
    text = path.read_text(encoding="utf-8")
    here = run.resolve()
    roots = [Path(__file__).resolve().parents[2]] + [p for p in here.parents if (p / "hbeo").is_dir()]   # checkouts
    forms = {str(here), str(run)} | {os.path.relpath(here, r) for r in roots}
    for form in sorted(forms, key=len, reverse=True):
        text = text.replace(form, "<run>")
    return _csv_rows(text) if path.suffix == ".csv" else _md_lines(text)


def table_differences(a, b, patterns=PATTERNS) -> list[str]:
    """What differs between the tables of run folders ``a`` and ``b`` (paths), timing columns aside: one
    line per file only one of them has, per file of another length, and per differing row (the first
    differing cell named by its column). Empty: the runs agree."""
    a, b = Path(a), Path(b)
    for d in (a, b):
        if not d.is_dir():
            raise FileNotFoundError(f"{d}: not a run folder")
    names = lambda d: {p.name for pat in patterns for p in d.glob(pat)}      # noqa: E731
    na, nb = names(a), names(b)
    out = [f"{n}: only in {a}" for n in sorted(na - nb)] + [f"{n}: only in {b}" for n in sorted(nb - na)]
    for name in sorted(na & nb):
        ra, rb = _lines(a / name, a), _lines(b / name, b)
        if len(ra) != len(rb):
            out.append(f"{name}: {len(ra)} rows in {a}, {len(rb)} in {b}")
        header = ra[0] if ra and isinstance(ra[0], list) else None
        for i, (x, y) in enumerate(zip(ra, rb)):
            if x == y:
                continue
            if isinstance(x, list):
                j = next((j for j, (u, v) in enumerate(zip(x, y)) if u != v), min(len(x), len(y)))
                col = header[j] if header and j < len(header) else f"column {j + 1}"
                out.append(f"{name}: row {i}, {col!r}: {x[j] if j < len(x) else '∅'} vs {y[j] if j < len(y) else '∅'}")
            else:
                out.append(f"{name}: line {i + 1}: {x!r} vs {y!r}")
    return out
