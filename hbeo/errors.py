"""Exceptions with messages a user can act on (they name the file and the problem)."""
from __future__ import annotations

import os


class HBEOError(Exception):
    """Base class of the errors hbeo raises on bad input or missing data."""


class DataError(HBEOError, ValueError):
    """A file or array that cannot be used; the message names the file and why."""

    def __init__(self, path, problem: str):
        self.path = None if path is None else os.fspath(path)
        self.problem = problem
        where = f"{self.path}: " if self.path else ""
        super().__init__(f"{where}{problem}")

    def __reduce__(self):   # picklable across worker processes
        return (type(self), (self.path, self.problem))


class MissingDataError(HBEOError, FileNotFoundError):
    """A dataset or file that is not where the settings say; the message says how to get it."""


class BatchError(DataError):
    """A batch (voxelizing, rendering, evaluating a split) in which no item succeeded.

    ``failures``: one dict per bad item (``{file, reason, step, object, split, position}``, as the
    run's ``failures.json`` lists them). A constructor argument and an attribute, so it survives
    pickling (an error raised in a worker process keeps its list)."""

    def __init__(self, path, problem: str, failures=()):
        super().__init__(path, problem)
        self.failures = list(failures)

    def __reduce__(self):   # picklable across worker processes, failures included
        return (type(self), (self.path, self.problem, self.failures))
