"""Tests for hbeo.data.download against a local HTTP server on 127.0.0.1 (no internet)."""
from __future__ import annotations

import hashlib
import http.server
import io
import re
import socket
import threading
import zipfile
from pathlib import Path

import pytest

from hbeo.data.download import (MODELNET10_SHA256, MODELNET10_URL, DownloadError, download, extract_zip,
                                fetch_modelnet10, find_class_root)
from hbeo.errors import HBEOError

OFF = b"OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n3 0 2 3\n3 1 2 3\n"


def make_zip(members: dict[str, bytes], compression=zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for name, data in members.items():
            zf.writestr(zipfile.ZipInfo(name), data, compress_type=compression)
    return buf.getvalue()


def modelnet_members(prefix: str = "ModelNet10/") -> dict[str, bytes]:
    members = {}
    for cls in ("chair", "bed"):
        for split in ("train", "test"):
            for i in range(1, 4):
                # a little per-file padding so the archive is a few KB and cuts land mid-file
                members[f"{prefix}{cls}/{split}/{cls}_{i:04d}.off"] = OFF + b"# " + bytes(500) + b"\n"
    members[f"{prefix}README.txt"] = b"ModelNet10 test copy\n"
    return members


def sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


class _Handler(http.server.BaseHTTPRequestHandler):
    protocol_version = "HTTP/1.1"   # Content-Length is binding: a short body is a broken download

    def log_message(self, *args):  # keep test output quiet
        pass

    def do_GET(self):
        srv = self.server
        with srv.lock:
            srv.requests.append({"path": self.path, "range": self.headers.get("Range")})
            n_request = len(srv.requests)
        if srv.status is not None:
            self.send_error(srv.status)
            return
        data = srv.payload
        if srv.corrupt:
            mid = len(data) // 2
            data = data[:mid] + bytes([data[mid] ^ 0xFF]) + data[mid + 1:]
        self.send_response(200)
        self.send_header("Content-Type", "application/zip")
        self.send_header("Content-Length", str(len(data)))
        self.end_headers()
        if srv.cut_after is not None and n_request <= srv.cut_times:
            self.wfile.write(data[:srv.cut_after])  # then drop the connection
            self.wfile.flush()
            self.close_connection = True
            return
        self.wfile.write(data)


class _Server(http.server.ThreadingHTTPServer):
    daemon_threads = True

    def reset(self, payload: bytes = b""):
        self.payload = payload
        self.requests: list[dict] = []
        self.corrupt = False
        self.cut_after: int | None = None   # cut the connection after this many body bytes ...
        self.cut_times = 1                   # ... on the first `cut_times` requests
        self.status: int | None = None       # answer every request with this HTTP error
        self.lock = threading.Lock()

    def url(self, name: str = "ModelNet10.zip") -> str:
        return f"http://127.0.0.1:{self.server_address[1]}/{name}"


@pytest.fixture
def server(monkeypatch):
    monkeypatch.setenv("no_proxy", "127.0.0.1,localhost")
    monkeypatch.setenv("NO_PROXY", "127.0.0.1,localhost")
    srv = _Server(("127.0.0.1", 0), _Handler)
    srv.reset(make_zip(modelnet_members()))
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.01}, daemon=True)
    thread.start()
    yield srv
    srv.shutdown()
    srv.server_close()
    thread.join(timeout=5)


FAST = dict(progress=False, timeout=5, retries=0)


def leftovers(folder: Path) -> list[str]:
    """Files in ``folder`` other than finished archives and their records (pooch's temp files)."""
    return sorted(p.name for p in folder.iterdir() if not p.name.endswith((".zip", ".sha256")))


# ---------------------------------------------------------------------------
# download

def test_constants():
    assert MODELNET10_URL == "http://3dvision.princeton.edu/projects/2014/3DShapeNets/ModelNet10.zip"
    assert MODELNET10_SHA256 is None or re.fullmatch(r"[0-9a-f]{64}", MODELNET10_SHA256)
    assert issubclass(DownloadError, RuntimeError) and issubclass(DownloadError, HBEOError)


def test_download_writes_verified_file_and_record(server, tmp_path):
    dest = tmp_path / "sub" / "ModelNet10.zip"
    out = download(server.url(), dest, expected_sha256=sha(server.payload), progress=True, timeout=5)
    assert out == dest
    assert dest.read_bytes() == server.payload
    assert (tmp_path / "sub" / "ModelNet10.zip.sha256").read_text().split() == [sha(server.payload),
                                                                                  "ModelNet10.zip"]
    assert leftovers(tmp_path / "sub") == []
    assert len(server.requests) == 1


def test_download_is_idempotent_and_offline_once_done(server, tmp_path):
    dest = tmp_path / "a.zip"
    download(server.url(), dest, **FAST)
    download(server.url(), dest, **FAST)
    download(server.url(), dest, expected_sha256=sha(server.payload), **FAST)
    assert len(server.requests) == 1


def test_download_checksum_mismatch_is_refused(server, tmp_path):
    server.corrupt = True
    dest = tmp_path / "a.zip"
    url = server.url()
    with pytest.raises(DownloadError) as exc:
        download(url, dest, expected_sha256=sha(server.payload), **FAST)
    msg = str(exc.value)
    assert "\n" not in msg and url in msg and str(dest) in msg
    assert f"expected {sha(server.payload)}" in msg and "got" in msg
    assert not dest.exists() and not (tmp_path / "a.zip.sha256").exists()
    assert leftovers(tmp_path) == []


def test_interrupted_download_leaves_nothing_that_looks_complete(server, tmp_path):
    server.cut_after = 1000
    dest = tmp_path / "a.zip"
    with pytest.raises(DownloadError, match=re.escape(server.url())):
        download(server.url(), dest, **FAST)
    assert not dest.exists() and not (tmp_path / "a.zip.sha256").exists()
    assert leftovers(tmp_path) == []


def test_interrupted_download_restarts_cleanly(server, tmp_path):
    server.cut_after = 1000
    dest = tmp_path / "a.zip"
    download(server.url(), dest, expected_sha256=sha(server.payload), progress=False, timeout=5, retries=1)
    assert dest.read_bytes() == server.payload
    assert [r["range"] for r in server.requests] == [None, None]      # restarted from zero
    assert leftovers(tmp_path) == []


def test_download_verifies_against_its_record(server, tmp_path):
    dest = tmp_path / "a.zip"
    download(server.url(), dest, **FAST)
    dest.write_bytes(b"damaged")                 # file damaged after the fact
    download(server.url(), dest, **FAST)         # detected via the record; downloaded again
    assert dest.read_bytes() == server.payload
    assert len(server.requests) == 2

    dest.unlink()                                # upstream changes: the record catches it
    server.payload = make_zip({"x/y.txt": b"different"})
    with pytest.raises(DownloadError, match="a.zip.sha256"):   # the message points at the record
        download(server.url(), dest, **FAST)
    assert not dest.exists()


def test_download_existing_file_without_record_is_trusted(server, tmp_path):
    dest = tmp_path / "a.zip"
    dest.write_bytes(server.payload)             # e.g. copied in by hand
    download(server.url(), dest, **FAST)
    assert len(server.requests) == 0
    assert (tmp_path / "a.zip.sha256").read_text().split()[0] == sha(server.payload)


def test_download_http_error(server, tmp_path):
    server.status = 404
    with pytest.raises(DownloadError, match=r"downloading http://127\.0\.0\.1:\d+/ModelNet10\.zip failed: HTTP 404"):
        download(server.url(), tmp_path / "a.zip", **FAST)
    assert len(server.requests) == 1
    assert list(tmp_path.iterdir()) == []


def test_download_without_network_names_the_url(tmp_path, monkeypatch):
    monkeypatch.setenv("no_proxy", "127.0.0.1,localhost")
    monkeypatch.setenv("NO_PROXY", "127.0.0.1,localhost")
    with socket.socket() as s:                   # a port nobody listens on: connection refused
        s.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{s.getsockname()[1]}/ModelNet10.zip"
    with pytest.raises(DownloadError) as exc:
        download(url, tmp_path / "a.zip", **FAST)
    msg = str(exc.value)
    assert msg.startswith(f"cannot download {url}") and "\n" not in msg
    assert list(tmp_path.iterdir()) == []


# ---------------------------------------------------------------------------
# extraction

def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path


def test_extract_zip_and_idempotency(tmp_path, monkeypatch):
    archive = _write(tmp_path / "m.zip", make_zip(modelnet_members()))
    out = extract_zip(archive, tmp_path / "out", progress=False)
    assert out == tmp_path / "out"
    assert (out / "ModelNet10" / "chair" / "train" / "chair_0001.off").read_bytes().startswith(OFF)
    assert (out / ".complete").read_text().split()[0] == sha(archive.read_bytes())

    def boom(*a, **k):
        raise AssertionError("should not extract again")
    monkeypatch.setattr(zipfile.ZipFile, "extract", boom)
    assert extract_zip(archive, tmp_path / "out", progress=False) == out


def test_extract_replaces_incomplete_or_other_dir(tmp_path):
    dest = tmp_path / "out"
    (dest / "stale").mkdir(parents=True)        # half-extracted: no .complete marker
    a = _write(tmp_path / "a.zip", make_zip({"one.txt": b"1"}))
    extract_zip(a, dest, progress=False)
    assert sorted(p.name for p in dest.iterdir()) == [".complete", "one.txt"]
    b = _write(tmp_path / "b.zip", make_zip({"two.txt": b"2"}))
    extract_zip(b, dest, progress=False)        # another archive: re-extracted
    assert sorted(p.name for p in dest.iterdir()) == [".complete", "two.txt"]
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-")] == []


@pytest.mark.parametrize("kind", ["not_a_zip", "truncated", "crc"])
def test_extract_corrupted_archive(tmp_path, kind):
    good = make_zip(modelnet_members(), compression=zipfile.ZIP_STORED)
    if kind == "not_a_zip":
        data = b"<html>not found</html>" * 50
    elif kind == "truncated":
        data = good[: len(good) // 2]
    else:
        i = good.index(b"OFF\n4 4 0", 200) + 5   # inside a stored member's data
        data = good[:i] + b"X" + good[i + 1:]
    archive = _write(tmp_path / "ModelNet10.zip", data)
    dest = tmp_path / "ModelNet10"
    with pytest.raises(DownloadError) as exc:
        extract_zip(archive, dest, progress=False)
    msg = str(exc.value)
    assert str(archive) in msg and "corrupted" in msg and "download again" in msg
    assert not dest.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-")] == []


@pytest.mark.parametrize("name", ["../evil.txt", "ok/../../evil.txt", "/abs/evil.txt", "C:/evil.txt"])
def test_extract_rejects_path_traversal(tmp_path, name):
    archive = _write(tmp_path / "a.zip", make_zip({"fine.txt": b"ok", name: b"evil"}))
    dest = tmp_path / "deep" / "out"
    with pytest.raises(DownloadError, match="unsafe member"):
        extract_zip(archive, dest, progress=False)
    assert not dest.exists()
    assert not (tmp_path / "evil.txt").exists() and not (tmp_path / "deep" / "evil.txt").exists()


def test_extract_is_atomic(tmp_path, monkeypatch):
    archive = _write(tmp_path / "m.zip", make_zip(modelnet_members()))
    dest = tmp_path / "ModelNet10"
    real_extract = zipfile.ZipFile.extract
    calls = []

    def failing_extract(self, member, path=None, pwd=None):
        calls.append(member)
        if len(calls) == 3:
            raise OSError("No space left on device (simulated)")
        return real_extract(self, member, path, pwd)

    monkeypatch.setattr(zipfile.ZipFile, "extract", failing_extract)
    with pytest.raises(OSError, match="simulated"):
        extract_zip(archive, dest, progress=False)
    assert not dest.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-")] == []

    # a run killed mid-extraction leaves its temporary directory behind
    leftover = tmp_path / ".tmp-ModelNet10-999999"
    (leftover / "ModelNet10").mkdir(parents=True)
    (leftover / "ModelNet10" / "half.off").write_bytes(b"OFF\n")
    monkeypatch.setattr(zipfile.ZipFile, "extract", real_extract)
    extract_zip(archive, dest, progress=True)
    assert (dest / ".complete").exists()
    assert (dest / "ModelNet10" / "chair" / "test" / "chair_0003.off").exists()
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".tmp-")] == []


# ---------------------------------------------------------------------------
# fetch_modelnet10

def test_fetch_modelnet10_end_to_end(server, tmp_path):
    members = modelnet_members()
    members["__MACOSX/ModelNet10/chair/train/._chair_0001.off"] = b"\x00junk"
    server.payload = make_zip(members)
    root = tmp_path / "data"
    classes = fetch_modelnet10(root, url=server.url(), progress=False, expected_sha256=None)
    assert classes == root / "ModelNet10" / "ModelNet10"
    assert (classes / "chair" / "train" / "chair_0001.off").is_file()
    assert (classes / "bed" / "test").is_dir()
    assert (root / "ModelNet10.zip.sha256").exists()
    assert (root / "ModelNet10" / ".complete").read_text().split()[0] == sha(server.payload)

    again = fetch_modelnet10(root, url=server.url(), progress=False, expected_sha256=None)
    assert again == classes and len(server.requests) == 1

    (root / "ModelNet10.zip").unlink()            # archive removed to save space
    assert fetch_modelnet10(root, url=server.url(), progress=False, expected_sha256=None) == classes
    assert len(server.requests) == 1


def test_fetch_modelnet10_flat_archive_with_pinned_hash(server, tmp_path):
    server.payload = make_zip(modelnet_members(prefix=""))
    classes = fetch_modelnet10(tmp_path, url=server.url(), progress=False, expected_sha256=sha(server.payload))
    assert classes == tmp_path / "ModelNet10"
    assert (classes / "chair" / "train").is_dir()


@pytest.mark.slow
def test_fetch_modelnet10_refuses_a_file_that_is_not_the_pinned_one(server, tmp_path):
    with pytest.raises(DownloadError, match="does not match"):
        fetch_modelnet10(tmp_path, url=server.url(), progress=False, expected_sha256="0" * 64)
    assert not (tmp_path / "ModelNet10.zip").exists() and not (tmp_path / "ModelNet10").exists()


def test_fetch_modelnet10_without_class_folders(server, tmp_path):
    server.payload = make_zip({"junk/readme.txt": b"nothing here"})
    with pytest.raises(DownloadError, match="no class folders"):
        fetch_modelnet10(tmp_path, url=server.url(), progress=False, expected_sha256=None)


def test_find_class_root(tmp_path):
    assert find_class_root(tmp_path / "missing") is None
    assert find_class_root(tmp_path) is None
    (tmp_path / "__MACOSX" / "chair" / "train").mkdir(parents=True)          # junk: ignored
    (tmp_path / ".tmp-ModelNet10-123" / "chair" / "train").mkdir(parents=True)  # unfinished: ignored
    assert find_class_root(tmp_path) is None
    (tmp_path / "ModelNet10" / "ModelNet10" / "sofa" / "test").mkdir(parents=True)
    (tmp_path / "ModelNet10" / "ModelNet10" / "README.txt").write_text("x")
    assert find_class_root(tmp_path) == tmp_path / "ModelNet10" / "ModelNet10"
    assert find_class_root(tmp_path / "ModelNet10" / "ModelNet10") == tmp_path / "ModelNet10" / "ModelNet10"
