import hashlib
import logging
import os
import re
import stat

import numpy as np
import pytest

from hbeo.errors import DataError
from hbeo.storage import (atomic_file, atomic_text, pack_bits, read_json, read_sidecar, sidecar_path, unpack_bits,
                          verify_sidecar, write_npz, write_sidecar)


def test_pack_bits_round_trip_grids_and_masks():
    rng = np.random.default_rng(0)
    grids = rng.random((3, 30, 30, 30)) < 0.3
    packed = pack_bits(grids)
    assert packed.shape == (3, 3375) and packed.dtype == np.uint8
    assert np.array_equal(unpack_bits(packed), grids)                  # default: 30^3 grids
    masks = rng.random((2, 7, 5)) < 0.5                                 # 35 bits: a padded last byte
    assert np.array_equal(unpack_bits(pack_bits(masks), (7, 5)), masks)
    assert pack_bits(np.zeros((0, 30, 30, 30), bool)).shape == (0, 3375)


def test_pack_bits_bad_shapes():
    with pytest.raises(ValueError, match=r"pack_bits: .*got shape \(8,\)"):
        pack_bits(np.zeros(8, bool))
    with pytest.raises(ValueError, match=r"unpack_bits: .*\(N, 5\).*\(7, 5\).*\(2, 4\)"):
        unpack_bits(np.zeros((2, 4), np.uint8), (7, 5))


def test_sidecar_write_read_verify(tmp_path, caplog):
    f = tmp_path / "shard.npz"
    f.write_bytes(b"hello")
    want = hashlib.sha256(b"hello").hexdigest()
    assert read_sidecar(f) is None and verify_sidecar(f) is None        # no record yet
    assert write_sidecar(f) == want
    assert sidecar_path(f).read_text() == f"{want}  shard.npz\n"        # sha256sum format
    assert read_sidecar(f) == want and verify_sidecar(f) == want
    f.write_bytes(b"hellO")                                             # damaged file
    assert verify_sidecar(f) is None
    sidecar_path(f).write_text("not a digest\n")
    with caplog.at_level(logging.WARNING, logger="hbeo.storage"):
        assert read_sidecar(f) is None
    assert "unreadable checksum record" in caplog.text


@pytest.mark.parametrize("umask, want", [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_atomic_files_get_the_users_umask(tmp_path, umask, want):
    """Issue 14, case 10: a file written through a temporary name (mkstemp: 0600) ends with the mode
    a plain open() would give it, 0666 less the umask; also when it replaces an existing file."""
    old = os.umask(umask)
    try:
        with atomic_file(tmp_path / "a.bin") as f:
            f.write(b"x")
        atomic_text(tmp_path / "b.txt", "x")
        (tmp_path / "c.txt").write_text("old")
        os.chmod(tmp_path / "c.txt", 0o600)
        atomic_text(tmp_path / "c.txt", "new")
        write_npz(tmp_path / "d.npz", {"format_version": 1}, a=np.zeros(2))
    finally:
        os.umask(old)
    for name in ("a.bin", "b.txt", "c.txt", "d.npz"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == want, name
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.bin", "b.txt", "c.txt", "d.npz"]   # no temporaries


def test_append_csv_adds_rows_and_new_columns_through_a_temporary_file(tmp_path):
    import pandas as pd
    from hbeo.storage import append_csv
    p = tmp_path / "log.csv"
    append_csv(p, [{"a": 1, "b": 0.5}])
    append_csv(p, [{"a": 2, "b": 0.25, "c": "x"}, {"a": 3, "b": 0.125, "c": "y"}])
    t = pd.read_csv(p)
    assert list(t.columns) == ["a", "b", "c"] and list(t.a) == [1, 2, 3] and list(t.b) == [0.5, 0.25, 0.125]
    assert pd.isna(t.c[0]) and list(t.c[1:]) == ["x", "y"]
    assert sorted(x.name for x in tmp_path.iterdir()) == ["log.csv"]           # no temporary file left


def test_append_csv_leaves_the_older_rows_text_as_it_was(tmp_path):
    """validation.csv lost the last digit of 20.958594736930078 (pandas' default float parser) and wrote a
    count as 3.0 once a later row left it empty, each time a row was appended."""
    from hbeo.storage import append_csv
    p = tmp_path / "log.csv"
    append_csv(p, [{"a": 3, "b": 20.958594736930078, "c": '{"x": 1, "y": "z"}'}])
    first = p.read_text().splitlines()
    append_csv(p, [{"b": 0.1, "c": "", "d": 2}])
    append_csv(p, [{"a": 4, "b": 1e-300}])
    lines = p.read_text().splitlines()
    assert lines[0] == "a,b,c,d" and lines[1] == first[1] + ","
    assert lines[1].startswith("3,20.958594736930078,")
    assert lines[2] == ",0.1,,2" and lines[3] == "4,1e-300,,"


class _Marker:
    """Unpickling this writes a file: the proof that a reader ran code from the file."""

    def __init__(self, path):
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def test_read_npz_refuses_a_pickled_array_without_running_it(tmp_path):
    """An .npz whose array is a pickled object (a crafted subspace, BEO model or grid set file) is refused by the
    one reader of the project's .npz files, and nothing in it runs."""
    from hbeo.errors import DataError
    from hbeo.storage import read_npz
    marker = tmp_path / "ran"
    evil = tmp_path / "evil.npz"
    np.savez(evil, meta=np.array('{"format_version": 1}'), basis=np.array([_Marker(str(marker))], dtype=object))
    with pytest.raises(DataError, match="evil.npz"):
        read_npz(evil, ["basis"], "subspace", 1)
    assert not marker.exists()


def test_a_link_is_written_through_and_a_pipe_in_place(tmp_path):
    """--out through a link updates the file it names; --out naming a device or pipe (/dev/null) is written
    to, never replaced by a regular file (as root, a rename would have replaced the device itself)."""
    import threading
    target = tmp_path / "real.json"
    target.write_text("old")
    (tmp_path / "link.json").symlink_to(target)
    atomic_text(tmp_path / "link.json", "new")
    assert (tmp_path / "link.json").is_symlink() and target.read_text() == "new"
    if not hasattr(os, "mkfifo"):
        return
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_text()))
    reader.start()
    atomic_text(fifo, "through the pipe")
    reader.join(timeout=10)
    assert got == ["through the pipe"] and stat.S_ISFIFO(fifo.stat().st_mode)
    assert [p.name for p in tmp_path.iterdir() if p.name.endswith(".tmp")] == []


@pytest.mark.parametrize("text, problem", [
    ('{"a": [1, 2', r"not a readable metrics file: not valid JSON \(JSONDecodeError: Expecting"),
    ("", r"not valid JSON \(empty\)"),
    (b'{"a": "\xff"}', r"not valid JSON \(UnicodeDecodeError"),
    ("[1, 2]", r"not a metrics file: it holds a JSON list, not a JSON object"),
    ('"text"', r"it holds text \('text'\), not a JSON object"),
])
def test_read_json_names_the_file_and_the_problem(tmp_path, text, problem):
    path = tmp_path / "eval_x.json"
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(DataError, match=f"^{re.escape(str(path))}: .*{problem}") as err:
        read_json(path, "metrics", dict)
    assert err.value.path == str(path)
    (tmp_path / "ok.json").write_text('{"a": [1, null]}')
    assert read_json(tmp_path / "ok.json", kind=dict) == {"a": [1, None]}
