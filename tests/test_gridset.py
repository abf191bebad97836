import numpy as np
import pytest

from hbeo.data import datasets
from hbeo.data import gridset
from hbeo.errors import DataError
from hbeo.data.gridset import GridSet, build_gridset


@pytest.fixture
def small(sample_dir):
    ds = datasets.get_dataset(str(sample_dir))
    return ds, ds.records("train")


def test_build_matches_direct_voxelization_and_caches(small, tmp_path):
    ds, recs = small
    gs = build_gridset(ds, recs, "train", cache=tmp_path, chunk=2, progress=False)
    assert gs.grids.shape == (5, 30, 30, 30) and list(gs.ids) == [r.id for r in recs]
    assert gs.counts() == {"bathtub": 5}
    for r, g in zip(recs, gs.grids):
        assert np.array_equal(g, gridset.record_grid(r))
    (folder,) = tmp_path.iterdir()
    (merged,) = folder.iterdir()                                   # chunks merged into one file
    assert merged.name.startswith("chunk_") and merged.suffix == ".npz"
    again = build_gridset(ds, recs, "train", cache=tmp_path, chunk=2, progress=False)
    assert np.array_equal(again.grids, gs.grids)


def test_resume_after_interruption_and_worker_count_independence(small, tmp_path, monkeypatch):
    ds, recs = small
    calls = {"n": 0}
    real = gridset._chunk_job

    def flaky(args):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt   # killed while working on the second chunk
        return real(args)

    monkeypatch.setattr(gridset, "_chunk_job", flaky)
    with pytest.raises(KeyboardInterrupt):
        build_gridset(ds, recs, "train", cache=tmp_path / "a", chunk=2, progress=False)
    (folder,) = (tmp_path / "a").iterdir()
    (first,) = folder.iterdir()                  # only the finished chunk, no temp files
    assert first.name.startswith("chunk_") and not first.name.startswith(".")
    monkeypatch.setattr(gridset, "_chunk_job", real)
    done = []
    monkeypatch.setattr(gridset, "_chunk_job", lambda a: done.append(len(a[0])) or real(a))
    resumed = build_gridset(ds, recs, "train", cache=tmp_path / "a", chunk=2, progress=False)
    assert done == [2, 1]                          # the first chunk was not recomputed
    monkeypatch.setattr(gridset, "_chunk_job", real)
    parallel = build_gridset(ds, recs, "train", cache=tmp_path / "b", chunk=2, workers=2, progress=False)
    assert np.array_equal(resumed.grids, parallel.grids)


def test_vox30_records_give_their_stored_grids(vox30_file, tmp_path):
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = datasets.get_dataset("modelnet10-vox30")
    recs = datasets.select(ds, "test", "ci")
    gs = build_gridset(ds, recs, "test", cache=tmp_path, progress=False)
    assert np.array_equal(gs.grids[0], recs[0].grid())


def test_save_load_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(0)
    gs = GridSet(rng.random((3, 30, 30, 30)) > 0.5, np.array([0, 2, 1]), np.array(["a", "b", "c"]),
                 ("x", "y", "z"), "train", {"note": 1})
    back = GridSet.load(gs.save(tmp_path / "g.npz"))
    assert np.array_equal(back.grids, gs.grids) and back.classes == gs.classes
    assert list(back.ids) == ["a", "b", "c"] and back.meta["note"] == 1
    (tmp_path / "junk.npz").write_bytes(b"junk")
    with pytest.raises(DataError, match=r"junk\.npz: not a readable grid set"):
        GridSet.load(tmp_path / "junk.npz")
    with pytest.raises(DataError, match="no such grid set"):
        GridSet.load(tmp_path / "missing.npz")


def test_rows_of_and_grids_of_match_ids_as_strings_and_leave_missing_empty():
    g = np.zeros((3, 4, 4, 4), bool)
    g[0, 0, 0, 0] = g[1, 1, 1, 1] = g[2, 2, 2, 2] = True
    gs = GridSet(g, np.array([0, 1, 1]), np.array(["a", "7", "c"]), ("x", "y"), "train")
    np.testing.assert_array_equal(gs.rows_of(["c", 7, "zz", "a"]), [2, 1, -1, 0])
    out = gs.grids_of(["c", "zz", "7"])
    assert out.shape == (3, 4, 4, 4) and out.dtype == bool
    assert out[0, 2, 2, 2] and out[0].sum() == 1
    assert not out[1].any()
    assert out[2, 1, 1, 1] and out[2].sum() == 1
    assert gs.grids_of([]).shape == (0, 4, 4, 4)


def test_grid_sets_refuse_repeated_ids_when_built_or_loaded(small, tmp_path):
    """A repeated id would make rows_of / grids_of return another object's grid for it."""
    ds, recs = small
    twice = [recs[0], recs[1], recs[0]]
    with pytest.raises(DataError, match=r"appear more than once \(bathtub_0001\)") as err:
        build_gridset(ds, twice, "train", cache=tmp_path / "c", progress=False)
    assert err.value.path == ds.name
    g = np.zeros((3, 30, 30, 30), bool)
    with pytest.raises(DataError, match=r"appear more than once \(a\)"):
        GridSet(g, np.array([0, 1, 0]), np.array(["a", "b", "a"]), ("x", "y"), "train")
    gs = GridSet(g, np.array([0, 1, 0]), np.array(["a", "b", "c"]), ("x", "y"), "train")
    gs.ids = np.array(["a", "b", "a"])                                   # a file written before the check
    path = gs.save(tmp_path / "dup.npz")
    with pytest.raises(DataError, match=r"dup\.npz: 1 object id\(s\) appear more than once \(a\)"):
        GridSet.load(path)
