import numpy as np
import pytest
import torch

from hbeo.model.network import (HBEONet, LossWeights, NetConfig, hbeo_loss,
                      bin_cosines, bin_targets, normalize_depth, pose_to_matrix)
from hbeo.rotations import (axis_angle_to_matrix, geodesic_deg, matrix_to_axis_angle, matrix_to_sixd,
                            sixd_to_matrix, uniform_so3)


def test_paper_sized_network_has_about_15m_parameters_and_right_heads():
    net = HBEONet(NetConfig())
    assert 14e6 < net.n_params() < 17e6
    out = net(torch.rand(2, 1, 240, 320))
    assert out["logits"].shape == (2, 10) and out["pose"].shape == (2, 3) and out["coeffs"].shape == (2, 344)
    convs = [m for m in net.features if isinstance(m, torch.nn.Conv2d)]
    assert len(convs) == 4 and all(c.stride == (2, 2) for c in convs)
    assert not any(isinstance(m, (torch.nn.MaxPool2d, torch.nn.AvgPool2d)) for m in net.modules())


def test_rotation_conversions_used_by_the_pose_heads():
    R = uniform_so3(50, np.random.default_rng(0))
    v = torch.tensor(matrix_to_axis_angle(R))
    assert torch.allclose(axis_angle_to_matrix(v), torch.tensor(R), atol=1e-9)
    Rt = torch.tensor(R)
    assert torch.allclose(sixd_to_matrix(matrix_to_sixd(Rt)), Rt, atol=1e-9)
    noisy = matrix_to_sixd(Rt) + 0.1 * torch.randn(50, 6, dtype=torch.float64)
    M = pose_to_matrix(noisy, "6d")
    assert torch.allclose(M @ M.transpose(1, 2), torch.eye(3, dtype=torch.float64).expand(50, 3, 3), atol=1e-9)
    assert torch.allclose(torch.det(M), torch.ones(50, dtype=torch.float64))


def test_loss_is_zero_at_the_truth_and_weights_apply():
    cfg = NetConfig(image_size=(32, 24), n_classes=3, n_coeffs=4, conv_channels=(4, 4, 4, 4), fc=(8, 8, 8))
    R = torch.tensor(uniform_so3(2, np.random.default_rng(1)), dtype=torch.float32)
    batch = {"label": torch.tensor([0, 2]), "rotation": R,
             "axis_angle": torch.tensor(matrix_to_axis_angle(R.numpy()), dtype=torch.float32),
             "coeffs": torch.randn(2, 4)}
    perfect = {"logits": torch.tensor([[50.0, 0, 0], [0, 0, 50.0]]), "pose": batch["axis_angle"],
               "coeffs": batch["coeffs"]}
    total, parts = hbeo_loss(perfect, batch, cfg)
    assert total.item() < 1e-6
    off = dict(perfect, coeffs=batch["coeffs"] + 1.0)
    t1, _ = hbeo_loss(off, batch, cfg, LossWeights(coeffs=1.0))
    t3, _ = hbeo_loss(off, batch, cfg, LossWeights(coeffs=3.0))
    assert t1.item() == pytest.approx(2.0, rel=1e-4) and t3.item() == pytest.approx(6.0, rel=1e-4)


def test_center_normalization_removes_the_depth_offset():
    d = torch.zeros(1, 1, 10, 10)
    d[..., 3:7, 3:7] = 1.5 + 0.01 * torch.arange(4.0)
    far = torch.where(d > 0, d + 2.0, d)
    assert torch.allclose(normalize_depth(d, "center"), normalize_depth(far, "center"), atol=1e-6)
    assert torch.equal(normalize_depth(d, "none"), d)
    assert (normalize_depth(d, "center")[d == 0] == 0).all()


def test_bad_configs():
    with pytest.raises(ValueError, match="rotation"):
        NetConfig(rotation="euler")
    with pytest.raises(ValueError, match="four convolutions"):
        NetConfig(conv_channels=(8, 8))


def _log_target(R, grid, sigma_deg=10.0):
    """Logits whose softmax is bin_targets(R, grid, sigma_deg)."""
    return -0.5 * (torch.acos(bin_cosines(R, grid)) / np.radians(sigma_deg)) ** 2


def _tiny(**kw):
    return NetConfig(image_size=(32, 24), n_classes=3, n_coeffs=4, conv_channels=(4, 4, 4, 4), fc=(8, 8, 8), **kw)


def test_bins_decode_a_peaked_distribution_to_its_rotation_off_the_grid():
    net = HBEONet(_tiny(rotation="bins", rotation_bins=2048, bin_sigma_deg=10.0))
    grid = net.bin_rotations.double()
    R = torch.tensor(uniform_so3(20, np.random.default_rng(3)))
    # logits = log of the smoothed target: the decoded rotation must come back near R, closer than
    # the nearest grid rotation alone gets (the refinement works between bins)
    logits = _log_target(R, grid)
    M = net.pose_matrix(logits)
    err = geodesic_deg(M.numpy(), R.numpy())
    nearest = np.degrees(np.arccos(bin_cosines(R, grid).max(1).values.numpy()))
    assert err.max() < 3.0 and err.mean() < nearest.mean() / 3
    assert torch.allclose(M @ M.transpose(1, 2), torch.eye(3, dtype=M.dtype).expand(20, 3, 3), atol=1e-9)
    assert torch.allclose(torch.det(M), torch.ones(20, dtype=M.dtype))


def test_bins_keep_the_stronger_of_two_modes():
    net = HBEONet(_tiny(rotation="bins", rotation_bins=1024))
    grid = net.bin_rotations.double()
    R = torch.tensor(uniform_so3(1, np.random.default_rng(4)))
    flip = torch.tensor([[-1.0, 0, 0], [0, -1.0, 0], [0, 0, 1.0]], dtype=R.dtype)   # 180 deg about z
    t = 0.6 * bin_targets(R, grid, 10.0) + 0.4 * bin_targets(R @ flip, grid, 10.0)
    M = net.pose_matrix(torch.log(t))
    assert geodesic_deg(M.numpy(), R.numpy())[0] < 6.0   # a regression would land ~90 deg from both


def test_bins_loss_is_lowest_at_the_truth_and_needs_the_grid():
    cfg = _tiny(rotation="bins", rotation_bins=512)
    net = HBEONet(cfg)
    R = torch.tensor(uniform_so3(4, np.random.default_rng(5)), dtype=torch.float32)
    batch = {"label": torch.tensor([0, 1, 2, 0]), "rotation": R, "coeffs": torch.zeros(4, 4)}
    base = {"logits": torch.zeros(4, 3), "coeffs": torch.zeros(4, 4)}
    good = dict(base, pose=_log_target(R, net.bin_rotations))
    wrong = dict(base, pose=_log_target(R.flip(0), net.bin_rotations))
    _, p_good = hbeo_loss(good, batch, cfg, grid=net.bin_rotations)
    _, p_wrong = hbeo_loss(wrong, batch, cfg, grid=net.bin_rotations)
    _, p_flat = hbeo_loss(dict(base, pose=torch.zeros(4, 512)), batch, cfg, grid=net.bin_rotations)
    assert p_good["pose"] < p_flat["pose"] < p_wrong["pose"]
    assert p_flat["pose"] == pytest.approx(np.log(512), rel=1e-4)
    with pytest.raises(ValueError, match="grid"):
        hbeo_loss(good, batch, cfg)
    with pytest.raises(ValueError, match="pose_matrix"):
        pose_to_matrix(good["pose"], "bins")
    assert net(torch.rand(2, 1, 24, 32))["pose"].shape == (2, 512)
    assert "bin_rotations" not in net.state_dict()


def test_voxel_shape_loss_is_the_occupancy_error_through_the_orthonormal_basis():
    """``--shape-loss voxels``: the coefficient term is ||W (c_hat - c)|| on raw coefficients (W orthonormal),
    divided by rms(std); the paper's loss keeps its configuration (no shape_loss key)."""
    from hbeo.model.fit import HBEONetTask
    torch.manual_seed(0)
    cfg = NetConfig(image_size=(32, 24), n_classes=3, n_coeffs=5, conv_channels=(4, 4, 4, 4), fc=(8, 8, 8), kernel=3)
    std = np.array([4.0, 2.0, 1.0, 0.5, 0.1], np.float32)
    W, _ = np.linalg.qr(np.random.default_rng(0).normal(size=(40, 5)))            # orthonormal basis
    net = HBEONet(cfg)
    batch = {"depth": torch.rand(6, 1, 24, 32), "label": torch.randint(0, 3, (6,)),
             "axis_angle": torch.zeros(6, 3), "rotation": torch.eye(3).repeat(6, 1, 1), "coeffs": torch.randn(6, 5)}
    _, paper = HBEONetTask(cfg).loss(net, batch)
    _, vox = HBEONetTask(cfg, coeff_std=std).loss(net, batch)
    with torch.no_grad():
        dz = (net(batch["depth"])["coeffs"] - batch["coeffs"]).numpy()
    grid_err = np.linalg.norm((dz * std) @ W.T, axis=1)                            # occupancy error, voxel space
    assert vox["coeff"] == pytest.approx(float(np.mean(grid_err) / np.sqrt(np.mean(std ** 2))), rel=1e-5)
    assert paper["coeff"] == pytest.approx(float(np.linalg.norm(dz, axis=1).mean()), rel=1e-5)
    assert "shape_loss" not in HBEONetTask(cfg).config()
    assert HBEONetTask(cfg, coeff_std=std).config()["shape_loss"] == "voxels"
