"""Resources checked before they are spent (hbeo.limits, issue #30 item 2): every size a user gives runs in
bounded memory or is refused up front with one line naming the option, the estimate and what fits."""
from __future__ import annotations

import time

import numpy as np
import pytest

from hbeo import limits
from hbeo.cli import main
from hbeo.limits import ResourceError

GB = 10 ** 9


# ------------------------------------------------------------------ rolls: batched, capped

def _bins_model(tiny_model, n=512):
    from hbeo.model.inference import HBEO
    from hbeo.model.network import HBEONet, NetConfig
    import torch
    base = tiny_model({"recenter": False})
    torch.manual_seed(1)
    net = HBEONet(NetConfig(image_size=(32, 24), n_classes=2, n_coeffs=base.subspace.dim_,
                            conv_channels=(4, 4, 4, 4), fc=(8, 8, 8), rotation="bins", rotation_bins=n))
    return HBEO(net, base.subspace, base.intrinsics, base.classes, {"recenter": False})


def _depth(K):
    d = np.zeros((K.height, K.width))
    d[8:16, 6:26] = 1.7
    d[8:12, 20:26] = 1.9
    return d


@pytest.mark.parametrize("rolls, images", [(5, 1), (7, 2), (3, 3)])
def test_rolls_in_batches_give_the_all_at_once_answer(tiny_model, monkeypatch, rolls, images):
    import hbeo.model.inference as inference
    m = _bins_model(tiny_model)
    d = np.stack([_depth(m.intrinsics)] * images)
    d[-1, 8:10] = 1.8                                   # the images differ
    monkeypatch.setattr(inference, "ROLL_BATCH", 10 ** 6)
    whole = m.predict(d, m.intrinsics, rolls=rolls)
    calls = []
    net = m._net
    monkeypatch.setattr(m, "_net", lambda x: calls.append(len(x)) or net(x))
    monkeypatch.setattr(inference, "ROLL_BATCH", 2 * images)      # two rolls per pass
    parts = m.predict(d, m.intrinsics, rolls=rolls)
    assert len(calls) == -(-rolls // 2) and max(calls) == 2 * images       # it did run in batches
    assert np.allclose(parts.probabilities, whole.probabilities, atol=1e-6)
    assert np.allclose(parts.pose_probs, whole.pose_probs, atol=1e-9)
    assert np.allclose(parts.coeffs, whole.coeffs, atol=1e-5)
    assert np.allclose(parts.rotation, whole.rotation, atol=1e-6)
    assert (parts.grids == whole.grids).all()


def _blas_threads() -> list[int]:
    from threadpoolctl import threadpool_info
    return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]


def test_one_blas_thread_limits_blas_only_and_restores_it():
    from threadpoolctl import threadpool_limits
    with threadpool_limits(limits=2, user_api="blas"):
        before = _blas_threads()
        assert before and max(before) == 2
        with limits.one_blas_thread():
            assert set(_blas_threads()) == {1}
        assert _blas_threads() == before


def test_predict_runs_the_network_and_back_projection_with_blas_on_one_thread(tiny_model, monkeypatch):
    """Spinning BLAS threads slowed ~4 % of network passes 10-30x on 2 cores (benchmarks/README.md,
    "Inference: the BLAS threads"): the whole prediction runs with numpy's BLAS on one thread."""
    from threadpoolctl import threadpool_limits
    m = _bins_model(tiny_model)
    seen = {}
    net, reconstruct = m._net, m.subspace.reconstruct
    monkeypatch.setattr(m, "_net", lambda x: seen.setdefault("net", _blas_threads()) and net(x))
    monkeypatch.setattr(m.subspace, "reconstruct",
                        lambda *a, **k: seen.setdefault("reconstruct", _blas_threads()) and reconstruct(*a, **k))
    with threadpool_limits(limits=2, user_api="blas"):
        p = m.predict(_depth(m.intrinsics), m.intrinsics)
        assert max(_blas_threads()) == 2                # restored for the caller
    assert set(seen["net"]) == {1} and set(seen["reconstruct"]) == {1}
    assert p.grids.shape == (1, 30, 30, 30)


def test_rolls_above_the_cap_are_refused_before_any_pass(tiny_model):
    m = _bins_model(tiny_model)
    with pytest.raises(ResourceError, match=r"rolls 100,000: .*at most 360"):
        m.predict(_depth(m.intrinsics), m.intrinsics, rolls=100_000)
    assert limits.check_rolls(360) == 360
    assert m._roll_perms == {}


def test_predict_rolls_100000_exits_2_in_one_line_before_reading_anything(tmp_path, capsys):
    t0 = time.perf_counter()
    code = main(["predict", "--model", str(tmp_path / "none.hbeo"), "--depth", str(tmp_path / "none.png"),
                 "--intrinsics", "65,65,39,29", "--rolls", "100000", "--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 2 and time.perf_counter() - t0 < 1
    assert err.startswith("error: --rolls 100,000:") and "at most 360" in err and err.count("\n") == 1
    assert not (tmp_path / "r.json").exists()


# ------------------------------------------------------------------ render: estimate before any work

def test_render_views_1e8_is_refused_up_front_with_the_estimate(tmp_path, capsys, monkeypatch):
    from hbeo.render import renderset
    monkeypatch.setattr(renderset, "_render_shards", lambda *a, **k: pytest.fail("rendering started"))
    out = tmp_path / "run"
    code = main(["render", "--profile", "ci", "--split", "test", "--views", "100000000", "--out", str(out),
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: --views 1.0e8: 3.0e9 images of 30 objects at 80x60") and "largest value" in err
    assert not (out / "render_test").exists()


def test_render_estimates_memory_and_disk_and_names_what_fits(tmp_path):
    with pytest.raises(ResourceError, match=r"--views 1,000: .*4 shard.*4.9 GB of memory, 4.0 GB available; "
                                            r"the largest value that fits is 406$"):
        limits.check_render(10, 1000, (320, 240), tmp_path, 1, 4, memory=4 * GB)
    limits.check_render(10, 406, (320, 240), tmp_path, 1, 4, memory=4 * GB)
    with pytest.raises(ResourceError, match=r"at least 2.5 GB on disk .*2.0 GB free in .*largest value that fits is 78,431"):
        limits.check_render(10, 10 ** 5, (80, 60), tmp_path, memory=10 ** 15, free=2 * GB)
    limits.check_render(10, 78_431, (80, 60), tmp_path, memory=10 ** 15, free=2 * GB)     # what it said fits


def test_workers_beyond_memory_or_cores_are_refused():
    with pytest.raises(ResourceError, match=r"--workers 100,000: more than 4 processes per core"):
        limits.check_workers(100_000)
    with pytest.raises(ResourceError, match=r"--workers 3: .*largest value that fits is 2"):
        limits.check_workers(3, memory=limits.WORKER_BYTES * 2)


# ------------------------------------------------------------------ training and evaluation held in memory

def test_train_in_memory_with_absurd_views_is_refused_before_rendering(tmp_path, capsys, monkeypatch):
    from hbeo.render import renderset
    monkeypatch.setattr(renderset, "render_set", lambda *a, **k: pytest.fail("rendering started"))
    code = main(["train", "--profile", "ci", "--views", "10000000", "--data", "memory", "--out",
                 str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: --views 1.0e7: 6.0e8 80x60 training images") and "held in memory" in err and "--data shards" in err


def test_train_with_an_absurd_fc_is_refused_before_the_network_is_built(tmp_path, capsys, monkeypatch):
    from hbeo.model import network
    from hbeo.render import renderset
    monkeypatch.setattr(renderset, "render_set", lambda *a, **k: pytest.fail("rendering started"))
    monkeypatch.setattr(network.HBEONet, "__init__", lambda *a, **k: pytest.fail("network allocated"))
    code = main(["train", "--profile", "ci", "--fc", "1000000000,1,1", "--out", str(tmp_path / "run"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith("error: --fc 1000000000,1,1: HBEONet would have ") and "80x60 input" in err, err
    assert "of memory" in err and "the largest W1 that fits (the other widths as given) is " in err, err
    assert not any((tmp_path / "run").rglob("*"))                 # nothing made: no grids, renders, checkpoint


@pytest.mark.parametrize("kw", [dict(), dict(rotation="bins", rotation_bins=64, kernel=3, image_size=(81, 59)),
                                dict(rotation="6d", dropout=0.1, fc=(7, 5, 3), n_coeffs=11)])
def test_network_params_counts_what_hbeonet_allocates(kw):
    from hbeo.model.network import HBEONet, NetConfig, network_params
    cfg = NetConfig(**{"image_size": (32, 24), "n_classes": 3, "n_coeffs": 4, "conv_channels": (4, 4, 8, 8),
                       "fc": (16, 8, 8), **kw})
    assert network_params(cfg) == HBEONet(cfg).n_params()


def test_network_check_names_the_largest_width_that_fits():
    from hbeo.model.network import NetConfig, check_network, network_params
    cfg = NetConfig(image_size=(80, 60), n_classes=10, n_coeffs=1, fc=(10 ** 6, 256, 256))
    with pytest.raises(ResourceError, match=r"^--fc 1000000,256,256: HBEONet would have [\d,]+ parameters at "
                                            r"80x60 input; .* 1.0 GB available; the largest W1 that fits .* is "
                                            r"([\d,]+)$") as e:
        check_network(cfg, memory=GB)
    fit = int(str(e.value).rsplit(" ", 1)[1].replace(",", ""))
    assert network_params(NetConfig(image_size=(80, 60), n_classes=10, n_coeffs=1, fc=(fit, 256, 256))) \
        * limits.TRAIN_BYTES_PER_PARAM <= GB * limits.MEMORY_FRACTION          # what it said fits, fits
    check_network(NetConfig(image_size=(80, 60), n_classes=10, n_coeffs=1, fc=(fit, 256, 256)), memory=GB)
    with pytest.raises(ResourceError, match=r"the largest W1 that fits"):
        check_network(NetConfig(image_size=(80, 60), n_classes=10, n_coeffs=1, fc=(fit + 1, 256, 256)), memory=GB)
    with pytest.raises(ResourceError, match="does not fit even with W3 = 1"):
        check_network(NetConfig(image_size=(80, 60), fc=(1, 10 ** 9, 10 ** 9)), memory=GB)

def test_in_memory_estimate_names_the_largest_views_that_fit():
    with pytest.raises(ResourceError, match=r"largest value that fits is 862, or use --data shards"):
        limits.check_in_memory(60 * 10 ** 6, (80, 60), per=60, memory=GB)
    limits.check_in_memory(60 * 862, (80, 60), per=60, memory=GB)
    with pytest.raises(ResourceError, match="index"):
        limits.check_in_memory(10 ** 11, (80, 60), source="stream", memory=GB)


def test_evaluation_views_are_refused_above_memory():
    with pytest.raises(ResourceError, match=r"--views 1.0e8: .*query views of 30 objects.*--per-class"):
        limits.check_evaluation(30, 10 ** 8, 1, (80, 60), memory=16 * GB)
    limits.check_evaluation(30, 100, 1, (80, 60), memory=16 * GB)


def test_available_memory_respects_the_address_space_limit():
    import resource
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    assert 0 < limits.available_memory()
    resource.setrlimit(resource.RLIMIT_AS, (3 * GB, hard))
    try:
        assert limits.available_memory() <= 3 * GB
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
