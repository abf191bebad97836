"""Mirror augmentation (hbeo.model.mirror): each class's mirror axis, the mirrored rotation and item, and the
training data that mirrors views with their labels."""
import json

import numpy as np
import pytest
import torch

from hbeo import conventions as C
from hbeo.data import procedural
from hbeo.model.augment import mirror_depth
from hbeo.model.mirror import MirrorAugment, mirror_axes, mirror_item, mirror_rotation
from hbeo.render.renderer import Renderer, prepare_mesh
from hbeo.rotations import uniform_so3

K = C.Intrinsics.kinect(80, 60)


@pytest.mark.parametrize("axis", [0, 1])
def test_mirror_rotation_is_F_R_Fobj_a_proper_rotation_and_its_own_inverse(axis):
    R = uniform_so3(5, np.random.default_rng(3))
    F, F_obj = np.diag([-1.0, 1, 1]), np.eye(3)
    F_obj[axis, axis] = -1
    M = mirror_rotation(R, axis)
    assert np.allclose(M, F @ R @ F_obj)
    assert np.allclose(np.linalg.det(M), 1) and np.allclose(M @ M.transpose(0, 2, 1), np.eye(3), atol=1e-12)
    assert np.allclose(mirror_rotation(M, axis), R)
    assert not np.allclose(M, mirror_rotation(R, 1 - axis))


def test_mirror_axes_finds_each_class_mirror_plane():
    """Class 0 is symmetric across x (a block with a back wall toward +y), class 1 across y (back toward +x)."""
    g = np.zeros((6, 30, 30, 30), bool)
    rng = np.random.default_rng(0)
    for i in range(6):
        w = rng.integers(4, 8)
        if i < 3:
            g[i, 15 - w:15 + w, 8:20, 5:10] = True          # seat, centred in x
            g[i, 15 - w:15 + w, 18:20, 5:25] = True         # back at +y
        else:
            g[i, 8:20, 15 - w:15 + w, 5:10] = True
            g[i, 18:20, 15 - w:15 + w, 5:25] = True
    assert mirror_axes(g, [0, 0, 0, 1, 1, 1], 2) == (0, 1)
    with pytest.raises(ValueError, match="class 2 has no training grid"):
        mirror_axes(g, [0, 0, 0, 1, 1, 1], 3)


def test_a_mirrored_item_is_the_view_of_the_mirrored_object_with_its_labels():
    mesh = prepare_mesh(procedural.generate("chair", "train", 0))
    R = uniform_so3(2, np.random.default_rng(4))
    t = np.array([[0.03, -0.02, 1.7], [0.0, 0.01, 1.6]])
    for axis in (0, 1):
        F_obj = np.eye(4)
        F_obj[axis, axis] = -1
        mirrored = mesh.copy()
        mirrored.apply_transform(F_obj)
        with Renderer(K) as r:
            base = r.render_many(mesh, R, t)
            want = r.render_many(mirrored, mirror_rotation(R, axis), t * [-1, 1, 1])
        for d, Ri, w in zip(base, R, want):
            item = {"depth": torch.from_numpy(d.astype(np.float32))[None], "label": 2,
                    "rotation": torch.from_numpy(Ri.astype(np.float32)), "axis_angle": torch.zeros(3),
                    "coeffs": torch.zeros(4), "object_index": 0}
            out = mirror_item(item, K, axis, np.arange(4.0))
            got = out["depth"][0].numpy()
            assert ((got > 0) != (w > 0)).sum() <= 0.05 * (w > 0).sum()
            assert np.allclose(out["rotation"].numpy(), mirror_rotation(Ri, axis), atol=1e-6)
            assert out["coeffs"].tolist() == [0, 1, 2, 3] and out["label"] == 2
            assert torch.equal(item["depth"][0], torch.from_numpy(d.astype(np.float32)))   # input untouched


def test_mirror_augment_mirrors_about_half_repeats_with_the_seed_and_needs_a_centred_camera():
    d = np.zeros((60, 80), np.float32)
    d[10:20, 5:30] = 1.7                                        # left of centre: its mirror is right of it
    items = [{"depth": torch.from_numpy(d)[None], "label": i % 2, "rotation": torch.eye(3), "axis_angle": torch.zeros(3),
              "coeffs": torch.zeros(3), "object_index": i % 4} for i in range(200)]
    mirrored = np.arange(12, dtype=np.float32).reshape(4, 3) + 1
    aug = MirrorAugment(items, K, (0, 1), mirrored)
    torch.manual_seed(1)
    a = [aug[i] for i in range(200)]
    torch.manual_seed(1)
    b = [aug[i] for i in range(200)]
    flipped = [bool(x["depth"][0, 15, 60] > 0) for x in a]
    assert 70 < sum(flipped) < 130
    assert flipped == [bool(x["depth"][0, 15, 60] > 0) for x in b]
    for i, (x, f) in enumerate(zip(a, flipped)):
        want = mirrored[i % 4] if f else np.zeros(3)
        assert np.array_equal(x["coeffs"].numpy(), want)
        assert np.allclose(np.diag(x["rotation"].numpy()), [1, 1, 1] if not f else
                           ([1, 1, 1] if i % 2 == 0 else [-1, -1, 1]))
    with pytest.raises(ValueError, match="principal point"):
        MirrorAugment(items, C.Intrinsics(K.fx, K.fy, K.cx + 3, K.cy, 80, 60), (0, 1), mirrored)
    with pytest.raises(ValueError, match="mirror axes"):
        MirrorAugment(items, K, (0, 2), mirrored)
    assert np.array_equal(mirror_depth(a[0]["depth"][0].numpy(), K) > 0, b[0]["depth"][0].numpy()[:, ::-1] > 0)


@pytest.mark.slow
def test_train_with_mirror_augmentation_on_the_ci_run(ci_render, ci_run, copy_run, tmp_path, capsys):
    """--augment-mirror: the targets come from the run's own grids (their unflipped coefficients are the rendered
    set's), the option reaches the checkpoint's data settings and the provenance; other data sources refuse it."""
    from hbeo import cli
    from hbeo.model.loop import load_checkpoint
    from hbeo.model.mirror import mirror_targets
    from hbeo.model.trainingdata import ViewArrays, ViewOptions
    from hbeo.render.torch_datasets import split_by_object
    from hbeo.subspace.basis import ObjectSubspace
    run = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz",
                                                    "render_train"])
    data = ViewArrays(run.renders("train"), ViewOptions(), progress=False)
    tr, _ = split_by_object(ci_render, 0.1, 0)
    axes, mirrored = mirror_targets(run, data, tr, progress=False)
    assert len(axes) == len(ci_render.classes) and set(axes) <= {0, 1} and mirrored.shape == (len(ci_render.object_ids),
                                                                                              data.coeffs.shape[1])
    sub = ObjectSubspace.load(run.subspace)
    from hbeo.data.gridset import GridSet
    gs = GridSet.load(run.grids("train"))
    o = int(data.object_index[0])
    g = gs.grids[list(map(str, gs.ids)).index(str(ci_render.object_ids[o]))]
    want = (sub.project(np.flip(g, axes[int(data.labels[0])])[None])[0] - data.coeff_mean) / data.coeff_std
    assert np.allclose(mirrored[o], want, atol=1e-4) and not np.allclose(mirrored[o], data.coeffs[0], atol=1e-2)
    args = ["train", "--dataset", "procedural", "--profile", "ci", "--out", str(run.path), "--epochs", "1",
            "--max-steps", "2", "--augment-mirror", "--quiet"]
    assert cli.main(args) == 0
    settings = load_checkpoint(run.training(run.model) / "checkpoint.pt")["settings"]
    assert settings["train"]["data"]["augment_mirror"] is True
    info = json.loads((run.training(run.model) / "provenance.json").read_text())
    assert info["options"]["augment_mirror"] is True
    assert cli.main([*args[:-1], "--data", "shards", "--name", "other.hbeo", "--quiet"]) == 2
    assert "mirror augmentation needs data 'memory'" in capsys.readouterr().err
