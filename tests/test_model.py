import json
import zipfile

import numpy as np
import pytest
import torch

from hbeo.conventions import Intrinsics
from hbeo.errors import DataError
from hbeo.model.inference import HBEO
from hbeo.model.network import HBEONet, NetConfig


N_CLASSES = 10                                 #: the ci run's classes (ModelNet10's)


@pytest.fixture(scope="module")
def model(ci_grids, ci_subspace, tiny_model):
    """conftest's untrained tiny model with the ci run's subspace and classes, its mean-shape
    coefficient non-empty."""
    gs = ci_grids["train"]
    assert len(gs.classes) == N_CLASSES
    return tiny_model({"ref_distance": 1.7}, classes=gs.classes, subspace=ci_subspace, mean_grids=gs.grids)


def blob_depth(K, z=1.7):
    d = np.zeros((K.height, K.width))
    d[K.height // 3: 2 * K.height // 3, K.width // 3: 2 * K.width // 3] = z
    return d


def test_predict_shapes_and_frames(model):
    K_user = Intrinsics(500.0, 500.0, 300.0, 220.0, 640, 480)
    p = model.predict(np.stack([blob_depth(K_user), blob_depth(K_user, 2.5)]), K_user)
    assert p.probabilities.shape == (2, N_CLASSES) and np.allclose(p.probabilities.sum(1), 1)
    assert p.rotation.shape == (2, 3, 3) and np.allclose(p.rotation @ p.rotation.transpose(0, 2, 1), np.eye(3), atol=1e-6)
    assert p.grids.shape == (2, 30, 30, 30) and p.grids.dtype == bool
    assert p.translation[1, 2] > p.translation[0, 2] and p.scale[1] > p.scale[0]
    d = p.to_dict(0)
    assert set(d) >= {"class", "probabilities", "rotation", "axis_angle", "coeffs", "timing_ms"}
    assert p.timing_ms["total"] > 0


def test_save_load_round_trip(model, tmp_path):
    path = model.save(tmp_path / "m.hbeo")
    back = HBEO.load(path)
    K = Intrinsics.kinect(64, 48)
    a, b = model.predict(blob_depth(K), K), back.predict(blob_depth(K), K)
    assert np.allclose(a.probabilities, b.probabilities) and np.array_equal(a.grids, b.grids)
    assert back.classes == model.classes and back.settings.ref_distance == 1.7


def test_bad_model_files(tmp_path):
    with pytest.raises(DataError, match="no such model file"):
        HBEO.load(tmp_path / "none.hbeo")
    (tmp_path / "junk.hbeo").write_bytes(b"junk")
    with pytest.raises(DataError, match=r"junk\.hbeo: not a readable hbeo model file"):
        HBEO.load(tmp_path / "junk.hbeo")
    with zipfile.ZipFile(tmp_path / "new.hbeo", "w") as z:       # a later format (hbeo.model.modelfile)
        z.writestr("meta.json", json.dumps({"format": "hbeo-model", "format_version": 99}))
    with pytest.raises(DataError, match="model format 99"):
        HBEO.load(tmp_path / "new.hbeo")


def test_mismatched_parts_are_refused(model):
    with pytest.raises(ValueError, match="coefficients"):
        HBEO(HBEONet(NetConfig(image_size=(32, 24), n_classes=N_CLASSES, n_coeffs=3, conv_channels=(4, 4, 4, 4),
                               fc=(8, 8, 8))), model.subspace, model.intrinsics, model.classes)


def test_to_mesh_places_the_completed_shape_in_the_camera_frame(model):
    K = Intrinsics.kinect(64, 48)
    p = model.predict(blob_depth(K, 1.8), K)
    assert p.grids[0].any()
    mesh = model.to_mesh(p)
    assert np.allclose(mesh.bounds.mean(0), p.translation[0], atol=0.35 * p.scale[0])
    assert mesh.extents.max() <= 1.2 * model.settings.object_size * p.scale[0]


def test_rotation_bins_model_round_trip(model, tmp_path):
    net = HBEONet(NetConfig(image_size=(32, 24), n_classes=N_CLASSES, n_coeffs=model.subspace.dim_,
                            conv_channels=(4, 4, 4, 4), fc=(8, 8, 8), rotation="bins", rotation_bins=256))
    m = HBEO(net, model.subspace, model.intrinsics, model.classes, model.settings)
    back = HBEO.load(m.save(tmp_path / "bins.hbeo"))
    K = Intrinsics.kinect(64, 48)
    a, b = m.predict(blob_depth(K), K), back.predict(blob_depth(K), K)
    assert np.allclose(a.rotation, b.rotation) and back.net.cfg.rotation == "bins"
    assert np.allclose(a.rotation[0] @ a.rotation[0].T, np.eye(3), atol=1e-6)


def test_bfloat16_inference_stays_close_and_saves_float32(model, tmp_path):
    K = Intrinsics.kinect(64, 48)
    a = model.predict(blob_depth(K), K)
    fast = HBEO.load(model.save(tmp_path / "m.hbeo"), precision="bfloat16")
    assert fast._net.coeff_head.weight.dtype == torch.bfloat16 and fast.net.coeff_head.weight.dtype == torch.float32
    b = fast.predict(blob_depth(K), K)
    assert b.probabilities.dtype == a.probabilities.dtype and np.allclose(a.probabilities, b.probabilities, atol=0.02)
    assert np.allclose(a.coeffs, b.coeffs, atol=0.05 * np.abs(a.coeffs).max() + 1e-3)
    back = HBEO.load(fast.save(tmp_path / "again.hbeo"))          # the float32 weights, unrounded
    assert back.net.coeff_head.weight.dtype == torch.float32
    assert np.allclose(back.predict(blob_depth(K), K).probabilities, a.probabilities, atol=1e-6)
    with pytest.raises(ValueError, match="precision"):
        model.set_precision("float16")


class _RollReader(torch.nn.Module):
    """Stands in for a trained bins network: finds the direction from a bar's centre to its far tip
    (the pixels at 1.9 m) and puts its probability on Rz(angle) R0, i.e. it answers like an ideal
    network whose object is rolled by that angle. Class and coefficients are constant."""

    def __init__(self, net, R0):
        super().__init__()
        self.net, self.R0 = net, torch.tensor(R0)

    def forward(self, x):
        from hbeo.rotations import z_angle_to_matrix
        from hbeo.model.network import bin_targets
        d = x.float()[:, 0]
        H, W = d.shape[1:]
        v, u = torch.meshgrid(torch.arange(H) - (H - 1) / 2, torch.arange(W) - (W - 1) / 2, indexing="ij")
        Rs = []
        for img in d:
            m, tip = (img > 0).float(), (img > 1.8).float()
            cu, cv = (m * u).sum() / m.sum(), (m * v).sum() / m.sum()
            tu, tv = (tip * u).sum() / tip.sum(), (tip * v).sum() / tip.sum()
            a = float(torch.atan2(tv - cv, tu - cu))
            Rs.append(torch.tensor(z_angle_to_matrix(a), dtype=torch.float32) @ self.R0)
        pose = torch.log(bin_targets(torch.stack(Rs).float(), self.net.bin_rotations, 10.0) + 1e-30)
        B = len(d)
        return {"logits": torch.zeros(B, self.net.cfg.n_classes), "pose": pose,
                "coeffs": torch.zeros(B, self.net.cfg.n_coeffs)}


def _bins_model(model, n=2048):
    net = HBEONet(NetConfig(image_size=(32, 24), n_classes=N_CLASSES, n_coeffs=model.subspace.dim_,
                            conv_channels=(4, 4, 4, 4), fc=(8, 8, 8), rotation="bins", rotation_bins=n))
    return HBEO(net, model.subspace, model.intrinsics, model.classes, {"recenter": False})


def test_roll_permutation_finds_the_turned_bin(model):
    from hbeo.rotations import geodesic_deg, z_angle_to_matrix
    m = _bins_model(model)
    G = m.net.bin_rotations.double().numpy()
    for a in (0.7, 2.0 * np.pi / 3):
        turned = z_angle_to_matrix(a) @ G
        assert geodesic_deg(G[m._roll_permutation(a).numpy()], turned).max() < 15      # grid spacing ~17 deg
        assert np.median(geodesic_deg(G[m._roll_permutation(-a).numpy()], turned)) > 60   # the other way round


def test_roll_averaging_turns_each_rolls_distribution_back(model):
    from hbeo.rotations import geodesic_deg, uniform_so3
    m = _bins_model(model)
    R0 = uniform_so3(1, np.random.default_rng(7))[0].astype(np.float32)
    m._net = _RollReader(m.net, R0)
    K = model.intrinsics
    d = np.zeros((K.height, K.width))
    d[10:14, 6:26] = 1.7
    d[10:14, 22:26] = 1.9                          # the tip points along the image's x axis: angle 0
    want = R0.astype(np.float64)[None]
    for rolls in (1, 3, 4):
        p = m.predict(d, K, rolls=rolls)
        assert geodesic_deg(p.rotation, want)[0] < 8, rolls
        assert np.allclose(p.probabilities, 1 / N_CLASSES)     # constant logits: uniform
    with pytest.raises(ValueError, match="rotation-bins"):
        model.predict(d, K, rolls=2)
    with pytest.raises(ValueError, match="positive integer"):
        m.predict(d, K, rolls=0)


class _Lefty(torch.nn.Module):
    """A network whose class 0 grows with the object's share of pixels left of the image centre (an
    untrained net's classes barely respond to its input); the rest is the wrapped network's answer."""

    def __init__(self, net):
        super().__init__()
        self.net = net

    def forward(self, x):
        out = dict(self.net(x))
        filled = (x.float()[:, 0] > 0).float()
        half = filled.shape[-1] // 2
        logits = out["logits"].clone()
        logits[:, 0] += 20 * (filled[..., :half].mean((1, 2)) - filled[..., half:].mean((1, 2)))
        return {**out, "logits": logits}


def test_mirror_averages_the_class_over_the_mirrored_image_and_keeps_pose_and_shape(model):
    """set_mirror(True): class probabilities are the mean of the network's on each rolled input and on its
    left-right mirror; rotation, coefficients and completion are exactly those without mirror."""
    from hbeo.model.augment import mirror_depth
    m, K = _bins_seed(model, 3), model.intrinsics
    m._net = _Lefty(m.net)
    d = np.zeros((K.height, K.width))
    d[6:18, 4:14] = 1.7
    d[6:10, 14:28] = 1.9                            # an L: its mirror is another image
    for rolls in (1, 3):          # not 4: a left-right count like _Lefty's is the same after the 180-degree roll
        plain = m.set_mirror(False).predict(d, K, rolls=rolls)
        mir = m.set_mirror(True).predict(d, K, rolls=rolls)
        other = m.set_mirror(False).predict(mirror_depth(d, K), K, rolls=rolls)
        assert np.abs(plain.probabilities - other.probabilities).max() > 0.01   # the mirror is seen apart
        assert np.allclose(mir.probabilities, (plain.probabilities + other.probabilities) / 2, atol=1e-6), rolls
        assert np.array_equal(mir.rotation, plain.rotation) and np.array_equal(mir.coeffs, plain.coeffs)
        assert np.array_equal(mir.grids, plain.grids)
    m.set_mirror(False)
    with pytest.raises(ValueError, match="True or False"):
        m.set_mirror("yes")


@pytest.mark.parametrize("device", ["cpu", pytest.param("cuda", marks=pytest.mark.skipif(
    not torch.cuda.is_available(), reason="needs a CUDA GPU"))])
def test_to_a_device_gives_the_same_answers(model, device):
    m, K = _bins_model(model), model.intrinsics
    d = np.zeros((K.height, K.width))
    d[8:16, 6:26] = 1.7
    before = m.predict(d, K, rolls=3)
    assert m.to(device) is m and m.device.type == device and next(m.net.parameters()).device.type == device
    after = m.predict(d, K, rolls=3)
    assert np.allclose(before.probabilities, after.probabilities, atol=1e-5)
    assert np.allclose(before.rotation, after.rotation, atol=1e-4) and np.array_equal(before.grids, after.grids)
    m.to("cpu")


# ------------------------------------------------------------------ ensembles of training seeds

def _bins_seed(model, seed, coeff_shift=0.0):
    torch.manual_seed(seed)
    net = HBEONet(NetConfig(image_size=(32, 24), n_classes=N_CLASSES, n_coeffs=model.subspace.dim_,
                            conv_channels=(4, 4, 4, 4), fc=(8, 8, 8), rotation="bins", rotation_bins=256))
    k = model.subspace.dim_
    settings = {**model.settings.to_dict(), "coeff_mean": [coeff_shift] * k, "coeff_std": [1.0 + coeff_shift] * k}
    return HBEO(net, model.subspace, model.intrinsics, model.classes, settings)


def test_an_ensemble_averages_its_members_answers(model, tmp_path):
    """Class probabilities, rotation distributions and de-standardized coefficients are the members' means;
    the rotation is decoded from the mean distribution; the same network twice answers as one."""
    K = Intrinsics.kinect(64, 48)
    d = np.stack([blob_depth(K), blob_depth(K, 2.2)])
    a, b = _bins_seed(model, 1), _bins_seed(model, 2, coeff_shift=0.5)        # b standardized differently
    pa, pb = a.predict(d, K), b.predict(d, K)
    ens = _bins_seed(model, 1).add_members([_bins_seed(model, 2, coeff_shift=0.5)])
    pe = ens.predict(d, K)
    assert np.allclose(pe.probabilities, (pa.probabilities + pb.probabilities) / 2, atol=1e-6)
    assert np.allclose(pe.pose_probs, (pa.pose_probs + pb.pose_probs) / 2, atol=1e-9)
    assert np.allclose(pe.coeffs, (pa.coeffs + pb.coeffs) / 2, atol=1e-5)
    want = ens.net.pose_matrix(torch.log(torch.from_numpy(pe.pose_probs))).numpy()
    assert np.allclose(pe.rotation, pe.view_rotation @ want, atol=1e-6)
    assert not np.allclose(pa.probabilities, pb.probabilities)                 # the members differ
    twice = _bins_seed(model, 1).add_members([_bins_seed(model, 1)]).predict(d, K)
    assert np.allclose(twice.probabilities, pa.probabilities, atol=1e-6)
    assert np.allclose(twice.rotation, pa.rotation, atol=1e-5) and (twice.grids == pa.grids).all()
    r4 = _bins_seed(model, 1).add_members([_bins_seed(model, 2, coeff_shift=0.5)]).predict(d, K, rolls=4)
    assert np.allclose(r4.probabilities.sum(1), 1) and r4.rotation.shape == (2, 3, 3)


def test_ensemble_members_must_match_and_an_ensemble_is_not_saved(model, tmp_path):
    a = _bins_seed(model, 1)
    with pytest.raises(ValueError, match="rotation-bins"):
        a.add_members([model])                                                   # a regression head
    other = _bins_seed(model, 2)
    other.classes = tuple(reversed(other.classes))
    with pytest.raises(ValueError, match="member 0 .*classes"):
        a.add_members([other])
    with pytest.raises(ValueError, match="already in the ensemble"):
        a.add_members([a])
    assert a.members == []                                                       # nothing half-added
    a.add_members([_bins_seed(model, 2)])
    with pytest.raises(ValueError, match="not one model file"):
        a.save(tmp_path / "e.hbeo")


def test_load_with_members_records_them_and_names_a_bad_one(model, tmp_path):
    fa = _bins_seed(model, 1).save(tmp_path / "a.hbeo")
    fb = _bins_seed(model, 2).save(tmp_path / "b.hbeo")
    ens = HBEO.load(fa, members=[fb])
    assert len(ens.members) == 1 and ens.member_files[0]["file"] == "b.hbeo"
    assert len(ens.member_files[0]["sha256"]) == 64
    fc = model.save(tmp_path / "regression.hbeo")
    with pytest.raises(DataError, match=r"regression\.hbeo: not an ensemble member of a\.hbeo.*rotation-bins"):
        HBEO.load(fa, members=[fc])
    copy = tmp_path / "copy.hbeo"
    copy.write_bytes(fb.read_bytes())
    for members in ([fa], [fb, copy]):                      # the model itself, or one member twice
        with pytest.raises(DataError, match="the same model as .*an ensemble averages different models"):
            HBEO.load(fa, members=members)
    with pytest.raises(DataError, match=r"missing\.hbeo: no such model file"):
        HBEO.load(fa, members=[tmp_path / "missing.hbeo"])
