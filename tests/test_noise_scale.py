"""Sensor noise at a finer sensor (``RenderSettings.noise_scale``, ``evaluate --noise-scale``): each view is rendered
at S times the image's size, the noise applied there, and the image read at the sensor pixel nearest each pixel's
centre, as ``predict`` reads a finer frame."""
import json
from dataclasses import replace

import numpy as np
import pytest

from hbeo import config
from hbeo.data import datasets
from hbeo.render.noise import MAX_NOISE_SCALE, SensorNoise
from hbeo.render.views import ObjectViews, RenderSettings


@pytest.fixture(scope="module")
def grids(tmp_path_factory):
    from test_streaming import _tiny_vox30
    path = _tiny_vox30(tmp_path_factory.mktemp("scale") / "tiny.npz")
    ds = datasets.get_dataset("modelnet10-vox30", path=path)
    return ds, RenderSettings.from_profile(config.get_profile("ci"), backend="torch")


def test_the_setting_needs_noise_is_bounded_and_is_left_out_of_the_settings_at_one():
    rs = RenderSettings(noise=True)
    assert rs.noise_scale == 1 and "noise_scale" not in rs.to_dict()      # sets made before it keep their identity
    assert RenderSettings.from_dict(rs.to_dict()) == rs
    s8 = replace(rs, noise_scale=8)
    assert s8.to_dict()["noise_scale"] == 8 and RenderSettings.from_dict(s8.to_dict()) == s8
    K, Ks = s8.intrinsics, s8.sensor_intrinsics
    assert (Ks.width, Ks.height) == (8 * K.width, 8 * K.height) and Ks.fx == 8 * K.fx
    assert RenderSettings().sensor_intrinsics == RenderSettings().intrinsics
    with pytest.raises(ValueError, match="noise_scale 2 needs noise"):
        RenderSettings(noise_scale=2)
    for bad in (0, MAX_NOISE_SCALE + 1, 1.5):
        with pytest.raises(ValueError, match="noise_scale"):
            RenderSettings(noise=True, noise_scale=bad)


def test_a_view_read_from_a_finer_sensor_is_the_image_s_own_view_when_the_noise_does_nothing(grids):
    """At an odd scale the sensor pixel s*u + s//2 lies on image pixel u's ray: with every part of the noise off,
    the view read from the 3-times finer sensor is the view rendered at the image's size (float16 depth)."""
    ds, rs = grids
    recs = ds.records(split="test")[:4]
    clean = ObjectViews(replace(rs, views_per_object=2))
    fine = ObjectViews(replace(rs, views_per_object=2, noise=True, noise_scale=3))
    fine.noise = SensorNoise(sigma_a=0, sigma_b=0, disparity_step=0, grazing_deg=90, edge_p=0, seg_px=0)
    n_pixels = 0
    for r in recs:
        a, b = clean.query_views(r, "test", 2), fine.query_views(r, "test", 2)
        assert a["depth"].shape == b["depth"].shape == (2, rs.image_size[1], rs.image_size[0])
        assert np.array_equal(a["rotation"], b["rotation"]) and np.array_equal(a["translation"], b["translation"])
        da, db = a["depth"].astype(np.float32), b["depth"].astype(np.float32)
        both = (da > 0) & (db > 0)
        assert (da > 0).sum() > 0 and ((da > 0) != (db > 0)).sum() <= 2            # a silhouette pixel at most
        assert np.abs(da[both] - db[both]).max() <= 2e-3                            # float16 steps near 2 m
        n_pixels += both.sum()
    assert n_pixels > 100


def test_noise_at_a_finer_sensor_is_deterministic_and_spares_a_small_object_s_pixels(grids):
    ds, rs = grids
    r = ds.records(split="test")[0]
    coarse = ObjectViews(replace(rs, noise=True)).query_views(r, "test", 3)
    fine = ObjectViews(replace(rs, noise=True, noise_scale=4)).query_views(r, "test", 3)
    again = ObjectViews(replace(rs, noise=True, noise_scale=4)).query_views(r, "test", 3)
    assert np.array_equal(fine["depth"], again["depth"]) and not np.array_equal(fine["depth"], coarse["depth"])
    clean = ObjectViews(rs).query_views(r, "test", 3)["depth"] > 0
    # the noise's pixel-sized parts (silhouette dropout, segmentation error) shrink with the sensor's pixels
    lost = {k: abs(int((v["depth"] > 0).sum()) - int(clean.sum())) for k, v in (("fine", fine), ("coarse", coarse))}
    assert lost["fine"] < lost["coarse"]


def test_streamed_batches_refuse_a_finer_sensor(grids):
    from hbeo.render.torch_datasets import FreshPoses
    ds, rs = grids
    fp = FreshPoses(ds, ds.records(split="train")[:3], "train", replace(rs, noise=True, noise_scale=2), None)
    with pytest.raises(ValueError, match="noise_scale 2 is for views rendered one object at a time"):
        fp.render_batch([0, 1])


@pytest.mark.slow
def test_evaluate_noise_scale_is_recorded_and_needs_noise(ci_model, copy_run, tmp_path, capsys):
    from hbeo import cli
    rd = copy_run(ci_model.parent, tmp_path / "run")
    args = ["evaluate", "--model", str(rd.model), "--dataset", "procedural", "--split", "val", "--quiet"]
    assert cli.main([*args, "--noise-scale", "2", "--out", str(tmp_path / "a.json")]) == 2
    assert "--noise-scale 2 says where the sensor noise is applied: it needs --noise" in capsys.readouterr().err
    assert not (tmp_path / "a.json").exists()
    assert cli.main([*args, "--noise", "--noise-scale", "17", "--out", str(tmp_path / "a.json")]) == 2
    assert "at most 16" in capsys.readouterr().err
    assert cli.main([*args, "--noise", "--noise-scale", "2", "--out", str(tmp_path / "a.json")]) == 0
    assert cli.main([*args, "--noise", "--out", str(tmp_path / "b.json")]) == 0
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    assert a["noise"] and a["noise_scale"] == 2 and b["noise"] and "noise_scale" not in b
    from hbeo.report.model_table import unpaired
    assert "noise_scale" in (unpaired(a, b) or "")                    # not the same queries: never paired
    import pandas as pd
    log = pd.read_csv(rd.validation_log)
    assert list(log.noise_scale) == [2, 1]
