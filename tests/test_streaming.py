"""The three sources of training images (memory, shards, stream) feed the loop the same items; the stream
rendered in batches by the torch grid renderer gives the images it gives one by one and resumes exactly."""
from dataclasses import replace

import numpy as np
import pytest
import torch

from hbeo import config
from hbeo.data import datasets
from hbeo.model.trainingdata import ViewOptions, training_data
from hbeo.model.loop import TrainConfig, data_loader
from hbeo.render.views import RenderSettings


def _spec(item):
    return {k: (tuple(v.shape), v.dtype) if torch.is_tensor(v) else type(v) for k, v in item.items()}


@pytest.fixture(scope="module")
def sources(ci_render, ci_subspace, ci_run, copy_run, tmp_path_factory):
    run = copy_run(ci_run, tmp_path_factory.mktemp("stream") / "run")
    prof = config.get_profile("ci")
    settings = RenderSettings.from_profile(prof)
    ds = datasets.get_dataset("procedural", profile=prof)
    return {s: training_data(run, ViewOptions(), source=s, dataset=ds, profile=prof, settings=settings,
                             progress=False) for s in ("memory", "shards", "stream")}


def test_the_three_sources_give_items_of_the_same_keys_shapes_and_dtypes(sources):
    want = _spec(sources["memory"].train[0])
    assert set(want) == {"depth", "label", "rotation", "axis_angle", "coeffs", "object_index"}
    assert _spec(sources["shards"].train[0]) == want
    stream_item = next(iter(sources["stream"].train))
    assert _spec(stream_item) == want
    assert _spec(next(iter(sources["stream"].val))) == want
    cfg = TrainConfig(batch_size=8, seed=0)
    batches = {s: next(iter(data_loader(d.train, cfg, 1))) for s, d in sources.items()}
    for s, b in batches.items():
        assert {k: (tuple(v.shape), v.dtype) for k, v in b.items()} == \
               {k: (tuple(v.shape), v.dtype) for k, v in batches["memory"].items()}, s


def test_shards_give_exactly_the_memory_items_and_split(sources):
    mem, sh = sources["memory"], sources["shards"]
    assert len(mem.train) == len(sh.train) and len(mem.val) == len(sh.val)
    np.testing.assert_allclose(sh.coeff_mean, mem.coeff_mean, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(sh.coeff_std, mem.coeff_std, rtol=1e-5)
    for i in (0, 7, len(mem.train) - 1):
        a, b = mem.train[i], sh.train[i]
        for k in ("depth", "rotation", "axis_angle", "label", "object_index"):
            assert torch.equal(torch.as_tensor(a[k]), torch.as_tensor(b[k])), k
        torch.testing.assert_close(a["coeffs"], b["coeffs"], rtol=1e-4, atol=1e-4)


def _loads(shard_sequence, cache: int) -> int:
    """Shard reads of an LRU cache of ``cache`` shards serving images of these shards in order."""
    held, loads = [], 0
    for k in shard_sequence:
        if k in held:
            held.remove(k)
        else:
            loads += 1
            held = held[-(cache - 1):] if cache > 1 else []
        held.append(k)
    return loads


def test_shard_order_depends_on_seed_and_epoch_only(sources):
    from hbeo.model.trainingdata import SHARD_MIX
    sh = sources["shards"].train
    orders = [list(sh.epoch_sampler(0, e)) for e in (0, 0, 1)]
    assert orders[0] == orders[1] != orders[2]
    assert sorted(orders[0]) == list(range(len(sh)))
    assert sh.base.dataset.cache_shards == SHARD_MIX


class _ClassSortedShards:
    """What ShardSampler reads of a DepthShards: 40 shards of 25 images, written in class order
    (10 classes, 4 shards each), as render_set writes them."""

    def __len__(self):
        return 1000

    def shard_of(self, i):
        return np.asarray(i) // 25


def test_shard_blocks_read_each_shard_once_and_mix_classes():
    from hbeo.render.torch_datasets import ShardSampler
    data, labels = _ClassSortedShards(), np.arange(1000) // 100
    idx = np.arange(0, 1000, 2)                           # a subset, as the training split is
    for mix in (1, 4, 8):
        order = np.array(list(ShardSampler(data, idx, seed=3, mix=mix)))
        assert sorted(order) == list(range(len(idx)))
        shards = data.shard_of(idx[order])
        assert _loads(shards, mix) == 40                  # each shard read once with a cache of `mix` shards
        assert _loads(shards, max(1, mix // 2)) > 40 or mix == 1
    def classes_per_batch(mix):
        order = np.array(list(ShardSampler(data, idx, seed=3, mix=mix)))
        lab = labels[idx[order]]
        return np.mean([len(np.unique(lab[i:i + 16])) for i in range(0, len(lab) - 15, 16)])
    # one shard at a time, a batch of 16 spans one or two shards (classes); blocks of 8 shards mix many
    assert classes_per_batch(1) < 2.2 < 4 < classes_per_batch(8)


def test_stream_draws_fresh_poses_each_epoch_and_a_fixed_validation_set(sources):
    st, mem = sources["stream"], sources["memory"]
    prof = config.get_profile("ci")
    n_val_objects = len(np.unique([mem.val[i]["object_index"] for i in range(len(mem.val))]))
    assert len(st.val) == n_val_objects * prof.data.stream_val_views
    assert len(st.train) == len(mem.train)            # one pass per rendered view
    cfg = TrainConfig(batch_size=4, seed=0)

    def first(epoch):
        return next(iter(data_loader(st.train, cfg, epoch)))["rotation"]
    assert torch.equal(first(0), first(0)) and not torch.equal(first(0), first(1))
    v1 = torch.cat([b["depth"] for b in data_loader(st.val, cfg)])
    v2 = torch.cat([b["depth"] for b in data_loader(st.val, cfg)])
    assert torch.equal(v1, v2)


# --------------------------------------------------------------------------- stream on the torch renderer

def _tiny_vox30(path):
    """A grid file in the modelnet10_vox30 layout: chairs (tall boxes with a back) and tables (a top on
    legs), 6 training and 3 test objects each, sizes varying with the index."""
    def chair(i):
        g = np.zeros((30, 30, 30), bool)
        g[8:22, 8:22, 3:12 + i % 3] = True
        g[8:11 + i % 2, 8:22, 12:27] = True
        return g

    def table(i):
        g = np.zeros((30, 30, 30), bool)
        g[3:27, 6 + i % 3:24, 16:19] = True
        for x in (4, 24):
            for y in (7 + i % 3, 22):
                g[x:x + 2, y:y + 2, 3:16] = True
        return g
    arrays = {"classes": np.array(["chair", "table"])}
    for split, n in (("train", 6), ("test", 3)):
        X = np.stack([f(i + 10 * (split == "test")) for f in (chair, table) for i in range(n)])
        arrays[f"X_{split}"] = X
        arrays[f"y_{split}"] = np.repeat([0, 1], n)
        arrays[f"names_{split}"] = np.array([f"{c}_{split}_{i}" for c in ("chair", "table") for i in range(n)])
    np.savez(path, **arrays)
    return path


@pytest.fixture(scope="module")
def torch_stream(tmp_path_factory):
    """A ci run on a tiny grid dataset with its subspace, and a function giving its torch-stream data."""
    from hbeo.run import Run
    tmp = tmp_path_factory.mktemp("torch_stream")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("HBEO_CACHE", str(tmp / "cache"))
        run = Run.open("ci", "modelnet10-vox30", tmp / "run", path=_tiny_vox30(tmp / "tiny.npz"))
        run.subspace(progress=False)
    settings = RenderSettings.from_profile(run.profile, backend="torch")

    def data(roll=False, **kw):
        return training_data(run.dir, ViewOptions(), augment_roll=roll, source="stream", dataset=run.dataset,
                             profile=run.profile, settings=replace(settings, **kw), progress=False)
    return run, data


def test_torch_stream_batches_are_the_images_rendered_one_by_one(torch_stream):
    _, data = torch_stream
    d = data(noise=True)
    base = d.train.base
    assert base.renders_batches and not data(backend="embree").train.base.renders_batches
    idx = [0, 5, 17, len(d.train) - 1]
    batch = base.render_batch(idx)
    assert batch["depth"].shape == (4, 1, 60, 80) and (batch["depth"] > 0).any(dim=(1, 2, 3)).all()
    for k, i in enumerate(idx):
        one = base[i]                          # ObjectViews, the torch backend on one object: the same image
        torch.testing.assert_close(batch["depth"][k], one["depth"], atol=1e-3, rtol=0)
        assert torch.equal(batch["rotation"][k], one["rotation"]) and torch.equal(batch["coeffs"][k], one["coeffs"])
    # the coefficients, projected for all objects at once (FreshPoses._prefill_coeffs), are each object's own
    from hbeo.data.gridset import record_grid
    b = base.base
    assert b.subspace is not None and base._ctx.prefilled
    for k, i in enumerate(idx):
        rec = b.records[i % len(b)]
        # float32 sums of 27,000 products in two orders (torch's kernels and numpy's BLAS pick their blocking by
        # CPU): on an AVX-512 Xeon a coefficient of 47.35 came out 5.9e-4 apart, 1.2e-5 of it; a wrong one is far off
        np.testing.assert_allclose(batch["coeffs"][k].numpy(), b.subspace.project(record_grid(rec)[None])[0],
                                   rtol=5e-5, atol=1e-4)
    # a model batch: the memory source's keys, shapes and dtypes
    items = d.train.__getitems__(idx)
    assert _spec(items[0]) == _spec(d.train[idx[0]])
    assert set(items[0]) == {"depth", "label", "rotation", "axis_angle", "coeffs", "object_index"}


def test_torch_stream_loader_batches_come_stacked_as_the_default_collation_would_build_them(torch_stream):
    """The training loader passes a batch rendered together on as it is (hbeo.batches.Stacked), every tensor
    where its depth is: the same values, shapes and dtypes as torch's default collation of its items."""
    from torch.utils.data import default_collate
    _, data = torch_stream
    d = data(roll=True)
    cfg = TrainConfig(batch_size=4, seed=3)
    batch = next(iter(data_loader(d.train, cfg, 0)))
    order = d.train.epoch_sampler(cfg.seed, 0)
    again = data(roll=True).train
    again.plan_reads(order)
    theirs = default_collate(list(again.__getitems__(order[:4].tolist())))
    assert set(batch) == set(theirs) == {"depth", "label", "rotation", "axis_angle", "coeffs", "object_index"}
    for k, v in theirs.items():
        assert batch[k].dtype == v.dtype and torch.equal(batch[k], v), k
        assert batch[k].device == batch["depth"].device


def test_stream_validation_renders_once_and_gives_the_same_items_again(torch_stream, monkeypatch):
    from hbeo.model import trainingdata
    _, data = torch_stream
    val = data().val
    first = list(val)
    calls = []
    monkeypatch.setattr(type(val.base), "__iter__", lambda self: calls.append(1) or iter(()))
    again = list(val)                                        # the kept pass: the base is not read
    assert not calls and len(again) == len(first) == len(val) > 0
    for a, b in zip(first, again):
        assert torch.equal(a["depth"], b["depth"]) and a["label"] == b["label"]
    val.set_epoch(1)                                         # another epoch's views: read again
    assert list(val) == [] and calls
    monkeypatch.undo()                                       # the base renders again
    monkeypatch.setattr(trainingdata, "STREAM_CACHE_PIXELS", 1)     # a pass too large to keep
    monkeypatch.setattr(trainingdata, "_SHARED_PASSES", {})         # (nor kept from an earlier training)
    fresh = data().val
    assert len(list(fresh)) == len(first) and fresh._kept is None and not trainingdata._SHARED_PASSES


def test_stream_validation_pass_serves_the_next_training_of_the_process_with_the_same_views(torch_stream,
                                                                                              monkeypatch):
    """A device job trains three times over the same validation objects: the second training's validation
    takes the first's kept pass (the same items) instead of rendering it again; other views (another render
    seed) and a rolled validation set do not share."""
    from hbeo.model import trainingdata
    monkeypatch.setattr(trainingdata, "_SHARED_PASSES", {})
    _, data = torch_stream
    first = list(data().val)
    calls = []
    real = type(data().val.base).__iter__
    monkeypatch.setattr(type(data().val.base), "__iter__", lambda self: calls.append(1) or real(self))
    second = data().val                                      # another training's data, built anew
    items = list(second)
    assert not calls and len(items) == len(first) > 0
    assert all(torch.equal(a["depth"], b["depth"]) and torch.equal(a["coeffs"], b["coeffs"])
               and a["label"] == b["label"] for a, b in zip(first, items))
    other = data(seed=7).val                                 # other views: rendered, and they differ
    assert other._kept is None and len(list(other)) == len(first) and calls
    assert not all(torch.equal(a["depth"], b["depth"]) for a, b in zip(first, other))
    assert data(seed=7).val._kept is not None                # ... and now kept in their place (the last only)
    assert data().val._kept is None and len(trainingdata._SHARED_PASSES) == 1
    v = data(seed=7).val
    rolled = trainingdata.ModelViewStream(v.base, v.K, v.opts, v.coeff_mean, v.coeff_std, roll=True, share=v.share)
    assert rolled.share is None and rolled._kept is None


def test_torch_stream_roll_turns_pose_and_image_together(torch_stream):
    _, data = torch_stream
    base = data().train.base
    torch.manual_seed(0)
    rolled = base.render_batch([3, 4], roll=True)
    plain = base.render_batch([3, 4])
    from hbeo.rotations import geodesic_deg
    R0, R1 = plain["rotation"].double().numpy(), rolled["rotation"].double().numpy()
    rel = R1 @ R0.transpose(0, 2, 1)               # Rz(a): a turn about the optical axis only
    np.testing.assert_allclose(rel[:, 2], [[0, 0, 1]] * 2, atol=1e-6)
    assert (geodesic_deg(R0, R1) > 1).all()
    torch.manual_seed(0)
    assert torch.equal(base.render_batch([3, 4], roll=True)["depth"], rolled["depth"])


def test_torch_stream_refuses_a_mesh_dataset():
    from hbeo.render.torch_datasets import FreshPoses
    prof = config.get_profile("ci")
    ds = datasets.get_dataset("procedural", profile=prof)
    with pytest.raises(ValueError, match="mesh only.*modelnet10-vox30"):
        FreshPoses(ds, ds.records("train")[:4], "train", RenderSettings(backend="torch"))


def test_torch_stream_training_resumes_exactly(torch_stream, tmp_path):
    """Killed after step 5 (2 epochs of 3 steps, a checkpoint every 2), resumed: the same weights."""
    from hbeo.model.distributed import weights_sha256
    from hbeo.model.fit import HBEONetTask
    from hbeo.model.loop import load_checkpoint, train
    from hbeo.model.network import NetConfig
    from hbeo.rundir import CHECKPOINT
    run, data = torch_stream

    def fit(out, **kw):
        d = data(roll=True, views_per_object=2)
        task = HBEONetTask(NetConfig(image_size=(80, 60), n_classes=2, n_coeffs=len(d.coeff_mean),
                                     conv_channels=(4, 4, 4, 4), fc=(8, 8, 8)))
        cfg = TrainConfig(epochs=2, batch_size=8, seed=0, progress=False, device="cpu", checkpoint_every=2,
                          data={"source": "stream", "backend": "torch"})
        return train(task, d.train, d.val, out, cfg, **kw)
    whole = weights_sha256(fit(tmp_path / "whole"))
    fit(tmp_path / "cut", stop_after_step=5)
    assert load_checkpoint(tmp_path / "cut" / CHECKPOINT)["step"] == 4
    assert weights_sha256(fit(tmp_path / "cut")) == whole


def _read(view, order, batch):
    """``view``'s batches over ``order``, read as the training loader reads them (after plan_reads)."""
    return [view.__getitems__(order[k:k + batch].tolist()) for k in range(0, len(order), batch)]


def _same(a, b):
    return all(torch.equal(x[k], y[k]) for x, y in zip(a, b) for k in x)


def test_torch_stream_rendered_ahead_gives_the_same_images_and_rolls_by_reading_position(torch_stream, monkeypatch):
    from hbeo.render.torch_datasets import FreshPoses
    _, data = torch_stream
    calls = []
    real = FreshPoses.render_batch
    monkeypatch.setattr(FreshPoses, "render_batch", lambda self, idx, **kw: calls.append((len(idx), kw)) or
                        real(self, idx, **kw))
    order = np.array([3, 3, 5, 0, 1, 2, 3, 7, 9, 11, 4, 6, 8, 10, 3, 2], np.int64)   # drawn with replacement
    one = data(roll=True).train
    one.ahead = 0
    one.plan_reads(order)
    by_batch = [[it for it in b] for b in _read(one, order, 4)]
    assert [n for n, _ in calls] == [4] * 4 and all(kw["roll_keys"] is not None for _, kw in calls)
    calls.clear()
    ahead = data(roll=True).train
    ahead.ahead = 6                                           # rounded up to whole batches: 8 images a march
    ahead.plan_reads(order)
    assert _same([i for b in _read(ahead, order, 4) for i in b], [i for b in by_batch for i in b])
    assert [n for n, _ in calls] == [8, 8]
    # the same object read twice in an epoch is rolled twice (positions 0 and 1), not given the same view
    first = by_batch[0]
    assert first[0]["object_index"] == first[1]["object_index"]
    assert not torch.equal(first[0]["rotation"], first[1]["rotation"])
    # a resumed epoch (the loader's rest of the order, starting at position 8) reads the same images
    rest = data(roll=True).train
    rest.plan_reads(order[8:], start=8)
    assert _same([i for b in _read(rest, order[8:], 4) for i in b], [i for b in by_batch[2:] for i in b])
    # a read outside the plan renders alone, as before (rolls from torch's global generator)
    calls.clear()
    assert len(rest.__getitems__([5, 5, 5])) == 3 and calls == [(3, {"roll": True})]


def test_torch_stream_training_rendered_ahead_gives_the_same_weights(torch_stream, tmp_path):
    from hbeo.model.distributed import weights_sha256
    from hbeo.model.fit import HBEONetTask
    from hbeo.model.loop import train
    from hbeo.model.network import NetConfig
    run, data = torch_stream

    def fit(out, ahead):
        d = data(roll=True, views_per_object=2)
        d.train.ahead = ahead
        task = HBEONetTask(NetConfig(image_size=(80, 60), n_classes=2, n_coeffs=len(d.coeff_mean),
                                     conv_channels=(4, 4, 4, 4), fc=(8, 8, 8)))
        cfg = TrainConfig(epochs=2, batch_size=8, seed=0, progress=False, device="cpu",
                          data={"source": "stream", "backend": "torch"})
        return train(task, d.train, d.val, out, cfg)
    assert weights_sha256(fit(tmp_path / "a", 0)) == weights_sha256(fit(tmp_path / "b", 24))


def test_poses_drawn_ahead_in_worker_processes_are_the_poses_drawn_here(torch_stream):
    from hbeo.render.posedraws import DrawAhead
    _, data = torch_stream
    base = data(roll=True).train.base
    base.set_epoch(3)
    idx, keys = [0, 7, 7, 2, 11, 5, 9], np.arange(40, 47)
    here = base.draws.draw(idx, 3, keys)
    drawer = DrawAhead(base.draws, 3)
    try:
        drawer.submit("a", idx, 3, keys)
        assert drawer.take("b") is None                         # another's draw: not taken, still pending
        ahead = drawer.take("a")
        assert drawer.take("a") is None                         # taken once
        drawer.submit("c", idx, 3, None)                        # unrolled
        plain = drawer.take("c")
    finally:
        drawer.close()
    for k in ("pos", "R", "t"):                                 # three slices, three processes: bit for bit
        assert np.array_equal(ahead[k], here[k]) and ahead[k].dtype == here[k].dtype
    assert np.array_equal(plain["R"], base.draws.draw(idx, 3)["R"]) and not np.array_equal(plain["R"], here["R"])
    got, want = base.render_batch(idx, roll=True, roll_keys=keys, drawn=ahead), \
        base.render_batch(idx, roll=True, roll_keys=keys)
    assert all(torch.equal(got[k], want[k]) for k in want)
    with pytest.raises(ValueError, match="not those of these images"):
        base.render_batch(idx[::-1], roll=True, roll_keys=keys, drawn=ahead)
    with pytest.raises(ValueError, match="need the roll keys"):
        base.render_batch(idx, roll=True, drawn=ahead)
    noisy = data(roll=True, noise=True).train.base
    with pytest.raises(ValueError, match="sensor noise"):
        noisy.render_batch(idx, roll=True, roll_keys=keys, drawn=ahead)


def test_torch_stream_marches_drawn_ahead_give_the_same_batches_and_weights(torch_stream, tmp_path, monkeypatch):
    from hbeo.model.distributed import weights_sha256
    from hbeo.model.fit import HBEONetTask
    from hbeo.model.loop import train
    from hbeo.model.network import NetConfig
    from hbeo.render.torch_datasets import FreshPoses
    run, data = torch_stream
    order = np.array([3, 3, 5, 0, 1, 2, 3, 7, 9, 11, 4, 6, 8, 10, 3, 2], np.int64)
    drawn, real = [], FreshPoses.render_batch
    monkeypatch.setattr(FreshPoses, "render_batch", lambda self, idx, **kw: drawn.append(kw.get("drawn") is not None)
                        or real(self, idx, **kw))
    views = {}
    for workers in (0, 2):
        v = data(roll=True).train
        v.ahead, v.draw_workers = 4, workers
        v.plan_reads(order)
        views[workers] = [i for b in _read(v, order, 4) for i in b]
        v.close()
    assert _same(views[2], views[0])
    assert drawn == [False] * 4 + [False, True, True, True]     # every march after the first was drawn ahead
    noisy = data(noise=True).train
    noisy.draw_workers = 2
    assert noisy._draw_ahead() is None                           # noise draws after the pose: never ahead

    def fit(out, workers):
        d = data(roll=True, views_per_object=2)
        d.train.ahead, d.train.draw_workers = 8, workers
        task = HBEONetTask(NetConfig(image_size=(80, 60), n_classes=2, n_coeffs=len(d.coeff_mean),
                                     conv_channels=(4, 4, 4, 4), fc=(8, 8, 8)))
        cfg = TrainConfig(epochs=2, batch_size=4, seed=0, progress=False, device="cpu",
                          data={"source": "stream", "backend": "torch"})
        try:
            return train(task, d.train, d.val, out, cfg)
        finally:
            d.train.close()
    assert weights_sha256(fit(tmp_path / "a", 0)) == weights_sha256(fit(tmp_path / "b", 2))


def test_no_process_draws_ahead_on_the_cpu_by_default():
    from hbeo.render.posedraws import DrawAhead, auto_draw_workers
    assert auto_draw_workers("cpu") == 0 and 0 <= auto_draw_workers("cuda") <= 8
    with pytest.raises(ValueError, match="at least one worker"):
        DrawAhead(None, 0)


def test_the_default_march_fits_the_devices_free_memory():
    from hbeo.render.gridcast import MARCH_BYTES_PER_RAY, RENDER_AHEAD, auto_render_ahead
    assert auto_render_ahead(0, 80 * 60) == 0                                   # the CPU: a batch at a time
    assert auto_render_ahead(140 * 2**30, 320 * 240) == RENDER_AHEAD            # an H200: the cap
    small = auto_render_ahead(6 * 2**30, 320 * 240)                             # a 6 GiB card: what fits
    assert 0 < small < RENDER_AHEAD and small * 320 * 240 * MARCH_BYTES_PER_RAY <= 6 * 2**30 / 4
    assert auto_render_ahead(6 * 2**30, 80 * 60) == RENDER_AHEAD                # small images: the cap again


def test_torch_stream_rolls_are_the_same_with_loader_workers(torch_stream):
    """Workers read batches out of the plan's turn; each finds its place in the plan, so its rolls (and images)
    are those the main process draws: the loader's batches are equal with 0 and 2 workers."""
    _, data = torch_stream
    cfg = TrainConfig(epochs=1, batch_size=4, seed=0, progress=False, device="cpu")
    batches = {}
    for workers in (0, 2):
        d = data(roll=True)
        batches[workers] = list(data_loader(d.train, replace(cfg, num_workers=workers), epoch=1))
    assert len(batches[0]) == len(batches[2]) > 2
    for a, b in zip(batches[0], batches[2]):
        assert torch.equal(a["depth"], b["depth"]) and torch.equal(a["rotation"], b["rotation"])


def test_torch_stream_batches_carry_each_images_own_label_and_pose_target(torch_stream):
    """Every image of a batch rendered together carries the class of the object it shows (the dataset's record,
    and what the one-by-one path gives) and the axis-angle of its own rotation (object -> camera), not another
    image's label nor the inverse rotation's target."""
    from hbeo.rotations import axis_angle_to_matrix, geodesic_deg, matrix_to_axis_angle
    _, data = torch_stream
    d = data()
    base = d.train.base
    b, n = base.base, len(base.base)
    idx = list(range(n)) + [n + 1, len(base) - 1]            # every object once, and two of a later pass
    batch = base.render_batch(idx)
    want = [b.classes.index(b.records[i % n].cls) for i in idx]
    assert set(want) == {0, 1}
    assert batch["label"].dtype == torch.long and batch["label"].tolist() == want
    assert batch["object_index"].tolist() == [i % n for i in idx]
    R = batch["rotation"].double().numpy()
    aa = batch["axis_angle"].double().numpy()
    angle = np.linalg.norm(aa, axis=1)
    ok = (angle > 0.2) & (angle < np.pi - 0.2)                # away from 0 and pi: R and R^T differ clearly
    assert ok.sum() >= len(idx) // 2
    assert (geodesic_deg(R[ok], R[ok].transpose(0, 2, 1)) > 10).all()
    np.testing.assert_allclose(aa[ok], matrix_to_axis_angle(R[ok]), atol=1e-4)
    np.testing.assert_allclose(axis_angle_to_matrix(aa), R, atol=1e-4)        # every target rebuilds its rotation
    # the one-by-one path: one image of each class, the same label, rotation and target
    for c in (0, 1):
        k = want.index(c)
        one = base[idx[k]]
        assert int(one["label"]) == c == int(batch["label"][k])
        assert torch.equal(batch["rotation"][k], one["rotation"])
        torch.testing.assert_close(batch["axis_angle"][k], one["axis_angle"], atol=1e-5, rtol=0)
    # and the training view's batch (what the loop reads) keeps each image's label
    items = d.train.__getitems__(idx)
    assert [int(it["label"]) for it in items] == want
    assert [int(it["object_index"]) for it in items] == [i % n for i in idx]
