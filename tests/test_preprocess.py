import numpy as np
import pytest

from hbeo.conventions import Intrinsics
from hbeo.model.preprocess import to_model_view
from hbeo.rotations import direction_to_matrix


def sphere_depth(K, center, r):
    """Analytic depth image of a sphere (first hit z), 0 elsewhere."""
    v, u = np.mgrid[0:K.height, 0:K.width]
    d = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones(u.shape)], -1)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    b = d @ center
    disc = b ** 2 - (center @ center - r * r)
    t = np.where(disc > 0, b - np.sqrt(np.clip(disc, 0, None)), 0)
    return np.where(disc > 0, t * d[..., 2], 0.0)


def test_direction_to_matrix_is_the_smallest_rotation_to_the_target():
    c = np.array([0.3, -0.2, 2.0])
    Q = direction_to_matrix(c)
    assert np.allclose(Q.T @ Q, np.eye(3)) and np.isclose(np.linalg.det(Q), 1)
    assert np.allclose(Q[:, 2], c / np.linalg.norm(c))
    angle = np.degrees(np.arccos((np.trace(Q) - 1) / 2))
    assert angle == pytest.approx(np.degrees(np.arccos(c[2] / np.linalg.norm(c))))
    assert np.allclose(direction_to_matrix(np.array([0, 0, 5.0])), np.eye(3))


def test_same_camera_centred_object_is_unchanged():
    K = Intrinsics.kinect(64, 48)
    d = sphere_depth(K, np.array([0.0, 0.0, 2.0]), 0.4)
    view = to_model_view(d, K, K, recenter=False)
    assert np.allclose(view.depth, d, atol=1e-6) and np.allclose(view.Q, np.eye(3))


def test_other_intrinsics_and_off_centre_object_are_brought_to_the_model_view():
    K_user, K_model = Intrinsics(600.0, 600.0, 330.0, 250.0, 640, 480), Intrinsics.kinect(64, 48)
    centered = to_model_view(sphere_depth(K_user, np.array([0.0, 0.0, 2.0]), 0.4), K_user, K_model).depth
    c = np.array([0.5, -0.3, 2.0])
    c = c / np.linalg.norm(c) * 2.0             # same distance, off to the side
    moved = to_model_view(sphere_depth(K_user, c, 0.4), K_user, K_model)
    assert np.allclose(moved.Q[:, 2], c / 2.0, atol=0.01)
    both = (moved.depth > 0) & (centered > 0)
    assert both.sum() > 0.95 * (centered > 0).sum()           # a sphere looks the same from any side
    diff = np.abs(moved.depth[both] - centered[both])
    assert np.median(diff) < 0.01 and np.percentile(diff, 90) < 0.03   # nearest-pixel lookup at the rim


def test_reference_distance_makes_the_view_distance_invariant():
    K_user, K_model = Intrinsics.kinect(320, 240), Intrinsics.kinect(64, 48)
    near = to_model_view(sphere_depth(K_user, np.array([0, 0, 1.5]), 0.4), K_user, K_model, ref_distance=2.0)
    far = to_model_view(sphere_depth(K_user, np.array([0, 0, 3.0]), 0.4), K_user, K_model, ref_distance=2.0)
    a, b = near.depth > 0, far.depth > 0
    assert (a ^ b).sum() <= 0.15 * a.sum()                    # same silhouette up to perspective
    both = a & b
    assert np.median(np.abs(near.depth[both] - far.depth[both])) < 0.05
    assert far.zoom == pytest.approx(2 * near.zoom, rel=0.05)


@pytest.mark.parametrize("depth, mask, msg", [
    (np.zeros((48, 64)), None, "no valid pixels"),
    (np.full((48, 64), np.nan), None, "all NaN"),
    (np.ones((48, 64)), np.ones((10, 10)), "mask is 10x10"),
    (np.ones(5), None, "2-D image"),
    (np.ones((10, 10)), None, "intrinsics are for 64x48"),
])
def test_bad_depth_inputs(depth, mask, msg):
    K = Intrinsics.kinect(64, 48)
    with pytest.raises(ValueError, match=msg):
        to_model_view(depth, K, K, mask=mask)


def test_same_camera_fast_path_equals_the_general_resampling():
    K = Intrinsics.kinect(64, 48)
    d = sphere_depth(K, np.array([0.1, -0.05, 1.6]), 0.35)
    K_almost = Intrinsics(K.fx, K.fy, K.cx + 1e-9, K.cy, K.width, K.height)   # not equal: general path
    fast, slow = to_model_view(d, K, K, recenter=False), to_model_view(d, K, K_almost, recenter=False)
    assert np.array_equal(fast.depth, slow.depth)
    assert np.allclose(fast.center, slow.center) and fast.distance == pytest.approx(slow.distance)
