"""The VoxCNN baseline: network shapes, the partial training set, training on the ci profile
(beats chance and an empty completion on held-out test objects), exact resume, the model file."""
import numpy as np
import pandas as pd
import pytest
import torch

from hbeo import config
from hbeo.baselines import voxcnn as V
from hbeo.errors import DataError
from hbeo.model.loop import TrainConfig, train
from hbeo.rundir import CHECKPOINT, RunDir
from hbeo.data.gridset import GridSet
from hbeo.subspace.metrics import iou
from hbeo.subspace.partial import depth_to_partial
from hbeo.render.torch_datasets import load_shard

TEST_EPOCHS = config.get_profile("ci").baselines.voxcnn_epochs      #: the ci profile as is (3 epochs, seconds each)


# ------------------------------------------------------------------ fixtures (the session's ci run)

@pytest.fixture(scope="module", autouse=True)
def one_thread():
    """One torch thread in this module: on two cores shared with other jobs, two threads wait on
    each other at every operation (3-10x slower measured); restored afterwards."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def ci_run(ci_render, ci_render_test, copy_run, tmp_path_factory):
    """This module's copy of the session's ci run (grids, subspace, rendered train and test sets;
    conftest): training the baseline writes its partial grids, checkpoint and model file there.
    Rendering the sets and training take ~15 s, so every test using this is marked slow."""
    names = ("grids_train.npz", "grids_test.npz", "subspace.npz", "render_train", "render_test")
    return copy_run(ci_render.root.parent, tmp_path_factory.mktemp("voxcnn_run"), names).path


@pytest.fixture(scope="module")
def pset(one_thread, ci_run):
    return V.partial_training_set(ci_run, progress=False)


@pytest.fixture(scope="module")
def trained(one_thread, ci_run, pset):
    return V.train_voxcnn(ci_run, "ci", progress=False)


@pytest.fixture(scope="module")
def test_views(one_thread, ci_run):
    """All rendered views of the held-out test objects: depth, pose, partial grids, truth."""
    from hbeo.render.renderset import Manifest
    m = Manifest.load(ci_run / "render_test")
    grids = GridSet.load(ci_run / "grids_test.npz")
    assert list(grids.ids) == m.object_ids
    K, size = m.settings.intrinsics, m.settings.object_size
    out = {k: [] for k in ("depth", "R", "t", "label", "target", "filled", "known")}
    for p in m.shard_paths():
        sh = load_shard(p)
        for i in range(len(sh["label"])):
            f, k = depth_to_partial(sh["depth"][i].astype(np.float32), K, sh["rotation"][i], sh["translation"][i], size)
            out["filled"].append(f)
            out["known"].append(k)
            out["depth"].append(sh["depth"][i].astype(np.float32))
            out["R"].append(sh["rotation"][i].astype(np.float64))
            out["t"].append(sh["translation"][i].astype(np.float64))
            out["label"].append(int(sh["label"][i]))
            out["target"].append(grids.grids[sh["object_index"][i]])
    out = {k: np.stack(v) for k, v in out.items()}
    out["K"], out["size"] = K, size
    return out


# ------------------------------------------------------------------ the network

def test_network_shapes_and_config():
    cfg = V.VoxCNNConfig(channels=(4, 8, 8), n_classes=10, bottleneck=16)
    x = torch.zeros(3, 2, 30, 30, 30)
    for skips in (True, False):
        net = V.VoxCNN(V.VoxCNNConfig(**{**cfg.to_dict(), "skips": skips})).eval()
        out = net(x)
        assert out["logits"].shape == (3, 10) and out["occupancy"].shape == (3, 30, 30, 30)
    assert V.VoxCNNConfig.from_dict(cfg.to_dict()) == cfg
    with pytest.raises(ValueError, match=r"\(B, 2, 30, 30, 30\)"):
        net(torch.zeros(1, 1, 30, 30, 30))
    with pytest.raises(ValueError):
        V.VoxCNNConfig(channels=(4, 8))
    # every profile builds and is small enough for a CPU
    for name, prof in config.PROFILES.items():
        n = V.VoxCNN(V.VoxCNNConfig(channels=prof.baselines.voxcnn_channels, bottleneck=prof.baselines.voxcnn_bottleneck)).n_params()
        assert n < 20_000_000, name


def test_space_to_depth_and_input_encoding():
    x = torch.randn(2, 3, 30, 30, 30)
    y = V.space_to_depth(x)
    assert y.shape == (2, 24, 15, 15, 15)
    assert torch.equal(V.depth_to_space(y), x)
    assert torch.equal(y[:, 1 * 8 + 4 * 1 + 2 * 0 + 1, 3, 4, 5], x[:, 1, 7, 8, 11])  # cell offset (1, 0, 1)
    rng = np.random.default_rng(0)
    f, k = rng.random((30, 30, 30)) < 0.2, rng.random((30, 30, 30)) < 0.5
    inp = V.network_input(f, k)
    assert inp.shape == (1, 2, 30, 30, 30)
    assert np.array_equal(inp[0, 0].numpy() > 0, f & k)      # known-filled
    assert np.array_equal(inp[0, 1].numpy() > 0, k & ~f)     # known-empty; the rest is unknown


# ------------------------------------------------------------------ the partial training set

@pytest.mark.slow
def test_partial_training_set(ci_run, pset):
    from hbeo.render.renderset import Manifest
    m = Manifest.load(ci_run / "render_train")
    assert len(pset) == m.n_images and pset.classes == m.classes
    # cached, written atomically, and reused (same arrays, no recomputation)
    cache = ci_run / "partial_train.npz"
    stamp = cache.stat().st_mtime_ns
    again = V.partial_training_set(ci_run, progress=False)
    assert cache.stat().st_mtime_ns == stamp and np.array_equal(again.known, pset.known)
    # one view agrees with depth_to_partial and its object's complete grid
    sh = load_shard(m.shard_paths()[0])
    i = 5
    f, k = depth_to_partial(sh["depth"][i].astype(np.float32), m.settings.intrinsics, sh["rotation"][i],
                            sh["translation"][i], m.settings.object_size)
    pf, pk = pset.partial([i])
    assert np.array_equal(pf[0], f) and np.array_equal(pk[0], k)
    grids = GridSet.load(ci_run / "grids_train.npz")
    assert np.array_equal(pset.targets([i])[0], grids.grids[sh["object_index"][i]])
    item = pset[i]
    assert item["x"].shape == (2, 30, 30, 30) and item["target"].shape == (30, 30, 30)
    assert int(item["label"]) == int(sh["label"][i])
    # a subset of views per object, and the split by object
    sub = V.partial_training_set(ci_run, views_per_object=2, progress=False)
    assert len(sub) == len(m.object_ids) * 2 and (ci_run / "partial_train_v2.npz").exists()
    tr, va = pset.split(0.1, 0)
    assert len(tr) + len(va) == len(pset) and len(va) > 0
    assert not set(pset.object_index[tr]) & set(pset.object_index[va])


# ------------------------------------------------------------------ training and held-out accuracy

@pytest.mark.slow
def test_trained_baseline_beats_chance_and_empty_completion(ci_run, trained, test_views):
    tv = test_views
    n = len(tv["label"])
    assert n >= 200                                   # 30 held-out objects x 8 views
    probs, occ = trained.predict_partial(tv["filled"], tv["known"])
    assert probs.shape == (n, 10) and np.allclose(probs.sum(1), 1)
    acc = float((probs.argmax(1) == tv["label"]).mean())
    # chance is 10 %: at n = 240 its standard deviation is ~2 %, so 30 % is ~10 sd above it
    assert acc >= 0.30, acc
    grid = occ >= 0.5
    completion = iou(tv["target"], grid)
    visible = iou(tv["target"], tv["filled"] & tv["known"])
    print(f"voxcnn ci: held-out accuracy {acc:.3f}, completion IoU {completion.mean():.3f} "
          f"(visible voxels alone {visible.mean():.3f}, empty grid 0)")
    assert completion.mean() > 0.2                    # an empty prediction scores 0
    assert completion.mean() > visible.mean()         # completes more than what the camera saw
    # training wrote the model file, the checkpoint and the log
    run = RunDir(ci_run)
    assert run.baseline("voxcnn").is_file() and run.training(run.baseline("voxcnn")).name == "train_voxcnn"
    log = pd.read_csv(run.train_log(run.baseline("voxcnn")))
    assert list(log.epoch) == list(range(1, TEST_EPOCHS + 1)) and "val_iou" in log and "grids_per_s" in log


@pytest.mark.slow
def test_predict_view(trained, test_views):
    tv = test_views
    for i in (0, 7):
        out = trained.predict_view(tv["depth"][i], tv["K"], tv["R"][i], tv["t"][i], tv["size"])
        assert set(out) >= {"probabilities", "rotation", "grid"}
        assert out["probabilities"].shape == (10,) and out["grid"].shape == (30, 30, 30)
        assert out["grid"].dtype == bool and np.array_equal(out["rotation"], tv["R"][i])
        p, o = trained.predict_partial(tv["filled"][i], tv["known"][i])
        assert np.allclose(out["probabilities"], p[0]) and np.array_equal(out["grid"], o[0] >= 0.5)
    for pose in ("1dof", "3dof", None):
        with pytest.raises(ValueError, match="known"):
            trained.predict_view(tv["depth"][0], tv["K"], tv["R"][0], tv["t"][0], tv["size"], pose=pose)
    empty = trained.predict_view(np.zeros_like(tv["depth"][0]), tv["K"], tv["R"][0], tv["t"][0], tv["size"])
    assert empty["probabilities"].shape == (10,)      # no object pixel: an all-unknown input


@pytest.mark.slow
def test_rerun_after_training_resumes_from_checkpoint(ci_run, trained):
    """All epochs are in the checkpoint: a rerun trains nothing and gives the same weights."""
    again = V.train_voxcnn(ci_run, "ci", epochs=TEST_EPOCHS, progress=False)
    a, b = trained.net.state_dict(), again.net.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(DataError, match=f"train_voxcnn/{CHECKPOINT}: .*train.epochs {TEST_EPOCHS} there"):
        V.train_voxcnn(ci_run, "ci", epochs=TEST_EPOCHS + 1, progress=False)


@pytest.mark.slow
def test_interrupted_training_resumes_exactly(tmp_path, pset):
    from torch.utils.data import Subset
    from hbeo.rundir import TRAIN_LOG
    idx = np.arange(len(pset))
    tr, va = Subset(pset, idx[idx % 8 < 2][:40]), Subset(pset, idx[idx % 8 == 7][:8])   # a small slice
    task = V.VoxCNNTask(V.VoxCNNConfig(channels=(4, 4, 8), bottleneck=16))
    tc = TrainConfig(epochs=2, batch_size=16, lr=3e-3, warmup_steps=2, progress=False)
    full = train(task, tr, va, tmp_path / "a", tc)
    train(task, tr, va, tmp_path / "b", tc, stop_after_epoch=1)            # "interrupted"
    assert list(pd.read_csv(tmp_path / "b" / TRAIN_LOG).epoch) == [1]
    resumed = train(task, tr, va, tmp_path / "b", tc)
    a, b = full.state_dict(), resumed.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    la, lb = (pd.read_csv(tmp_path / d / TRAIN_LOG).drop(columns="grids_per_s") for d in "ab")
    assert la.equals(lb) and {"val_iou", "val_bce", "val_accuracy"} <= set(la)
    other = V.VoxCNNTask(V.VoxCNNConfig(channels=(4, 4, 4), bottleneck=16))
    with pytest.raises(DataError, match=r"other settings \(model\.net\.channels \[4, 4, 8\] there, \[4, 4, 4\] now"):
        train(other, tr, va, tmp_path / "a", tc)


@pytest.mark.slow
def test_interrupted_train_voxcnn_writes_no_model(tmp_path, ci_run, pset, copy_run):
    run = copy_run(ci_run, tmp_path / "run", ("render_train", "grids_train.npz")).path
    small = config.get_profile("ci", voxcnn_channels=(4, 4, 8), voxcnn_bottleneck=16, voxcnn_views_per_object=1)
    rd = RunDir(run)
    model_file = rd.baseline("voxcnn")
    V.train_voxcnn(rd, small, epochs=2, stop_after_epoch=1, progress=False)
    assert not model_file.exists() and rd.checkpoint(model_file).exists()
    V.train_voxcnn(run, small, epochs=2, progress=False)                 # a path works as well as a RunDir
    assert model_file.exists()
    assert list(pd.read_csv(rd.train_log(model_file)).epoch) == [1, 2]


# ------------------------------------------------------------------ the model file

@pytest.mark.slow
def test_save_load_round_trip(tmp_path, trained, test_views):
    path = trained.save(tmp_path / "m.hbeo")
    back = V.VoxCNNBaseline.load(path)
    assert back.classes == trained.classes and back.net.cfg == trained.net.cfg
    assert back.settings["profile"] == "ci" and back.settings["object_size"] == pytest.approx(1.0)
    f, k = test_views["filled"][:8], test_views["known"][:8]
    for a, b in zip(trained.predict_partial(f, k), back.predict_partial(f, k)):
        assert np.array_equal(a, b)


@pytest.mark.slow
def test_bad_model_files(tmp_path, trained):
    """The baseline's loader on bad files; the format's every case is in tests/test_modelfile.py."""
    import json
    import zipfile
    with pytest.raises(DataError, match="missing.hbeo: no such model file"):
        V.VoxCNNBaseline.load(tmp_path / "missing.hbeo")
    junk = tmp_path / "junk.hbeo"
    junk.write_bytes(b"not a model file")
    with pytest.raises(DataError, match="junk.hbeo: not a readable"):
        V.VoxCNNBaseline.load(junk)
    old = tmp_path / "voxcnn.pt"                  # the old torch-pickle format: refused without unpickling
    torch.save({"format_version": 1, "kind": "hbeo-voxcnn", "state_dict": {}}, old)
    with pytest.raises(DataError, match="voxcnn.pt: a torch pickle, which hbeo does not open.*python -m hbeo convert-model"):
        V.VoxCNNBaseline.load(old)
    good = trained.save(tmp_path / "good.hbeo")
    broken = tmp_path / "broken.hbeo"             # a configuration the stored weights do not fit
    with zipfile.ZipFile(good) as z, zipfile.ZipFile(broken, "w") as out:
        for name in z.namelist():
            data = z.read(name)
            if name == "meta.json":
                meta = json.loads(data)
                meta["net_cfg"]["channels"] = [1, 2, 3]
                data = json.dumps(meta).encode()
            out.writestr(name, data)
    with pytest.raises(DataError, match="broken.hbeo: weights.safetensors does not match net_cfg"):
        V.VoxCNNBaseline.load(broken)
    truncated = tmp_path / "truncated.hbeo"
    truncated.write_bytes(good.read_bytes()[:1000])
    with pytest.raises(DataError, match="truncated.hbeo: not a readable"):
        V.VoxCNNBaseline.load(truncated)
