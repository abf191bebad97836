import numpy as np
import pytest

from hbeo.errors import DataError
from hbeo.storage import read_npz, write_npz


def test_round_trip_and_every_failure_names_the_file(tmp_path):
    p = write_npz(tmp_path / "a.npz", {"format_version": 2, "x": [1, 2]}, compressed=True, w=np.arange(3))
    meta, arrays = read_npz(p, ("w",), "thing", 2)
    assert meta["x"] == [1, 2] and np.array_equal(arrays["w"], np.arange(3))
    assert [f.name for f in tmp_path.iterdir()] == ["a.npz"]          # no temporary file left behind
    with pytest.raises(DataError, match=r"a\.npz: thing format 2, this hbeo reads 3; rebuild it"):
        read_npz(p, ("w",), "thing", 3, "; rebuild it")
    with pytest.raises(DataError, match=r"a\.npz: not a readable thing file \(KeyError"):
        read_npz(p, ("w", "v"), "thing", 2)
    with pytest.raises(DataError, match=r"b\.npz: no such thing file"):
        read_npz(tmp_path / "b.npz", ("w",), "thing", 2)
    (tmp_path / "c.npz").write_bytes(b"junk")
    with pytest.raises(DataError, match=r"c\.npz: not a readable thing file"):
        read_npz(tmp_path / "c.npz", ("w",), "thing", 2)
