import shutil
import warnings

import numpy as np
import pytest

from hbeo.data import datasets
from hbeo.conventions import CLASSES
from hbeo.errors import MissingDataError

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
