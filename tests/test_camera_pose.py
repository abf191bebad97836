import numpy as np
import pytest
from scipy import stats
from scipy.spatial.transform import Rotation

from hbeo import conventions as C
from hbeo.render.poses import ViewSampler
from hbeo.rotations import matrix_to_axis_angle, uniform_so3, yaw_elevation_to_matrix


def test_kinect_intrinsics_scale_with_the_image():
    K = C.Intrinsics.kinect(320, 240)
    assert (K.fx, K.fy, K.cx, K.cy) == (262.5, 262.5, 159.5, 119.5)
    assert C.Intrinsics.kinect(640, 480).fx == 525.0
    assert np.allclose(C.Intrinsics.kinect(64, 64).K, [[52.5, 0, 31.5], [0, 52.5, 31.5], [0, 0, 1]])


@pytest.mark.parametrize("args", [(100, 100, 10, 10, 0, 10), (100, 100, 10, 10, 10, 0),
                                  (-5, 100, 10, 10, 20, 20), (np.nan, 100, 10, 10, 20, 20)])
def test_nonsense_intrinsics_are_rejected(args):
    with pytest.raises(ValueError):
        C.Intrinsics(*args)


def test_backproject_then_project_round_trip():
    K = C.Intrinsics(300.0, 310.0, 40.3, 29.7, 80, 60)
    rng = np.random.default_rng(0)
    depth = np.zeros((60, 80))
    depth[rng.random((60, 80)) < 0.3] = 1.0
    depth *= rng.uniform(0.5, 3.0, depth.shape)
    pts, rc = C.backproject(depth, K)
    uvz = C.project(pts, K)
    assert np.allclose(uvz[:, 0], rc[:, 1]) and np.allclose(uvz[:, 1], rc[:, 0])
    assert np.allclose(uvz[:, 2], depth[rc[:, 0], rc[:, 1]])
    with pytest.raises(ValueError, match="intrinsics are for 80x60"):
        C.backproject(np.zeros((10, 10)), K)


def angle_cdf(theta):
    """CDF of the rotation angle of a Haar-uniform rotation: (theta - sin theta) / pi."""
    return (theta - np.sin(theta)) / np.pi


def test_so3_sampler_is_uniform():
    R = uniform_so3(5000, np.random.default_rng(2))
    assert np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3), atol=1e-9) and np.allclose(np.linalg.det(R), 1)
    theta = np.linalg.norm(matrix_to_axis_angle(R), axis=1)
    assert stats.kstest(theta, angle_cdf).pvalue > 0.01
    for axis in range(3):                          # every rotated axis is uniform on the sphere
        assert stats.kstest(R[:, 2, axis], stats.uniform(-1, 2).cdf).pvalue > 0.01


def test_the_uniformity_test_rejects_a_non_uniform_sampler():
    e = np.random.default_rng(3).uniform([0, 0, 0], [2 * np.pi, np.pi, 2 * np.pi], (5000, 3))
    R = Rotation.from_euler("zyz", e).as_matrix()  # uniform Euler angles are not uniform on SO(3)
    theta = np.linalg.norm(matrix_to_axis_angle(R), axis=1)
    assert stats.kstest(theta, angle_cdf).pvalue < 1e-6


def test_upright_rotations_have_no_roll_and_the_asked_elevation():
    rng = np.random.default_rng(4)
    yaw, elev = rng.uniform(0, 2 * np.pi, 100), rng.uniform(0.1, 1.0, 100)
    R = yaw_elevation_to_matrix(yaw, elev)
    up = R[:, :, 2]                               # object +z in camera coordinates
    assert np.allclose(up[:, 0], 0, atol=1e-12)    # no roll: up stays vertical in the image
    assert (up[:, 1] < 0).all()                   # and points to the top of the image (y is down)
    assert np.allclose(np.arcsin(-up[:, 2]), elev)  # camera looks down by the elevation
    front = yaw_elevation_to_matrix(0.0, 0.0)
    assert np.allclose(front @ [0, -1, 0], [0, 0, -1])   # at yaw 0 the object's front faces the camera


def test_view_sampler_ranges_and_errors():
    vs = ViewSampler("upright", distance=(1.5, 2.0), shift=0.1)
    R, t = vs.sample(500, np.random.default_rng(5))
    assert R.shape == (500, 3, 3) and t.shape == (500, 3)
    assert t[:, 2].min() >= 1.5 and t[:, 2].max() <= 2.0
    assert (np.abs(t[:, :2]) <= 0.1 * t[:, 2:3] + 1e-12).all()
    a, _ = ViewSampler().sample(3, np.random.default_rng(9))
    b, _ = ViewSampler().sample(3, np.random.default_rng(9))
    assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="unknown sampler"):
        ViewSampler("random")
    with pytest.raises(ValueError, match="inside an object"):
        ViewSampler(distance=(0.5, 1.0), object_size=1.0)
