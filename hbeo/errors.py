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
