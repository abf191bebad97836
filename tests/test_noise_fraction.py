"""Sensor noise on a share of the training views (``RenderSettings.noise_fraction``, ``train --noise-fraction``):
each object's first views carry the noise as ``noise`` and ``noise_scale`` say, the rest are the clean set's views."""
from dataclasses import replace

import numpy as np
import pytest

from hbeo import config
from hbeo.data import datasets
from hbeo.render.noise import check_noise_fraction
from hbeo.render.views import ObjectViews, RenderSettings, object_rng


@pytest.fixture(scope="module")
def grids(tmp_path_factory):
    from test_streaming import _tiny_vox30
    path = _tiny_vox30(tmp_path_factory.mktemp("fraction") / "tiny.npz")
    ds = datasets.get_dataset("modelnet10-vox30", path=path)
    return ds, RenderSettings.from_profile(config.get_profile("ci"), backend="torch", views_per_object=4)


def test_the_setting_needs_noise_a_whole_number_of_views_and_is_left_out_at_one():
    rs = RenderSettings(noise=True, views_per_object=4)
    assert rs.noise_fraction == 1 and "noise_fraction" not in rs.to_dict() and rs.noisy_views == 4
    half = replace(rs, noise_fraction=0.5)
    assert half.noisy_views == 2 and half.to_dict()["noise_fraction"] == 0.5
    assert RenderSettings.from_dict(half.to_dict()) == half
    assert RenderSettings(views_per_object=4).noisy_views == 0
    # query views are clean or all noisy, whatever share of the training views carried it
    q = RenderSettings.for_queries(half.to_dict(), views=3, seed=0, noise=True)
    assert q.noise_fraction == 1 and q.noisy_views == 3
    assert RenderSettings.for_queries(half.to_dict(), views=3, seed=0).noisy_views == 0
    with pytest.raises(ValueError, match="noise_fraction 0.5 needs noise"):
        RenderSettings(views_per_object=4, noise_fraction=0.5)
    for bad, says in ((0.3, "1.2 views"), (0.1, "0.4 views"), (0.0, r"in \(0, 1\]"), (1.5, r"in \(0, 1\]"),
                      (float("nan"), r"in \(0, 1\]")):
        with pytest.raises(ValueError, match=says):
            RenderSettings(noise=True, views_per_object=4, noise_fraction=bad)
    check_noise_fraction(True, 0.25, 20)
    for noise, f, views, says in ((False, 0.5, 20, "needs --noise"), (True, 0.33, 20, "6.6 views"),
                                  (True, 0.5, 1, "0.5 views"), (True, 0.0, 20, r"in \(0, 1\]")):
        with pytest.raises(ValueError, match=says):
            check_noise_fraction(noise, f, views)


@pytest.mark.parametrize("scale", [1, 2])
def test_the_first_views_carry_the_noise_and_the_rest_are_the_clean_set_s(grids, scale):
    """The noisy views are those rendered at the sensor's size with the noise drawn from the object's stream after
    its poses; the clean ones are bit for bit the views a clean set with the same seed holds."""
    ds, rs = grids
    mixed = replace(rs, noise=True, noise_scale=scale, noise_fraction=0.5)
    views, clean = ObjectViews(mixed), ObjectViews(rs)
    sensor = ObjectViews(replace(rs, noise=True, noise_scale=scale))
    n_noisy_pixels = 0
    for p, r in enumerate(ds.records(split="train")[:3]):
        a, c = views.views(r, p, 0, "train"), clean.views(r, p, 0, "train")
        assert a["depth"].shape == c["depth"].shape == (4, rs.image_size[1], rs.image_size[0])
        assert np.array_equal(a["rotation"], c["rotation"]) and np.array_equal(a["translation"], c["translation"])
        assert np.array_equal(a["depth"][2:], c["depth"][2:])
        # the reference: poses from the object's stream, views 0 and 1 at the sensor's size, then the noise
        g = object_rng(rs.seed, "train", p)
        R, t = rs.view_sampler.sample(4, g)
        depth = sensor._depth(r, R[:2], t[:2])
        want = sensor.noise.apply(depth, sensor.sensor, g)[:, scale // 2::scale, scale // 2::scale]
        want = np.nan_to_num(want, nan=0.0).astype(np.float16)
        want[~(want > 0)] = 0
        assert np.array_equal(a["depth"][:2], want)
        n_noisy_pixels += int((a["depth"][:2] != c["depth"][:2]).sum())
    views.close()
    assert n_noisy_pixels > 20                               # the noise did change the first views
