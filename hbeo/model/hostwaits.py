"""Where a CUDA run's host waits for the device: torch's sync debug mode, counted by the line that led to each wait.

:func:`host_waits` runs a block with torch's sync debug mode at ``warn`` on a CUDA device and counts every
synchronizing operation torch reports there (a device value read on the host, ``nonzero``, a blocking copy
between host and device memory) at the innermost line of the project's own code that led to it
(``hbeo/model/trainingdata.py:297 _on_device``). On another device the mode does not exist: the block runs as it
is and counts only what it warns itself with torch's message (:data:`MESSAGE`; what the tests do).

The GPU job times its calibration under it (``maintainer/device_job.py``; ``lease.json``'s ``budget``:
``host_waits`` and ``host_wait_sites``). The loop's step reads nothing back (:func:`hbeo.model.loop.train_step`;
``tests/test_train.py`` checks it on a GPU under the ``error`` mode), so the waits counted there are the data
path's and those of a training's start and end (validation, saving): what a faster loop would remove next.

May import: the foundation modules (here :mod:`hbeo.config`).
"""
from __future__ import annotations

import sys
import warnings
from collections import Counter
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import torch

from hbeo.config import REPO_ROOT

#: The warning of torch's sync debug mode at ``warn`` (c10/cuda/CUDAFunctions.cpp, ``warn_or_error_on_sync``).
MESSAGE = "called a synchronizing CUDA operation"
#: The repository's folders whose lines name a wait (the package, the maintainer and benchmark scripts, tests).
OWN = ("hbeo", "maintainer", "benchmarks", "scripts", "tests")


def site(frame) -> str:
    """``path:line function`` of the innermost frame of the project's own code from ``frame`` outwards (paths
    relative to the repository; the virtual environment inside it is not the project's), else of the innermost
    frame outside the warnings machinery."""
    f, first = frame, None
    while f is not None:
        path = Path(f.f_code.co_filename)
        rel = path.relative_to(REPO_ROOT) if path.is_relative_to(REPO_ROOT) else None
        if rel is not None and rel.parts[0] in OWN:
            return f"{rel}:{f.f_lineno} {f.f_code.co_name}"
        if first is None and f.f_code.co_filename != warnings.__file__:
            first = f
        f = f.f_back
    first = first or frame
    return f"{first.f_code.co_filename}:{first.f_lineno} {first.f_code.co_name}"


@contextmanager
def host_waits(device) -> Iterator[Counter]:
    """Run the block counting the host's waits for ``device`` (a Counter of :func:`site` -> waits, filled as the
    block runs); other warnings are shown as they would be. The sync debug mode is set back afterwards."""
    counts: Counter = Counter()
    cuda = torch.device(device).type == "cuda"
    show = warnings.showwarning

    def hook(message, category, filename, lineno, file=None, line=None):
        if str(message).startswith(MESSAGE):
            counts[site(sys._getframe(1))] += 1
        else:
            show(message, category, filename, lineno, file, line)

    with warnings.catch_warnings():
        warnings.filterwarnings("always", message=MESSAGE)       # every one, not once a line
        warnings.showwarning = hook
        before = torch.cuda.get_sync_debug_mode() if cuda else None
        if cuda:
            torch.cuda.set_sync_debug_mode("warn")
        try:
            yield counts
        finally:
            if cuda:
                torch.cuda.set_sync_debug_mode(before)
