import math

import numpy as np
import pytest
import torch

from hbeo import conventions as C
from hbeo.data import procedural
from hbeo.model.augment import RollAugment, mirror_depth, roll_depth
from hbeo.render.renderer import Renderer, prepare_mesh
from hbeo.rotations import axis_angle_to_matrix, matrix_to_axis_angle, uniform_so3, z_angle_to_matrix

K = C.Intrinsics.kinect(80, 60)


@pytest.fixture(scope="module")
def chair_views():
    """A procedural chair rendered at 3 poses and at the same poses rolled by 3 angles."""
    mesh = prepare_mesh(procedural.generate("chair", "train", 0))
    R = uniform_so3(3, np.random.default_rng(1))
    t = np.array([[0.02, -0.03, 1.7], [0.0, 0.0, 1.6], [-0.04, 0.02, 1.8]])
    angles = [0.7, 2.5, -1.9]
    Rz = z_angle_to_matrix(np.asarray(angles))
    with Renderer(K) as r:
        base = r.render_many(mesh, R, t)
        rolled = r.render_many(mesh, Rz @ R, np.einsum("nij,nj->ni", Rz, t))
    return base, rolled, angles


def test_rolled_view_matches_rendering_the_rolled_pose(chair_views):
    base, rolled, angles = chair_views
    for d, want, a in zip(base, rolled, angles):
        got = roll_depth(d, K, a)
        both = (got > 0) & (want > 0)
        # silhouettes agree up to nearest-pixel rounding along the outline (thin legs at 80x60: ~10 %
        # of the area), depths agree where both see
        assert ((got > 0) != (want > 0)).sum() <= 0.15 * (want > 0).sum()
        assert np.median(np.abs(got[both] - want[both])) < 0.01
        # and a roll by an angle 6 degrees off does not (the test can fail)
        other = roll_depth(d, K, a + 0.1)
        assert ((other > 0) != (want > 0)).sum() > 2 * ((got > 0) != (want > 0)).sum()


def test_roll_by_zero_is_identity_and_needs_square_pixels(chair_views):
    d = chair_views[0][0]
    assert np.array_equal(roll_depth(d, K, 0.0), d)
    with pytest.raises(ValueError, match="square pixels"):
        roll_depth(d, C.Intrinsics(60, 70, 39.5, 29.5, 80, 60), 0.3)


def test_roll_augment_turns_rotation_and_axis_angle_consistently_and_repeats_with_the_seed(chair_views):
    base = chair_views[0]
    R = uniform_so3(3, np.random.default_rng(1)).astype(np.float32)
    items = [{"depth": torch.from_numpy(d)[None], "rotation": torch.from_numpy(r), "label": 1,
              "axis_angle": torch.from_numpy(matrix_to_axis_angle(r).astype(np.float32))}
             for d, r in zip(base, R)]
    aug = RollAugment(items, K)
    torch.manual_seed(5)
    a = [aug[i] for i in range(3)]
    torch.manual_seed(5)
    b = [aug[i] for i in range(3)]
    for i, (x, y, r) in enumerate(zip(a, b, R)):
        assert torch.equal(x["depth"], y["depth"]) and torch.equal(x["rotation"], y["rotation"])
        Rz = x["rotation"].double().numpy() @ r.T.astype(np.float64)
        assert np.allclose(Rz[2], [0, 0, 1], atol=1e-5)        # a turn about the camera's z axis only
        assert np.allclose(axis_angle_to_matrix(x["axis_angle"].double().numpy()), x["rotation"].numpy(),
                           atol=1e-5)
        # the image was rolled by the same angle as the rotation
        angle = math.atan2(Rz[1, 0], Rz[0, 0])
        assert (x["depth"][0].numpy() != roll_depth(base[i], K, angle)).mean() < 0.01
    torch.manual_seed(6)
    assert not torch.equal(aug[0]["rotation"], a[0]["rotation"])


def test_mirrored_view_matches_rendering_the_mirrored_object_at_the_conjugated_pose(chair_views):
    """mirror_depth of a view of the object at (R, t) is the view of the object mirrored by F_obj at
    (F R F_obj, F t), F = diag(-1, 1, 1) in the camera frame, for either mirror plane of the object."""
    mesh = prepare_mesh(procedural.generate("chair", "train", 0))
    R = uniform_so3(3, np.random.default_rng(1))
    t = np.array([[0.02, -0.03, 1.7], [0.0, 0.0, 1.6], [-0.04, 0.02, 1.8]])
    F = np.diag([-1.0, 1.0, 1.0])
    base = chair_views[0]
    for F_obj in (np.diag([-1.0, 1.0, 1.0]), np.diag([1.0, -1.0, 1.0])):
        mirrored = mesh.copy()
        T = np.eye(4)
        T[:3, :3] = F_obj
        mirrored.apply_transform(T)
        with Renderer(K) as r:
            want = r.render_many(mirrored, F @ R @ F_obj, t @ F)
        for d, w in zip(base, want):
            got = mirror_depth(d, K)
            both = (got > 0) & (w > 0)
            assert ((got > 0) != (w > 0)).sum() <= 0.05 * (w > 0).sum()
            assert np.median(np.abs(got[both] - w[both])) < 1e-3
            assert ((d > 0) != (w > 0)).sum() > 5 * ((got > 0) != (w > 0)).sum()   # the unmirrored view does not


def test_mirror_twice_is_identity_and_off_centre_columns_fall_out(chair_views):
    d = chair_views[0][0]
    assert np.array_equal(mirror_depth(mirror_depth(d, K), K), d)          # cx = (W - 1) / 2
    assert not np.array_equal(mirror_depth(d, K), d)
    batch = np.stack(chair_views[0])
    assert np.array_equal(mirror_depth(batch, K)[1], mirror_depth(batch[1], K))
    off = C.Intrinsics(K.fx, K.fy, K.cx - 2, K.cy, K.width, K.height)      # 2 cx = 75: columns 76.. leave the frame
    m = mirror_depth(d, off)
    assert (m[:, 76:] == 0).all() and np.array_equal(m[:, :76], d[:, 75::-1])
