import hashlib
import json
import os
import re
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import torch

from hbeo import cli
from hbeo import config
from hbeo import conventions as C
from hbeo.data import datasets
from hbeo.data.datasets import ObjectRecord
from hbeo.errors import DataError
from hbeo.data.gridset import build_gridset, record_grid
from hbeo.render.torch_datasets import DepthShards, ShardSampler, StreamingDepth, load_shard, split_by_object
from hbeo.render.renderset import Manifest, render_set
from hbeo.render.views import RenderSettings
from hbeo.subspace.basis import ObjectSubspace
from hbeo.rotations import axis_angle_to_matrix

CLASSES = ("bed", "chair", "table")
SMALL = RenderSettings(image_size=(32, 24), views_per_object=2)
REPO = Path(__file__).resolve().parent.parent


# Not the session's ci run (conftest): these tests count images, shards and views of a set small
# enough to spell out (6 objects x 2 views of 32x24 in shards of 4 objects, a 1-component subspace)
# and render it again several ways; the ci set (60 objects x 8 views of 80x60) would take ~10x longer.

@pytest.fixture(scope="module")
def ds():
    return datasets.ProceduralDataset(n_train=2, n_test=1, seed=3, classes=CLASSES)


@pytest.fixture(scope="module")
def subspace(ds, tmp_path_factory):
    gs = build_gridset(ds, ds.records("train"), "train", cache=tmp_path_factory.mktemp("cache"), progress=False)
    return ObjectSubspace(n_components=1).fit(gs.grids, gs.labels, gs.classes, progress=False)


@pytest.fixture(scope="module")
def rendered(ds, subspace, tmp_path_factory):
    out = tmp_path_factory.mktemp("set")
    m = render_set(ds, ds.records("train"), "train", out, SMALL, subspace=subspace,
                   objects_per_shard=4, progress=False)
    return m


def _shards(m: Manifest) -> list[dict]:
    return [load_shard(p) for p in m.shard_paths()]


def _same_sets(a: Manifest, b: Manifest):
    assert [s["sha256"] for s in a.shards] == [s["sha256"] for s in b.shards]   # byte-identical files
    for x, y in zip(_shards(a), _shards(b)):
        assert x.keys() == y.keys()
        for k in x:
            assert np.array_equal(x[k], y[k]), k


def test_set_has_the_right_arrays_labels_and_manifest(rendered, ds, subspace):
    m = Manifest.load(rendered.root)
    recs = ds.records("train")
    assert m.n_images == len(recs) * 2 == 12 and len(m.shards) == 2
    assert m.counts == {"bed": 4, "chair": 4, "table": 4}
    assert m.classes == CLASSES and m.split == "train" and m.coeffs_dim == subspace.dim_
    assert m.data["settings"]["image_size"] == [32, 24] and m.data["dataset_fingerprint"] == ds.fingerprint()
    assert not (m.root / "manifest.partial.json").exists()
    m.verify()
    parts = _shards(m)
    assert [len(p["depth"]) for p in parts] == [8, 4]
    a = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k != "intrinsics"}
    assert a["depth"].dtype == np.float16 and a["depth"].shape == (12, 24, 32)
    assert a["mask"].dtype == bool and np.array_equal(a["mask"], a["depth"] > 0)
    assert (a["depth"] >= 0).all() and a["mask"].reshape(12, -1).any(axis=1).all()   # every view sees it
    assert a["depth"][a["mask"]].min() > 0.5 and a["depth"].max() < 3.0          # metres, ~1.4-2 m away
    assert list(a["label"]) == [CLASSES.index(r.cls) for r in recs for _ in range(2)]
    assert list(a["object_index"]) == [i for i in range(6) for _ in range(2)]
    assert list(a["object_id"]) == [r.id for r in recs for _ in range(2)]
    assert list(a["view"]) == [0, 1] * 6
    R = a["rotation"].astype(np.float64)
    assert a["rotation"].dtype == np.float32 and a["axis_angle"].dtype == np.float32
    assert np.allclose(np.einsum("nji,njk->nik", R, R), np.eye(3), atol=1e-5)
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-5)
    assert np.allclose(axis_angle_to_matrix(a["axis_angle"]), R, atol=1e-5)
    assert a["translation"].shape == (12, 3) and (a["translation"][:, 2] >= 1.4).all()
    assert np.allclose(parts[0]["intrinsics"], C.Intrinsics.kinect(32, 24).as_tuple())
    assert len({a["rotation"][i].tobytes() for i in range(12)}) == 12   # views differ


def test_coefficients_are_the_projection_of_the_complete_grid(rendered, ds, subspace):
    parts = _shards(rendered)
    coeffs = np.concatenate([p["coeffs"] for p in parts])
    assert coeffs.dtype == np.float32 and coeffs.shape == (12, subspace.dim_)
    for i, r in enumerate(ds.records("train")):
        want = subspace.project(record_grid(r)[None])[0]
        assert np.allclose(coeffs[2 * i], want, rtol=1e-5, atol=1e-5)
        assert np.array_equal(coeffs[2 * i], coeffs[2 * i + 1])


@pytest.mark.slow
def test_identical_bytes_for_any_worker_count_and_rerun_is_a_no_op(ds, tmp_path):
    recs = ds.records("train")
    one = render_set(ds, recs, "train", tmp_path / "w1", SMALL, workers=1, objects_per_shard=2, progress=False)
    two = render_set(ds, recs, "train", tmp_path / "w2", SMALL, workers=2, objects_per_shard=2, progress=False)
    assert one.rendered == two.rendered == 12 and one.images_per_s > 0
    _same_sets(one, two)
    again = render_set(ds, recs, "train", tmp_path / "w1", SMALL, workers=1, objects_per_shard=2, progress=False)
    assert again.rendered == 0 and again.images_per_s is None
    # a shard deleted after the fact is rendered again, identically
    (tmp_path / "w2" / "shard_00001.npz").unlink()
    with pytest.warns(UserWarning, match=r"shard_00001\.npz: shard listed in the manifest is missing"):
        fixed = render_set(ds, recs, "train", tmp_path / "w2", SMALL, workers=1, objects_per_shard=2,
                           progress=False)
    assert fixed.rendered == 4
    _same_sets(one, fixed)


@pytest.mark.slow
def test_resume_after_kill_gives_the_uninterrupted_result(tmp_path, capsys):
    out = tmp_path / "run"
    args = [sys.executable, "-m", "hbeo", "render", "--dataset", "procedural", "--profile", "ci",
            "--out", str(out), "--views", "10", "--noise", "--objects-per-shard", "2", "--quiet"]
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    sdir = out / "render_train"
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env)
    try:
        deadline = time.time() + 60
        while not (sdir / "shard_00000.npz.sha256").exists():   # the first shard is finished
            assert proc.poll() is None, proc.communicate()
            assert time.time() < deadline, "no shard appeared within 60 s"
            time.sleep(0.005)
    finally:
        proc.kill()
        proc.communicate()
    assert not (sdir / "manifest.json").exists(), "render finished before it could be killed"
    complete, kept = {}, set()
    for p in sorted(sdir.iterdir()):
        if re.fullmatch(r"shard_\d{5}\.npz", p.name):
            d = load_shard(p)                                 # whatever has a shard name is complete
            assert len(d["depth"]) == 20 and d["depth"].shape[1:] == (60, 80)
            complete[p.name] = p.stat().st_mtime_ns
        elif p.name.endswith(".npz.sha256"):              # sidecars are written after their shard
            shard = p.with_name(p.name[:-len(".sha256")])
            assert p.read_text().split()[0] == hashlib.sha256(shard.read_bytes()).hexdigest()
            kept.add(shard.name)
        else:
            assert p.name == "manifest.partial.json" or (p.name.startswith(".") and p.name.endswith(".tmp")), p
    assert complete
    assert cli.main(args[3:]) == 0                      # rerun (in-process: saves a start-up)
    printed = capsys.readouterr().out
    assert "images/s" in printed and "train: 600 images of 60 objects" in printed
    resumed = Manifest.load(sdir)
    assert resumed.rendered == 0 and len(resumed.shards) == 30
    assert not [p for p in sdir.iterdir() if p.name.endswith(".tmp")]
    assert kept
    for name in kept:                            # finished shards were kept, not rendered again
        assert (sdir / name).stat().st_mtime_ns == complete[name]
    ds = datasets.get_dataset("procedural", profile="ci")
    settings = RenderSettings.from_profile("ci", views_per_object=10, noise=True)
    clean = render_set(ds, datasets.select(ds, "train", "ci"), "train", tmp_path / "clean", settings,
                       workers=2, objects_per_shard=2, progress=False)
    _same_sets(clean, resumed)


def test_depth_shards_split_by_object_and_sampler(rendered, subspace):
    data = DepthShards(rendered.root)
    assert len(data) == 12
    item = data[5]
    assert set(item) == {"depth", "label", "rotation", "axis_angle", "translation", "coeffs", "object_index"}
    assert item["depth"].shape == (1, 24, 32) and item["depth"].dtype == torch.float32
    assert item["rotation"].shape == (3, 3) and item["axis_angle"].shape == (3,)
    assert item["translation"].shape == (3,) and item["coeffs"].shape == (subspace.dim_,)
    assert int(item["object_index"]) == 2 and int(item["label"]) == data.labels[5]
    assert torch.equal(data[-1]["depth"], data[11]["depth"])
    with pytest.raises(IndexError):
        data[12]
    batch = next(iter(torch.utils.data.DataLoader(data, batch_size=4)))
    assert batch["depth"].shape == (4, 1, 24, 32) and batch["label"].dtype == torch.long
    for seed in range(5):
        tr, va = split_by_object(rendered, val_fraction=0.34, seed=seed)
        assert len(tr) + len(va) == 12 and not set(tr) & set(va) and len(va) == 6   # 1 of 2 per class
        assert not set(data.objects(tr)) & set(data.objects(va))
        assert sorted(data.labels[va]) == [0, 0, 1, 1, 2, 2]
    assert len(split_by_object(data, 0.0)[1]) == 0
    sampler = ShardSampler(data, tr, seed=1)
    order = list(sampler)
    assert sorted(order) == list(range(len(tr)))
    shards = data.shard_of(tr[order])
    assert (np.diff(shards) != 0).sum() <= 1                 # each shard visited once


def test_streaming_yields_the_rendered_images(rendered, ds, subspace):
    stream = StreamingDepth(ds, ds.records("train"), "train", SMALL, subspace=subspace)
    loader = torch.utils.data.DataLoader(stream, batch_size=None, num_workers=2)

    def key(it):
        return (int(it["object_index"]), int(it["label"]), it["depth"].numpy().tobytes(),
                it["rotation"].numpy().tobytes(), it["translation"].numpy().tobytes(),
                it["coeffs"].numpy().tobytes())

    streamed = [key(it) for it in loader]
    stored = [key(it) for it in DepthShards(rendered.root)]
    assert len(streamed) == 12 and Counter(streamed) == Counter(stored)
    assert [key(it) for it in loader] == streamed              # deterministic per epoch
    stream.set_epoch(1)
    later = {k[3] for k in (key(it) for it in stream)}
    assert not later & {k[3] for k in stored}                 # new viewpoints in a new epoch


def _broken_mesh():
    raise OSError("cannot read broken.off")


@pytest.mark.slow
def test_bad_inputs(ds, tmp_path):
    with pytest.raises(ValueError, match="no records"):
        render_set(ds, [], "train", tmp_path / "a", SMALL)
    with pytest.raises(ValueError, match="no records"):
        StreamingDepth(ds, [], "train", SMALL)
    with pytest.raises(ValueError, match="views_per_object"):
        RenderSettings(views_per_object=0)
    with pytest.raises(ValueError, match="sampler"):
        RenderSettings(sampler="cylinder")
    with pytest.raises(ValueError, match="image_size"):
        RenderSettings(image_size=(0, 24))
    with pytest.raises(ValueError, match="backend"):
        RenderSettings(backend="raytracer")
    with pytest.raises(ValueError, match="inside an object"):
        RenderSettings(distance=(0.5, 1.0))
    with pytest.raises(ValueError, match="split"):
        render_set(ds, ds.records("test"), "train", tmp_path / "a", SMALL)
    recs = ds.records("test")
    render_set(ds, recs, "test", tmp_path / "b", SMALL, progress=False)
    with pytest.raises(DataError, match=r"different settings \(settings.seed: 0 there, 1 now"):
        render_set(ds, recs, "test", tmp_path / "b", RenderSettings(image_size=(32, 24), seed=1), progress=False)
    with pytest.raises(DataError, match="different settings"):
        render_set(ds, recs[:2], "test", tmp_path / "b", SMALL, progress=False)
    # a bad object is left out and named (tests/test_safe_batches.py has the details); none good: DataError
    broken = ObjectRecord("chair", "test", "broken_0001", _mesh=_broken_mesh)
    m = render_set(ds, [recs[0], broken, recs[1]], "test", tmp_path / "d", SMALL, workers=2,
                   objects_per_shard=1, progress=False)
    assert [f["object"] for f in m.failures] == ["test/chair/broken_0001"] and len(m.shards) == 2
    assert m.n_images == len(DepthShards(m)) == 2 * SMALL.views_per_object
    with pytest.raises(DataError, match=r"none of the 1 test objects could be rendered; first: test/chair/broken_0001"):
        render_set(ds, [broken], "test", tmp_path / "c", SMALL, progress=False)
    with pytest.raises(DataError, match="no rendered set manifest"):
        DepthShards(tmp_path / "c")
    with pytest.raises(SystemExit) as exit_:                 # refused while the command line is read
        cli.main(["render", "--profile", "ci", "--out", str(tmp_path / "e"), "--views", "0"])
    assert exit_.value.code == 2 and not (tmp_path / "e").exists()


def test_settings_from_profile_round_trip():
    s = RenderSettings.from_profile("cpu", sampler="upright", seed=None)
    assert s.image_size == (80, 60) and s.views_per_object == 20 and s.sampler == "upright" and s.seed == 0
    assert RenderSettings.from_dict(json.loads(json.dumps(s.to_dict()))) == s
    assert s.intrinsics == C.Intrinsics.kinect(80, 60)
    assert config.get_profile("ci").data.views_per_object == RenderSettings.from_profile("ci").views_per_object


def test_view_arrays_keep_views_that_show_nothing(rendered, monkeypatch):
    """A view showing nothing (degenerate grids seen edge-on do that) stays an empty image with its
    pose when views are re-centred, instead of stopping the training set."""
    from hbeo.model import trainingdata
    real = trainingdata.load_shard

    def one_empty(path):
        sh = real(path)
        sh["depth"][0] = 0
        return sh

    monkeypatch.setattr(trainingdata, "load_shard", one_empty)
    plain = trainingdata.ViewArrays(rendered, trainingdata.ViewOptions(), progress=False)
    turned = trainingdata.ViewArrays(rendered, trainingdata.ViewOptions(recenter=True, ref_distance=1.7), progress=False)
    assert not plain.depth[0].any() and not turned.depth[0].any()
    assert np.array_equal(turned.rotation[0], plain.rotation[0])
    assert turned.depth[1].any() and not np.array_equal(turned.rotation[1], plain.rotation[1])
