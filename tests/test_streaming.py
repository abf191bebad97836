"""The three sources of training images (memory, shards, stream) feed the loop the same items."""
import numpy as np
import pytest
import torch

from hbeo import config
from hbeo.model.fit import ViewOptions, training_data
from hbeo.model.train import TrainConfig, data_loader
from hbeo.render.views import RenderSettings


def _spec(item):
    return {k: (tuple(v.shape), v.dtype) if torch.is_tensor(v) else type(v) for k, v in item.items()}


@pytest.fixture(scope="module")
def sources(ci_render, ci_subspace, ci_run, copy_run, tmp_path_factory):
    run = copy_run(ci_run, tmp_path_factory.mktemp("stream") / "run")
    prof = config.get_profile("ci")
    settings = RenderSettings.from_profile(prof)
    return {s: training_data(run, ViewOptions(), source=s, dataset="procedural", profile=prof, settings=settings,
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


def test_shard_order_is_shard_by_shard_and_depends_on_seed_and_epoch_only(sources):
    sh = sources["shards"].train
    orders = [list(sh.epoch_sampler(0, e)) for e in (0, 0, 1)]
    assert orders[0] == orders[1] != orders[2]
    assert sorted(orders[0]) == list(range(len(sh)))
    shards = sh.base.dataset.shard_of(sh.base.indices[orders[0]])
    assert (np.diff(shards) != 0).sum() == len(np.unique(shards)) - 1      # each shard visited once


def test_stream_draws_fresh_poses_each_epoch_and_a_fixed_validation_set(sources):
    st, mem = sources["stream"], sources["memory"]
    prof = config.get_profile("ci")
    n_val_objects = len(np.unique([mem.val[i]["object_index"] for i in range(len(mem.val))]))
    assert len(st.val) == n_val_objects * prof.stream_val_views
    assert len(st.train) == len(mem.train)            # one pass per rendered view
    cfg = TrainConfig(batch_size=4, seed=0)

    def first(epoch):
        return next(iter(data_loader(st.train, cfg, epoch)))["rotation"]
    assert torch.equal(first(0), first(0)) and not torch.equal(first(0), first(1))
    v1 = torch.cat([b["depth"] for b in data_loader(st.val, cfg)])
    v2 = torch.cat([b["depth"] for b in data_loader(st.val, cfg)])
    assert torch.equal(v1, v2)
