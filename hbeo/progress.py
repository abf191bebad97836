"""Progress bars: one ``tqdm`` for the whole package, and a side channel that lets a terminal follow a
notebook run by papermill.

Every module imports :func:`tqdm` from here instead of ``tqdm.auto``. In an interactive session it *is*
``tqdm.auto.tqdm`` (a widget in JupyterLab, text in a terminal). When the environment variable
:data:`PROGRESS_ENV` names a file (``python -m hbeo reproduce`` sets it for the notebooks it executes), each
bar writes its text form to that file instead (append mode, at most every :data:`MININTERVAL_S` seconds) and
the executed notebook keeps no widget output; :class:`ProgressEcho`, running in the parent process, prints
the latest bar (the step, the items done and tqdm's time estimate) to the terminal while the notebook runs.
In a notebook that papermill runs without that variable (``papermill in.ipynb out.ipynb``: the kernel ran
papermill's injected cell, :func:`run_by_papermill`), a bar is text on the cell's stderr, written at most
every :data:`MININTERVAL_S` seconds: the executed notebook keeps its last frame, not a widget's empty first.

Foundation layer: imports nothing from hbeo.
"""
from __future__ import annotations

import os
import re
import sys
import threading
import time
from pathlib import Path

PROGRESS_ENV = "HBEO_PROGRESS_FILE"
#: seconds between two writes of one bar to the progress file, and between two lines :class:`ProgressEcho` prints
MININTERVAL_S = 5.0


#: The first line of the cell papermill injects after a notebook's ``parameters`` cell (its Python translator).
PAPERMILL_HEADER = "# Parameters\n"


def kernel_history() -> list:
    """The cells this IPython kernel ran, in order (IPython's ``In``); [] outside IPython."""
    ip = sys.modules.get("IPython")
    shell = ip.get_ipython() if ip is not None else None
    return list(shell.user_ns.get("In", [])) if shell is not None else []


def run_by_papermill(history=None) -> bool:
    """Whether the kernel ran papermill's injected parameters cell (``history``: default :func:`kernel_history`)."""
    return any(str(cell).startswith(PAPERMILL_HEADER) for cell in (kernel_history() if history is None else history))


def _text_bar(args, kwargs, stream):
    from tqdm.std import tqdm as text
    kwargs.update(file=stream, mininterval=max(MININTERVAL_S, kwargs.get("mininterval", 0)), ncols=100,
                  dynamic_ncols=False, ascii=True)
    return text(*args, **kwargs)


def tqdm(*args, **kwargs):
    """``tqdm.auto.tqdm(*args, **kwargs)``, or, when :data:`PROGRESS_ENV` names a file, a text bar written to
    that file, or, in a notebook papermill runs without it, a text bar on stderr (the caller's ``disable``
    still applies)."""
    path = os.environ.get(PROGRESS_ENV)
    if not path:
        if run_by_papermill():
            return _text_bar(args, kwargs, sys.stderr)
        from tqdm.auto import tqdm as auto
        return auto(*args, **kwargs)
    stream = open(path, "a", buffering=1, encoding="utf-8")   # closed with the bar (below)
    bar = _text_bar(args, kwargs, stream)
    close = bar.close

    def close_both():
        close()
        stream.close()
    bar.close = close_both
    return bar


_SEGMENT = re.compile(r"[\r\n]+")


def latest_line(path: str | os.PathLike, tail_bytes: int = 4096) -> str:
    """The last non-blank line (split on ``\\r`` and ``\\n``) of a progress file; "" when there is none."""
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            size = f.tell()
            f.seek(max(0, size - tail_bytes))
            text = f.read().decode("utf-8", errors="replace")
    except OSError:
        return ""
    parts = [p.strip() for p in _SEGMENT.split(text) if p.strip()]
    return parts[-1] if parts else ""


class ProgressEcho:
    """While a notebook runs, print its latest progress line to ``out`` every :data:`MININTERVAL_S` seconds
    when it changed, prefixed by ``prefix`` and the time since the start. A context manager: on entry it sets
    :data:`PROGRESS_ENV` to a fresh file ``path`` (the kernel papermill starts inherits it), on exit it
    restores the variable and removes the file."""

    def __init__(self, path: str | os.PathLike, prefix: str, out=None, interval_s: float = MININTERVAL_S):
        self.path, self.prefix, self.out, self.interval_s = Path(path), prefix, out, interval_s
        self._stop = threading.Event()
        self._thread = None
        self._old = None
        self._t0 = 0.0

    def __enter__(self):
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.path.write_text("")
        self._old = os.environ.get(PROGRESS_ENV)
        os.environ[PROGRESS_ENV] = str(self.path)
        self._t0 = time.perf_counter()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()
        return self

    def _loop(self):
        last = ""
        while not self._stop.wait(self.interval_s):
            line = latest_line(self.path)
            if line and line != last:
                last = line
                mins, secs = divmod(int(time.perf_counter() - self._t0), 60)
                print(f"{self.prefix} {mins}:{secs:02d} | {line}", file=self.out or sys.stdout, flush=True)

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        if self._old is None:
            os.environ.pop(PROGRESS_ENV, None)
        else:
            os.environ[PROGRESS_ENV] = self._old
        self.path.unlink(missing_ok=True)
        return False
