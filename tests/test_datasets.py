import shutil
import warnings

import numpy as np
import pytest

from hbeo.data import datasets
from hbeo.data.gridset import GridSet
from hbeo.conventions import CLASSES
from hbeo.errors import DataError, MissingDataError
from hbeo.storage import pack_bits, write_npz

OFFICIAL = {"bathtub": (106, 50), "bed": (515, 100), "chair": (889, 100), "desk": (200, 86),
            "dresser": (200, 86), "monitor": (465, 100), "night_stand": (200, 86),
            "sofa": (680, 100), "table": (392, 100), "toilet": (344, 100)}


def test_procedural_source_sizes_ids_and_meshes():
    ds = datasets.get_dataset("procedural", n_train=2, n_test=1, seed=3)
    assert ds.classes == CLASSES and len(ds) == 30
    assert ds.summary().loc["total", "total"] == 30
    recs = ds.records("test")
    assert [r.cls for r in recs] == list(CLASSES)
    r = recs[0]
    assert r.split == "test" and r.id == "bathtub_test_0000" and r.has_mesh and not r.has_grid
    m = r.mesh()
    assert len(m.faces) > 0 and r.grid() is None
    again = datasets.get_dataset("procedural", n_train=2, n_test=1, seed=3).records("test")[0].mesh()
    assert np.array_equal(m.vertices, again.vertices)                      # deterministic
    other = datasets.get_dataset("procedural", n_train=2, n_test=1, seed=4)
    assert other.fingerprint() != ds.fingerprint()


def test_procedural_sized_by_profile():
    ds = datasets.get_dataset("procedural", profile="ci")
    s = ds.summary()
    assert (s.loc["chair", "train"], s.loc["chair", "test"]) == (6, 3)
    with pytest.raises(ValueError, match="n_train"):
        datasets.ProceduralDataset(n_train=-1)


def test_vox30_matches_official_split_and_skips_empty_grids(vox30_file):
    with pytest.warns(UserWarning, match="skipped 8 empty grids"):
        ds = datasets.get_dataset("modelnet10-vox30")
    s = ds.summary()
    for cls, (n_train, n_test) in OFFICIAL.items():
        assert (s.loc[cls, "train"], s.loc[cls, "test"]) == (n_train, n_test)
    assert s.loc["total", "total"] == 4899 and s.loc["total", "skipped"] == 8
    assert len(ds) == 4891
    assert ("test", "desk", "desk_0255") in ds.skipped
    assert all(r.grid().any() for r in ds.records("train", classes=["bathtub"]))
    r = ds.records("train", classes=["chair"], per_class=1)[0]
    assert r.id == "chair_0001" and r.grid().shape == (30, 30, 30) and r.mesh() is None


def _tiny_vox30(path, fill):
    X = np.zeros((2, 30, 30, 30), np.uint8)
    X[:, 10:20, 10:20, 10:fill] = 1
    np.savez(path, X_train=X, y_train=np.array([0, 1]), names_train=np.array(["a_1", "b_1"]),
             X_test=X[:1], y_test=np.array([1]), names_test=np.array(["b_2"]), classes=np.array(["a", "b"]))
    return path


def test_vox30_fingerprint_follows_content_not_path_or_time(tmp_path):
    one = _tiny_vox30(tmp_path / "one.npz", 20)
    (tmp_path / "copy").mkdir()
    copy = shutil.copy(one, tmp_path / "copy" / "one.npz")
    fp = datasets.Vox30Dataset(one).fingerprint()
    assert datasets.Vox30Dataset(copy).fingerprint() == fp        # other folder, other mtime
    assert datasets.Vox30Dataset(_tiny_vox30(tmp_path / "two.npz", 21)).fingerprint() != fp


def test_vox30_missing_or_broken_file(tmp_path):
    with pytest.raises(MissingDataError, match="HBEO_VOX30"):
        datasets.Vox30Dataset(tmp_path / "nope.npz")
    bad = tmp_path / "bad.npz"
    np.savez(bad, X_train=np.zeros((2, 30, 30, 30)))
    with pytest.raises(ValueError, match=r"bad\.npz: missing arrays"):
        datasets.Vox30Dataset(bad)
    bad.write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"bad\.npz: unreadable grid archive"):
        datasets.Vox30Dataset(bad)


def test_folder_source_reads_modelnet_layout(sample_dir, tmp_path):
    ds = datasets.get_dataset(str(sample_dir))
    assert ds.classes == ("bathtub",) and len(ds) == 5
    r = ds.records("train")[0]
    assert r.id == "bathtub_0001" and r.path.name == "bathtub_0001.off"
    assert r.mesh().faces.shape == (3546, 3)
    # a user's own folder with mixed formats and a class ModelNet10 does not have
    import trimesh
    (tmp_path / "mug" / "test").mkdir(parents=True)
    trimesh.creation.cylinder(0.5, 1.0).export(tmp_path / "mug" / "test" / "m1.ply")
    (tmp_path / "mug" / "test" / "notes.txt").write_text("ignored")
    user = datasets.get_dataset(str(tmp_path))
    assert user.classes == ("mug",) and [r.id for r in user] == ["m1"]
    with pytest.raises(MissingDataError, match="ModelNet layout"):
        datasets.FolderDataset(tmp_path / "mug")


def test_modelnet10_source_finds_extracted_archive(sample_dir, tmp_path):
    root = tmp_path / "data"
    shutil.copytree(sample_dir, root / "ModelNet10" / "ModelNet10")
    ds = datasets.get_dataset("modelnet10", root=root)
    assert ds.name == "modelnet10" and ds.summary().loc["bathtub", "train"] == 5
    with pytest.raises(MissingDataError, match="--download"):
        datasets.get_dataset("modelnet10", root=tmp_path / "empty")


def test_unknown_dataset_and_split():
    with pytest.raises(ValueError, match="unknown dataset"):
        datasets.get_dataset("shapenet")
    ds = datasets.get_dataset("procedural", n_train=1, n_test=0)
    with pytest.raises(ValueError, match="unknown split"):
        ds.records("val")
    with pytest.raises(ValueError, match="no class"):
        ds.records("train", classes=["lamp"])


def test_select_takes_a_per_class_prefix(vox30_file):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = datasets.get_dataset("modelnet10-vox30")
    recs = datasets.select(ds, "train", "ci")
    assert len(recs) == 60 and recs[0].id == "bathtub_0001"
    assert len(datasets.select(ds, "test", "full")) == 907


def _vox30_with(path, **change):
    arrays = dict(X_train=np.zeros((2, 30, 30, 30), np.uint8), y_train=np.array([0, 1]),
                  names_train=np.array(["a_1", "b_1"]), X_test=np.zeros((1, 30, 30, 30), np.uint8),
                  y_test=np.array([1]), names_test=np.array(["b_2"]), classes=np.array(["a", "b"]))
    arrays["X_train"][:, 10:20, 10:20, 10:20] = 1
    arrays["X_test"][:, 5:9, 5:9, 5:9] = 1
    arrays.update(change)
    np.savez(path, **arrays)
    return path


def _float_grids(value):
    X = np.zeros((2, 30, 30, 30), np.float32)
    X[:, 10:20, 10:20, 10:20] = 1
    X[0, 0, 0, 0] = value
    return X


@pytest.mark.parametrize("change, problem", [
    # issue 14, case 11: floats with NaN used to load as occupied voxels
    ({"X_train": _float_grids(np.nan)}, r"X_train holds NaN or infinite values"),
    ({"X_train": np.full((2, 30, 30, 30), np.nan, np.float32)}, r"X_train holds NaN or infinite values"),
    ({"X_train": _float_grids(0.5)}, r"X_train holds float32 values other than 0 and 1 \(e\.g\. 0\.5\)"),
    ({"X_train": _float_grids(np.inf)}, r"X_train holds NaN or infinite values"),
    ({"X_train": np.full((2, 30, 30, 30), 2, np.int16)}, r"X_train holds int16 values other than 0 and 1 \(e\.g\. 2\)"),
    ({"X_train": np.zeros((2, 30, 30, 30), complex)}, r"X_train has dtype complex128; expected bool, 0/1 integers"),
    ({"X_train": np.full((2, 30, 30, 30), "x")}, r"X_train has dtype <U1"),
    ({"X_train": np.zeros((2, 32, 32, 32), bool)}, r"X_train has shape \(2, 32, 32, 32\); expected \(N, 30, 30, 30\)"),
    ({"y_train": np.array([0.0, np.nan])}, r"y_train must hold integer labels, got float64"),
    ({"y_train": np.array([0, 2])}, r"y_train has labels outside 0\.\.1"),
    ({"y_train": np.array([[0, 1]])}, r"X_train has shape .* matching y_train \(1, 2\)"),
    ({"names_test": np.array(["b_2", "c_2"])}, r"X_test has shape .* matching y_test \(1,\) and names_test \(2,\)"),
    ({"classes": np.array([1.5, 2.5])}, r"classes must hold class names"),
    ({"classes": np.array(["a", "a"])}, r"classes must hold distinct"),
])
def test_vox30_refuses_what_is_not_a_grid_file(tmp_path, change, problem):
    bad = _vox30_with(tmp_path / "bad.npz", **change)
    with pytest.raises(DataError, match=rf"^{tmp_path / 'bad.npz'}: {problem}") as err:
        datasets.Vox30Dataset(bad)
    assert "\n" not in str(err.value)


def test_vox30_accepts_bool_integer_and_exact_float_grids(tmp_path):
    for i, dtype in enumerate((bool, np.uint8, np.int64, np.float16, np.float64)):
        X = _float_grids(1.0).astype(dtype)
        ds = datasets.Vox30Dataset(_vox30_with(tmp_path / f"ok{i}.npz", X_train=X))
        grid = ds.records("train")[0].grid()
        assert grid.dtype == bool and grid.sum() == 1001, dtype


# ---------------------------------------------------------------- grid set files (GridSet.load)

def _gridset_file(path, meta_change=None, **arrays):
    """A grid set file as GridSet.save writes it, with some meta entries or arrays replaced."""
    grids = np.zeros((2, 30, 30, 30), bool)
    grids[:, 5:9, 5:9, 5:9] = True
    meta = {"format_version": 1, "split": "train", "classes": ["a", "b"], "resolution": 30, **(meta_change or {})}
    a = {"packed": pack_bits(grids), "labels": np.array([0, 1]), "ids": np.array(["a_1", "b_1"]), **arrays}
    write_npz(path, {k: v for k, v in meta.items() if v is not None}, **a)
    return path


@pytest.mark.parametrize("meta_change, arrays, problem", [
    # issue 14, case 11: labels and meta were never checked (KeyError, tracebacks, silent nonsense)
    ({}, {"labels": np.array([0, 7])}, r"labels outside 0\.\.1"),
    ({}, {"labels": np.array([0.0, np.nan])}, r"labels must be integers, got float64"),
    ({}, {"labels": np.array([0, 1, 1])}, r"2 grids, labels \(3,\), ids \(2,\)"),
    ({}, {"ids": np.array([["a", "b"]])}, r"2 grids, labels \(2,\), ids \(1, 2\)"),
    ({"resolution": None}, {}, r"meta lacks \"resolution\""),
    ({"resolution": 32}, {}, r"resolution 32; expected 30"),
    ({"resolution": "30"}, {}, r"\"resolution\" must be an integer"),
    ({"classes": "ab"}, {}, r"\"classes\" must be a list of distinct class names"),
    ({"classes": ["a", "a"]}, {}, r"\"classes\" must be a list of distinct class names"),
    ({"split": None}, {}, r"meta lacks \"split\""),
    ({}, {"packed": np.zeros((2, 9), np.uint8)}, r"corrupt grid set"),
])
def test_gridset_load_refuses_what_is_not_a_grid_set(tmp_path, meta_change, arrays, problem):
    bad = _gridset_file(tmp_path / "grids_train.npz", meta_change, **arrays)
    with pytest.raises(DataError, match=rf"^{tmp_path / 'grids_train.npz'}: .*({problem})") as err:
        GridSet.load(bad)
    assert "\n" not in str(err.value)


def test_gridset_load_reads_a_good_file(tmp_path):
    gs = GridSet.load(_gridset_file(tmp_path / "grids_train.npz"))
    assert gs.grids.shape == (2, 30, 30, 30) and gs.grids.dtype == bool and gs.classes == ("a", "b")
    assert list(gs.labels) == [0, 1] and gs.counts() == {"a": 1, "b": 1}


def test_vox30_with_an_empty_split(tmp_path):
    """An archive whose test split holds no grids (found by tests/test_fuzz.py: a reshape error)."""
    ds = datasets.Vox30Dataset(_vox30_with(tmp_path / "v.npz", X_test=np.zeros((0, 30, 30, 30), np.uint8),
                                           y_test=np.zeros(0, np.int64), names_test=np.array([], str)))
    assert len(ds.records("train")) == 2 and ds.records("test") == []


def test_vox30_record_pickles_its_own_grid_not_the_whole_archive(tmp_path):
    # each Dask render task pickles its records: a loader bound to the whole (N, 30, 30, 30) array sent
    # all N grids with every task (a 40-view ModelNet10 render held ~17 GB and was OOM-killed)
    import pickle
    X = np.zeros((200, 30, 30, 30), np.uint8)
    for i in range(200):
        X[i, 5:5 + i % 20 + 1, 10:20, 10:12] = 1
    path = _vox30_with(tmp_path / "many.npz", X_train=X, y_train=np.arange(200) % 2,
                       names_train=np.array([f"a_{i}" for i in range(200)]))
    ds = datasets.Vox30Dataset(path)
    recs = ds.records("train")
    assert len(recs) == 200
    for r in (recs[0], recs[137]):
        blob = pickle.dumps(r)
        assert len(blob) < 2 * 27_000 + 2_000, len(blob)            # one grid's bytes, not 200
        back = pickle.loads(blob)
        assert np.array_equal(back.grid(), r.grid()) and back.id == r.id and back.grid().shape == (30, 30, 30)
    a, b = recs[5].grid(), recs[6].grid()
    assert a.base is not None and a.base is b.base                     # in this process: views, no copies


BOX_OFF = "OFF\n4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 1 3\n3 0 2 3\n3 1 2 3\n"


@pytest.mark.parametrize("files, pair", [
    (["chair/train/a.off", "chair/train/a.obj", "chair/train/b.off"], ("chair/train/a.obj", "chair/train/a.off")),
    (["chair/train/0001.off", "table/train/0001.off"], ("chair/train/0001.off", "table/train/0001.off")),
    (["chair/train/0001.off", "chair/test/0001.off"], ("chair/train/0001.off", "chair/test/0001.off")),
])
def test_folder_source_refuses_ids_shared_by_two_files(files, pair, tmp_path):
    """An id is a file stem; two files with one would make lookups by id (GridSet.rows_of, the grouped
    validation split, mirror targets) return the other object's grid."""
    for f in files:
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_text(BOX_OFF)
    with pytest.raises(DataError, match="shared by several files") as err:
        datasets.get_dataset(str(tmp_path))
    msg = str(err.value)
    assert msg.startswith(str(tmp_path)) and all(p in msg for p in pair)
    assert "rename" in msg and "chair_0001" in msg
    (tmp_path / pair[1]).rename((tmp_path / pair[1]).with_name("chair_" + (tmp_path / pair[1]).name))
    ids = [r.id for r in datasets.get_dataset(str(tmp_path))]            # renamed: accepted
    assert len(ids) == len(set(ids)) == len(files)
