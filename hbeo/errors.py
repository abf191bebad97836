"""Exceptions with messages a user can act on (they name the file and the problem), and the words for an
operating-system error (:func:`os_error_line`) that the command line prints."""
from __future__ import annotations

import errno
import os
from pathlib import Path


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


def require_file(path, what: str) -> None:
    """DataError naming ``path`` when it is not a file: missing (``no such WHAT file``) or a folder."""
    if Path(path).is_dir():
        raise DataError(path, f"is a folder, not a {what} file")
    if not Path(path).is_file():
        raise DataError(path, f"no such {what} file")


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


#: what an operating-system error means, in words
_OS_WORDS = {errno.ENOSPC: "no space left on the device", errno.EROFS: "read-only file system",
             errno.EACCES: "permission denied", errno.EPERM: "operation not permitted",
             errno.ENOTDIR: "not a folder", errno.EISDIR: "is a folder, not a file",
             errno.ENOENT: "no such file or folder", errno.EEXIST: "already exists",
             errno.EDQUOT: "disk quota exceeded", errno.ENAMETOOLONG: "file name too long",
             errno.EIO: "input/output error (a failing disk or a lost network drive?)",
             errno.EMFILE: "too many open files", errno.EXDEV: "cannot move across file systems",
             errno.ENOTEMPTY: "folder not empty", errno.ELOOP: "too many symbolic links"}
_PATH_SETTINGS = ("HBEO_RESULTS", "HBEO_CACHE", "HBEO_DATA")


def os_error_line(err: OSError) -> str:
    """``PATH: what happened`` in words for an operating-system error (the CLI's one error line) (the file in the way for ENOTDIR, and the
    setting that pointed there)."""
    path = err.filename
    own = err.strerror if (err.strerror or "").startswith("cannot ") else None     # atomic_file's own words
    words = own or _OS_WORDS.get(err.errno) or (err.strerror or str(err)).lower()
    if path is None:
        return words
    path = os.fsdecode(path)
    if err.errno == errno.ENOTDIR:              # name the file that stands where a folder must be
        for parent in [Path(path), *Path(path).parents]:
            if parent.exists():
                if not parent.is_dir():
                    words, path = "not a folder (a file is in the way)", str(parent)
                break
    for name in _PATH_SETTINGS:
        value = os.environ.get(name)
        if value and (path == value or path.startswith(value.rstrip("/") + "/")):
            words += f" (set by {name})"
            break
    return f"{path}: {words}"
