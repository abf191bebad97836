"""Download and extract the ModelNet10 archive: pooch fetches and verifies, zipfile extracts.

Owns: fetching ``ModelNet10.zip`` (:func:`download`, :func:`fetch_modelnet10`), extracting
it safely (:func:`extract_zip`) and finding the folder that holds the class folders
(:func:`find_class_root`). Imports only the foundation (:mod:`hbeo.storage`,
:mod:`hbeo.errors`) and third-party packages (pooch, requests, tqdm).

Download (:func:`download`, with `pooch <https://www.fatiando.org/pooch>`__)
    pooch streams the file into a temporary file beside ``dest``, checks its sha256 and only
    then renames it to ``dest``: ``dest`` never holds a partial or unverified file. An
    interrupted attempt (dropped connection, truncated body, timeout, server error, hash
    mismatch) is deleted and restarted from zero up to ``retries`` times; there is no
    resume. Ctrl-C removes the temporary file too; only a killed process leaves a ``tmp*``
    file behind (never taken for the archive; delete it). When ``dest`` already exists and
    matches the expected hash, nothing touches the network; when it does not match, it is
    downloaded again. Failures raise :class:`DownloadError` with one line naming the URL.

Expected hash
    :data:`MODELNET10_SHA256` is the pin slot for the official archive's sha256. Princeton
    publishes no checksum and none could be verified while writing this, so it is None
    (no invented value). Until it is set, :func:`download` falls back on trust on first use:
    every successful download records the file's sha256 in ``<dest>.sha256``
    (``sha256sum`` format) and later calls verify against that record (delete it to accept
    a legitimately changed upstream file). A given ``expected_sha256`` always wins.

Extraction (:func:`extract_zip`, stdlib ``zipfile``)
    Members with absolute paths or ``..`` components are refused before anything is
    written. The archive is extracted into a temporary sibling directory
    ``.tmp-<name>-<pid>``, CRC-checked as it is read, marked complete with a ``.complete``
    file holding the archive's sha256, and only then renamed into place. A directory
    without a matching ``.complete`` is never taken as extracted; temporary directories
    left by a killed run are removed by the next call. A corrupted archive raises
    :class:`DownloadError` telling the user to delete it and download again.

Concurrent calls on the same target (two processes downloading the same file at once) are
not supported.
"""
from __future__ import annotations

import glob
import logging
import os
import re
import shutil
import zipfile
import zlib
from pathlib import Path

from tqdm import tqdm

from hbeo.errors import HBEOError
from hbeo.storage import read_sidecar, sha256_file, sidecar_path, write_sidecar

logger = logging.getLogger(__name__)

MODELNET10_URL = "http://3dvision.princeton.edu/projects/2014/3DShapeNets/ModelNet10.zip"

#: sha256 of the official ModelNet10.zip, enforced on every download and existing file once
#: set. None: no published, verifiable value was found (see the module docstring); the
#: first download's hash is recorded beside the archive instead (trust on first use).
MODELNET10_SHA256: str | None = None

MARKER_NAME = ".complete"        #: marker file written inside a fully extracted directory


class DownloadError(HBEOError, RuntimeError):
    """A download or extraction failed in a way that retrying will not fix."""


# ---------------------------------------------------------------------------
# download

def _one_line(err: BaseException, limit: int = 400) -> str:
    text = " ".join(str(err).split())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def download(url: str, dest, expected_sha256: str | None = None, progress: bool = True, *,
             retries: int = 2, timeout: float = 60.0) -> Path:
    """Download ``url`` to ``dest`` with pooch, verified, renamed into place; returns ``dest``.

    The expected sha256 is ``expected_sha256`` when given, else the record ``<dest>.sha256``
    of an earlier download, else none (the first download is recorded). ``retries``: failed
    attempts restarted before giving up; ``timeout``: seconds without data before one fails.
    Raises :class:`DownloadError` (one line naming ``url``) when the server cannot be reached,
    answers with an HTTP error, or the file does not match the expected hash.
    """
    import pooch
    import requests

    dest = Path(dest)
    recorded = read_sidecar(dest)
    want = expected_sha256.lower() if expected_sha256 else recorded
    hint = "" if expected_sha256 or want is None else \
        f" (expected hash recorded in {sidecar_path(dest)}: delete it if the upstream file legitimately changed)"
    fetcher = pooch.create(path=dest.parent, base_url="", registry={dest.name: want},
                           urls={dest.name: url}, retry_if_failed=int(retries))
    downloader = pooch.HTTPDownloader(progressbar=bool(progress), timeout=timeout,
                                      headers={"User-Agent": "hbeo-downloader"})
    try:
        fetcher.fetch(dest.name, downloader=downloader)
    except requests.exceptions.HTTPError as err:
        resp = err.response
        status = f"HTTP {resp.status_code} {resp.reason}" if resp is not None else _one_line(err)
        raise DownloadError(f"downloading {url} failed: {status}") from None
    except requests.exceptions.RequestException as err:    # unreachable, timed out, cut short
        offline = " (no internet connection?)" if isinstance(err, requests.exceptions.ConnectionError) else ""
        raise DownloadError(f"cannot download {url}{offline}: {_one_line(err, 200)}") from None
    except ValueError as err:        # pooch: the downloaded file does not match the expected hash
        raise DownloadError(f"downloading {url} to {dest}: {_one_line(err)}{hint}") from None
    if recorded is None or recorded != want:
        write_sidecar(dest, want)
    return dest


# ---------------------------------------------------------------------------
# extraction

def _unsafe_member(name: str) -> bool:
    """True for zip member names that would land outside the target directory."""
    n = name.replace("\\", "/")
    return n.startswith("/") or re.match(r"[A-Za-z]:", n) is not None or ".." in n.split("/")


def _read_marker(directory: Path) -> str | None:
    try:
        text = (directory / MARKER_NAME).read_text().split()
    except (FileNotFoundError, NotADirectoryError, UnicodeDecodeError):
        return None
    return text[0].lower() if text else None


def _remove_leftovers(dest_dir: Path) -> None:
    pattern = f".tmp-{glob.escape(dest_dir.name)}-*"
    for leftover in dest_dir.parent.glob(pattern):
        if leftover.is_dir() and not leftover.is_symlink():
            logger.info("removing leftover temporary directory %s", leftover)
            shutil.rmtree(leftover, ignore_errors=True)


def extract_zip(archive: Path, dest_dir: Path, progress: bool = True, *,
                sha256: str | None = None) -> Path:
    """Extract ``archive`` into ``dest_dir`` atomically; returns ``dest_dir``.

    Does nothing when ``dest_dir/.complete`` records the archive's sha256 (pass
    ``sha256`` if it is already known, to skip hashing the archive). An existing
    ``dest_dir`` that is incomplete or from another archive is replaced. Raises
    :class:`DownloadError` for a corrupted archive or an unsafe member path.
    """
    archive, dest_dir = Path(archive), Path(dest_dir)
    dest_dir.parent.mkdir(parents=True, exist_ok=True)
    _remove_leftovers(dest_dir)

    if not archive.is_file():
        raise DownloadError(f"archive {archive} does not exist")
    sha = (sha256 or sha256_file(archive)).lower()
    if _read_marker(dest_dir) == sha:
        return dest_dir
    if dest_dir.exists():
        logger.warning("%s is incomplete or from another archive; extracting again", dest_dir)

    corrupted = f"corrupted archive {archive}, delete it and download again"
    try:
        zf = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, EOFError) as e:
        raise DownloadError(f"{corrupted} ({e})") from e

    tmp = dest_dir.parent / f".tmp-{dest_dir.name}-{os.getpid()}"
    with zf:
        members = zf.infolist()
        bad = [m.filename for m in members if _unsafe_member(m.filename)]
        if bad:
            raise DownloadError(f"refusing to extract {archive}: unsafe member path(s) {bad[:5]}")
        try:
            tmp.mkdir()
            with tqdm(total=sum(m.file_size for m in members), unit="B", unit_scale=True,
                      unit_divisor=1024, desc=f"extract {archive.name}", disable=not progress) as bar:
                for member in members:
                    zf.extract(member, tmp)     # reads the whole member: CRC is checked here
                    bar.update(member.file_size)
            (tmp / MARKER_NAME).write_text(f"{sha}  {archive.name}\n")
            if dest_dir.exists() or dest_dir.is_symlink():
                old = dest_dir.parent / f"{tmp.name}-old"
                os.replace(dest_dir, old)
                os.replace(tmp, dest_dir)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, dest_dir)
        except (zipfile.BadZipFile, zlib.error, EOFError) as e:
            raise DownloadError(f"{corrupted} ({e})") from e
        finally:
            if tmp.exists():
                shutil.rmtree(tmp, ignore_errors=True)
    return dest_dir


# ---------------------------------------------------------------------------
# ModelNet10

def _is_class_dir(path: Path) -> bool:
    return (path / "train").is_dir() or (path / "test").is_dir()


def find_class_root(directory: Path, max_depth: int = 4) -> Path | None:
    """The shallowest directory under ``directory`` (itself included, at most
    ``max_depth`` levels down) whose subdirectories include class folders (folders
    with ``train/`` or ``test/``); None if there is none or ``directory`` is missing.

    ``__MACOSX`` and hidden directories (``.tmp-*`` extractions among them) are skipped.
    """
    level = [Path(directory)] if Path(directory).is_dir() else []
    for _ in range(max_depth + 1):
        nxt = []
        for d in level:
            try:
                children = sorted(c for c in d.iterdir() if c.is_dir()
                                  and not c.name.startswith((".", "__MACOSX")))
            except OSError:
                continue
            if any(_is_class_dir(c) for c in children):
                return d
            nxt.extend(children)
        level = nxt
    return None


def _class_root(extracted: Path, archive: Path) -> Path:
    found = find_class_root(extracted)
    if found is None:
        raise DownloadError(f"no class folders (<class>/train, <class>/test) found in {extracted}, "
                            f"extracted from {archive}; is this the ModelNet10 archive?")
    return found


def fetch_modelnet10(root, url: str = MODELNET10_URL, progress: bool = True, *,
                     expected_sha256: str | None = MODELNET10_SHA256) -> Path:
    """Download ModelNet10 to ``root/ModelNet10.zip``, extract it to ``root/ModelNet10/``
    and return the directory holding the class folders (``bathtub/``, ``chair/``...).

    Idempotent and offline once done. If the archive was deleted after a complete
    extraction, the extracted copy is used as is.
    """
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    archive, out = root / "ModelNet10.zip", root / "ModelNet10"

    marker = _read_marker(out)
    if not archive.exists() and marker is not None \
            and (expected_sha256 is None or marker == expected_sha256.lower()):
        logger.info("using extracted %s (archive %s is not present)", out, archive)
        return _class_root(out, archive)

    download(url, archive, expected_sha256=expected_sha256, progress=progress)
    extract_zip(archive, out, progress=progress, sha256=read_sidecar(archive))  # just verified
    return _class_root(out, archive)
