"""Predict -> verify (hbeo.model.verify) and the masked projection it shares with BEO
(hbeo.subspace.projection): MAP with a prior, rotation modes, translation refinement, and the
verify step on a rendered view at its true pose."""
import numpy as np
import pytest
import torch

from hbeo.model.verify import Verifier, VerifyConfig, align_translation, rotation_modes
from hbeo.rotations import geodesic_deg, super_fibonacci, z_angle_to_matrix
from hbeo.subspace.projection import MaskedProjector


def _basis(d=200, k=6, seed=0):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(d - 20, k)))
    return np.concatenate([np.zeros((20, k)), q]).astype(np.float32)   # 20 rows no training object reaches


def test_masked_projection_solves_the_map_normal_equations():
    W = _basis()
    rng = np.random.default_rng(1)
    filled, known = rng.random((3, 200)) < 0.2, rng.random((3, 200)) < 0.5
    known |= filled
    known[2] = rng.random(200) < 0.9                           # more known than unknown: the other branch
    filled[2] &= known[2]
    P, mu = np.linspace(0.5, 2.0, 6), rng.normal(size=6)
    o, sse = MaskedProjector(W).project(filled, known, precision=P, prior_mean=mu)
    Wd = W.astype(np.float64)
    for i in range(3):
        Wk, w = Wd[known[i]], filled[i][known[i]].astype(float)
        want = np.linalg.solve(Wk.T @ Wk + np.diag(P), Wk.T @ w + P * mu)
        np.testing.assert_allclose(o[i], want, rtol=1e-5, atol=1e-6)
        np.testing.assert_allclose(sse[i], np.sum((Wk @ o[i] - w) ** 2), rtol=1e-5, atol=1e-6)
    # a scalar ridge without a prior mean is BEO's partial projection
    o0, _ = MaskedProjector(W).project(filled, known, precision=1e-3)
    Wk, w = Wd[known[0]], filled[0][known[0]].astype(float)
    np.testing.assert_allclose(o0[0], np.linalg.solve(Wk.T @ Wk + 1e-3 * np.eye(6), Wk.T @ w), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="must both be"):
        MaskedProjector(W).project(filled[:, :10], known[:, :10])


def test_rotation_modes_find_two_separated_peaks_with_their_mass():
    grid = super_fibonacci(4096)
    R1, R2 = grid[10], grid[10] @ z_angle_to_matrix(np.pi)    # a front/back flip
    cos = lambda R: (np.einsum("ij,nij->n", R, grid) - 1) / 2
    logits = 40 * np.maximum(cos(R1), cos(R2) - 0.05)          # the flip a bit less likely
    p = torch.softmax(torch.tensor(logits), 0).numpy()
    Rs, mass = rotation_modes(p, grid, 4, 40.0)
    assert geodesic_deg(Rs[0], R1) < 5 and geodesic_deg(Rs[1], R2) < 5
    assert mass[0] > mass[1] > mass[2:].max(initial=0) and mass.sum() <= 1 + 1e-9


def test_translation_alignment_moves_a_shifted_shape_back_onto_the_depth():
    from hbeo.conventions import Intrinsics
    from hbeo.model.verify import shape_depth, surface_points
    shape = np.zeros((30, 30, 30), bool)
    shape[6:24, 9:21, 3:27] = True                              # a box, 1 m = 24 voxels
    K = Intrinsics(65.6, 65.6, 39.5, 29.5, 80, 60)
    R = z_angle_to_matrix(0.6) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    t_true = np.array([0.1, -0.05, 1.8])
    pts = surface_points(shape, 1.0)
    depth = shape_depth(pts, R, t_true, K)
    assert (depth > 0).sum() > 200 and depth[depth > 0].min() > 1.2
    for off in ([0.06, -0.04, 0.15], [-0.05, 0.05, -0.2]):
        start = t_true + np.array(off)
        t = align_translation(depth, R, start, pts, K)
        assert np.linalg.norm(t - t_true) < 0.1 * np.linalg.norm(start - t_true)
    # nothing observed: the start is kept
    assert np.linalg.norm(align_translation(np.zeros_like(depth), R, t_true, pts, K) - t_true) == 0


def test_verify_works_at_the_model_cameras_pixel_density():
    """A 640x480 frame is reduced to every 8th pixel (the 80x60 model camera's density): the kept pixels are the
    originals, with their own rays; the true shape at its true pose agrees with a hole-free frame of it there,
    where at full resolution its point splat leaves holes (and the back showing through them) that disagree."""
    from hbeo.conventions import Intrinsics, backproject
    from hbeo.model.verify import depth_agreement, shape_depth, surface_points, working_stride, working_view
    model_K, big = Intrinsics.kinect(80, 60), Intrinsics(525.0, 530.0, 321.3, 238.7, 640, 480)
    assert working_stride(big, model_K) == 8 and working_stride(model_K, model_K) == 1
    assert working_stride(Intrinsics(1050.0, 525.0, 320, 240, 640, 480), model_K) == 8       # the smaller ratio
    assert working_stride(Intrinsics.kinect(40, 30), model_K) == 1                          # coarser: 1
    depth = np.zeros((480, 640))
    depth[100:400, 150:500] = 1.7 + 0.001 * np.arange(350)         # any values: which pixels are kept
    d, K = working_view(depth, big, model_K)
    assert d.shape == (60, 80) and (K.width, K.height) == (80, 60)
    np.testing.assert_array_equal(d, depth[4::8, 4::8])
    keep = np.zeros_like(depth)
    keep[4::8, 4::8] = depth[4::8, 4::8]
    np.testing.assert_allclose(backproject(d, K)[0], backproject(keep, big)[0], rtol=0, atol=1e-12)  # same rays
    assert working_view(depth, model_K, model_K)[1] is model_K                 # the model's camera: unchanged
    assert working_view(depth[::8, ::8], Intrinsics.kinect(80, 60), model_K)[1] == model_K
    shape = np.zeros((30, 30, 30), bool)
    shape[6:24, 9:21, 3:27] = True
    pts = surface_points(shape, 1.0)
    R = z_angle_to_matrix(0.6) @ np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]], float)
    t, tol = np.array([0.2, -0.1, 1.7]), 2.0 / 30
    seen = shape_depth(_dense_points(shape), R, t, big)                      # a sensor's frame: no holes
    seen_small, Ks = working_view(seen, big, model_K)
    assert depth_agreement(seen_small, shape_depth(pts, R, t, Ks), tol) > 0.8
    assert depth_agreement(seen, shape_depth(pts, R, t, big), tol) < 0.5     # what verify saw before


def _dense_points(shape, n=8):
    """A shape's surface voxels as n^3 points each (object frame, metres, object_size 1): dense enough that a
    640x480 view at 1.7 m has no holes, as a sensor's frame of the surface."""
    from scipy import ndimage
    from hbeo.conventions import OBJECT_VOXELS
    surf = np.argwhere(shape & ~ndimage.binary_erosion(shape)).astype(np.float64)
    g = (np.arange(n) + 0.5) / n - 0.5
    sub = np.stack(np.meshgrid(g, g, g, indexing="ij"), -1).reshape(-1, 3)
    return ((surf[:, None] + 0.5 + sub[None]).reshape(-1, 3) - shape.shape[0] / 2) / OBJECT_VOXELS


@pytest.fixture(scope="module")
def model_and_view(ci_model, ci_grids):
    from dataclasses import replace
    from hbeo.data import datasets
    from hbeo.model.inference import HBEO
    from hbeo.render.views import ObjectViews, RenderSettings
    from hbeo import config
    model = HBEO.load(ci_model)
    ds = datasets.get_dataset("procedural", profile=config.get_profile("ci"))
    rec = ds.records(split="test")[0]
    rs = replace(RenderSettings.from_dict(model.settings.render), views_per_object=1)
    views = ObjectViews(rs)
    try:
        arrays = views.views(rec, 0, ds.classes.index(rec.cls), "test", 0)
    finally:
        views.close()
    return model, arrays, rec


def test_verify_at_the_true_pose_completes_better_than_the_network_alone(model_and_view):
    from dataclasses import replace
    from hbeo.data.gridset import record_grid
    from hbeo.subspace.metrics import iou
    model, a, rec = model_and_view
    d = a["depth"][0].astype(np.float32)
    pred = model.predict(d, model.intrinsics)
    truth = record_grid(rec)
    at_truth = replace(pred, rotation=a["rotation"][:1].astype(np.float64),
                       translation=a["translation"][:1].astype(np.float64))
    out = Verifier(model, VerifyConfig(classes=3, rotations=1, class_weight=0.0, refine_translation=False)).verify(
        d, model.intrinsics, at_truth)
    assert iou(truth, out["grid"]) > iou(truth, pred.grids[0]) + 0.1
    assert out["n_hypotheses"] == 3 and out["probabilities"].sum() == pytest.approx(1.0)
    # a regression head's modes: the regressed rotation and its turns about the up axis
    v = Verifier(model, VerifyConfig(rotations=4))
    Rs, logw = v.hypotheses_rotations(pred, 0)
    assert len(Rs) == 4 and np.allclose(logw, 0)
    np.testing.assert_allclose(geodesic_deg(Rs[0], Rs[2]), 180, atol=1e-6)
    q = v.apply(d, model.intrinsics, pred)
    assert q.grids.shape == pred.grids.shape and q.timing_ms["verify"] > 0      # verify is timed, in the total
    assert q.timing_ms["total"] == pytest.approx(pred.timing_ms["total"] + q.timing_ms["verify"])
    # one class tried: the network's class and probabilities stand; an unmeetable agreement keeps HBEO's answer
    one = Verifier(model, VerifyConfig(classes=1, min_agreement=0)).verify(d, model.intrinsics, pred)
    assert one["label"] == pred.labels[0] and np.allclose(one["probabilities"], pred.probabilities[0])
    assert 0 <= one["agreement"] <= 1 and not one["kept_network"] and one["stride"] == 1
    K = model.intrinsics                               # the same frame at twice the resolution: stride 2
    K2 = type(K)(2 * K.fx, 2 * K.fy, 2 * K.cx + 0.5, 2 * K.cy + 0.5, 2 * K.width, 2 * K.height)
    assert Verifier(model, VerifyConfig(classes=1)).verify(d.repeat(2, 0).repeat(2, 1), K2, pred)["stride"] == 2
    kept = Verifier(model, VerifyConfig(classes=1, min_agreement=1.01)).verify(d, model.intrinsics, pred)
    assert kept["kept_network"] and np.array_equal(kept["grid"], pred.grids[0])
    assert np.array_equal(kept["rotation"], pred.rotation[0])


def test_evaluate_with_verify_reports_its_settings_and_refuses_baselines(model_and_view):
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.evaluation.evaluate import evaluate_model
    model = model_and_view[0]
    ds = datasets.get_dataset("procedural", profile=config.get_profile("ci"))
    plain = evaluate_model(model, ds, per_class=1, progress=False)
    out = evaluate_model(model, ds, per_class=1, progress=False, verify=VerifyConfig())
    assert plain["verify"] is None and out["verify"] == VerifyConfig().to_dict()
    assert out["n_queries"] == plain["n_queries"] == 10
    with pytest.raises(ValueError, match="verify applies to HBEO"):
        evaluate_model(model, ds, per_class=1, progress=False, verify=VerifyConfig(), method=object())


def test_verify_settings_parse_from_the_command_line_text():
    assert VerifyConfig.parse(None) == VerifyConfig() == VerifyConfig.parse("")
    cfg = VerifyConfig.parse("classes=1, noise-var=2,refine_translation=off")
    assert (cfg.classes, cfg.noise_var, cfg.refine_translation) == (1, 2.0, False)
    for bad, msg in (("foo=1", "key one of"), ("classes", "key one of"), ("classes=x", "not a int"),
                     ("rotations=0", "out of range"), ("refine_translation=maybe", "not a bool")):
        with pytest.raises(ValueError, match=msg):
            VerifyConfig.parse(bad)
