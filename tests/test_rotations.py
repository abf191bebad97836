import subprocess
import sys

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from hbeo import rotations as RT


def is_rotation(R, atol=1e-9):
    R = np.asarray(R)
    return (np.allclose(R @ np.swapaxes(R, -1, -2), np.eye(3), atol=atol)
            and np.allclose(np.linalg.det(R), 1.0, atol=atol))


@pytest.fixture(scope="module")
def Rs():
    return RT.uniform_so3(300, np.random.default_rng(0))


def test_samplers_give_rotations_deterministically():
    R = RT.uniform_so3(50, np.random.default_rng(1))
    assert R.shape == (50, 3, 3) and is_rotation(R)
    assert np.array_equal(R, RT.uniform_so3(50, np.random.default_rng(1)))
    G = RT.super_fibonacci(64)
    assert G.shape == (64, 3, 3) and is_rotation(G) and np.array_equal(G, RT.super_fibonacci(64))
    assert RT.geodesic_deg(G[:, None], G[None])[~np.eye(64, dtype=bool)].min() > 10   # spread out
    with pytest.raises(ValueError, match="n=0"):
        RT.super_fibonacci(0)


def test_axis_angle_round_trips_numpy_and_torch(Rs):
    v = RT.matrix_to_axis_angle(Rs)
    assert v.shape == (300, 3) and np.linalg.norm(v, axis=1).max() <= np.pi + 1e-12
    assert np.allclose(RT.axis_angle_to_matrix(v), Rs, atol=1e-12)
    assert np.allclose(Rotation.from_rotvec(v).as_matrix(), Rs, atol=1e-12)       # scipy agrees
    vt = torch.tensor(v)
    Mt = RT.axis_angle_to_matrix(vt)
    assert isinstance(Mt, torch.Tensor) and Mt.dtype == torch.float64
    assert np.allclose(Mt.numpy(), Rs, atol=1e-12)
    M32 = RT.axis_angle_to_matrix(vt.float())
    assert M32.dtype == torch.float32 and np.allclose(M32.numpy(), Rs, atol=1e-5)
    assert np.array_equal(RT.axis_angle_to_matrix(np.zeros(3)), np.eye(3))        # zero vector: identity


def test_axis_and_angle_matches_the_rotation_vector():
    axis, ang = np.array([0.3, -2.0, 0.5]), np.linspace(-3, 3, 13)
    A = RT.axis_and_angle_to_matrix(axis, ang)
    assert A.shape == (13, 3, 3)
    v = axis / np.linalg.norm(axis) * ang[:, None]
    assert np.allclose(A, RT.axis_angle_to_matrix(v), atol=1e-12)
    assert RT.axis_and_angle_to_matrix(np.ones((2, 4, 3)), 0.5).shape == (2, 4, 3, 3)


def test_quaternion_round_trip_and_known_value(Rs):
    q = RT.matrix_to_quaternion(Rs)
    assert q.shape == (300, 4) and np.allclose(np.linalg.norm(q, axis=1), 1) and (q[:, 0] >= 0).all()
    assert np.allclose(RT.quaternion_to_matrix(q), Rs, atol=1e-12)
    assert np.allclose(RT.quaternion_to_matrix(-q), Rs, atol=1e-12)                # q and -q: one rotation
    h = np.sqrt(0.5)                                                               # 90 deg about +z
    assert np.allclose(RT.quaternion_to_matrix([h, 0, 0, h]), [[0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert np.allclose(RT.matrix_to_quaternion(np.eye(3)), [1, 0, 0, 0])


def test_sixd_round_trip_and_orthonormalization(Rs):
    x = RT.matrix_to_sixd(Rs)
    assert x.shape == (300, 6) and np.array_equal(x[:, :3], Rs[:, :, 0])
    assert np.allclose(RT.sixd_to_matrix(x), Rs, atol=1e-12)
    noisy = x + 0.2 * np.random.default_rng(2).normal(size=x.shape)
    M = RT.sixd_to_matrix(noisy)
    assert is_rotation(M)
    Mt = RT.sixd_to_matrix(torch.tensor(noisy))
    assert isinstance(Mt, torch.Tensor) and np.allclose(Mt.numpy(), M, atol=1e-12)   # one formula, two backends
    assert np.array_equal(RT.matrix_to_sixd(torch.tensor(Rs)).numpy(), x)


def test_project_to_so3_numpy_and_torch(Rs):
    M = Rs + 0.1 * np.random.default_rng(3).normal(size=Rs.shape)
    P = RT.project_to_so3(M)
    assert is_rotation(P)
    assert np.allclose(RT.project_to_so3(Rs), Rs, atol=1e-12)
    assert np.allclose(RT.project_to_so3(torch.tensor(M)).numpy(), P, atol=1e-12)
    reflected = M[:5] @ np.diag([1.0, 1.0, -1.0])                                  # det < 0: still a rotation
    assert is_rotation(RT.project_to_so3(reflected))


def test_elementary_rotations_known_values():
    assert np.allclose(RT.z_angle_to_matrix(np.pi / 2) @ [1, 0, 0], [0, 1, 0])     # +x toward +y
    assert np.allclose(RT.x_angle_to_matrix(np.pi / 2) @ [0, 1, 0], [0, 0, 1])     # +y toward +z
    assert np.allclose(RT.z_angle_to_matrix(0.4), Rotation.from_euler("z", 0.4).as_matrix(), atol=1e-15)
    assert np.allclose(RT.x_angle_to_matrix(-1.1), Rotation.from_euler("x", -1.1).as_matrix(), atol=1e-15)
    assert RT.z_angle_to_matrix(0.3)[2, 2] == 1.0 and RT.x_angle_to_matrix(0.3)[0, 0] == 1.0   # exact axis
    assert RT.z_angle_to_matrix(np.zeros((4, 2))).shape == (4, 2, 3, 3)


def test_yaw_elevation_order_and_broadcasting():
    yaw, el = 0.7, 0.4
    R = RT.yaw_elevation_to_matrix(yaw, el)
    assert R.shape == (3, 3) and is_rotation(R)
    assert np.allclose(R, RT.yaw_elevation_to_matrix(0.0, el) @ RT.z_angle_to_matrix(yaw))   # yaw first
    assert np.allclose(R[:, 2], [0, -np.cos(el), -np.sin(el)])       # object up: image up, tilted away
    assert RT.yaw_elevation_to_matrix(np.zeros(5), 0.3).shape == (5, 3, 3)


def test_direction_to_matrix_is_the_smallest_rotation():
    d = np.array([[0.3, -0.2, 2.0], [0, 0, 1.0], [0, 0, -1.0], [1.0, 0, 0]])
    Q = RT.direction_to_matrix(d)
    assert Q.shape == (4, 3, 3) and is_rotation(Q)
    assert np.allclose(Q[..., 2], d / np.linalg.norm(d, axis=1, keepdims=True))
    assert np.allclose(Q[1], np.eye(3)) and np.allclose(Q[2], np.diag([1.0, -1.0, -1.0]))
    angle = RT.geodesic_deg(Q[0], np.eye(3))                 # no twist: the angle between +z and d
    assert angle == pytest.approx(np.degrees(np.arccos(d[0, 2] / np.linalg.norm(d[0]))))


def test_view_rotation_rows():
    V = RT.view_deg_to_matrix(-60.0, 25.0)
    assert is_rotation(V)
    assert V[1, 2] > 0                                       # object +z points up in the picture
    assert np.allclose(RT.view_deg_to_matrix(0.0, 0.0), [[0, 1, 0], [0, 0, 1], [1, 0, 0]])


def test_geodesic_symmetric_bounded_and_known(Rs):
    A, B = Rs[:150], Rs[150:]
    d = RT.geodesic_deg(A, B)
    assert d.shape == (150,) and np.allclose(d, RT.geodesic_deg(B, A))
    assert (d >= 0).all() and (d <= 180).all()
    assert np.allclose(RT.geodesic_deg(Rs, Rs), 0, atol=1e-5)
    assert RT.geodesic_deg(np.eye(3), RT.z_angle_to_matrix(np.radians(37))) == pytest.approx(37)
    assert RT.geodesic_deg(Rs[0], Rs[0] @ RT.x_angle_to_matrix(np.pi)) == pytest.approx(180)
    assert np.allclose(RT.geodesic(A, B), np.radians(d))
    assert RT.geodesic_deg(Rs[:4, None], Rs[None, :5]).shape == (4, 5)                  # broadcasts


@pytest.mark.parametrize("fn, arg", [
    (RT.axis_angle_to_matrix, np.zeros((5, 4))),
    (RT.axis_angle_to_matrix, torch.zeros(5, 2)),
    (RT.matrix_to_axis_angle, np.zeros((5, 3))),
    (RT.quaternion_to_matrix, np.zeros((2, 3))),
    (RT.matrix_to_quaternion, np.zeros((3, 4))),
    (RT.sixd_to_matrix, np.zeros(5)),
    (RT.matrix_to_sixd, torch.zeros(2, 2, 3)),
    (RT.project_to_so3, np.zeros((2, 3, 2))),
    (RT.direction_to_matrix, np.zeros((2, 2))),
])
def test_bad_shapes_raise_value_error_naming_what_arrived(fn, arg):
    with pytest.raises(ValueError, match=rf"{fn.__name__}: .*got \({', '.join(map(str, arg.shape))},?\)"):
        fn(arg)
    with pytest.raises(ValueError, match=r"geodesic: R2 must have shape \(\.\.\., 3, 3\), got \(3,\)"):
        RT.geodesic_deg(np.eye(3), np.zeros(3))


def test_importing_rotations_and_the_data_layer_does_not_import_torch():
    code = ("import sys, numpy as np; import hbeo.rotations as R; import hbeo.data.voxel; "
            "R.axis_angle_to_matrix(np.ones(3)); print('torch' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_check_rotation_matrices_names_the_first_bad_matrix():
    Rs = RT.uniform_so3(4, np.random.default_rng(0))
    assert np.array_equal(RT.check_rotation_matrices(Rs), Rs)
    assert RT.check_rotation_matrices(np.zeros((0, 3, 3))).shape == (0, 3, 3)
    assert RT.check_rotation_matrices(Rs[:2, None]).shape == (2, 1, 3, 3)           # any leading shape
    bad = Rs.copy()
    bad[2] = bad[2] * 1.01                                                           # not orthonormal
    with pytest.raises(ValueError, match=r"R\[2\] is not a rotation matrix \(\|R\^T R - I\| = 0\.02"):
        RT.check_rotation_matrices(bad)
    mirror = Rs[0] @ np.diag([1.0, 1.0, -1.0])                                       # orthonormal, det -1
    with pytest.raises(ValueError, match=r"R_true is not a rotation matrix .*det = -1"):
        RT.check_rotation_matrices(mirror, "R_true")
    small = Rs[1].copy()
    small[0, 0] += 0.3 * RT.ROTATION_TOL                                             # within the tolerance
    RT.check_rotation_matrices(small)
    with pytest.raises(ValueError, match=r"check_rotation_matrices: R must have shape"):
        RT.check_rotation_matrices(np.eye(2))


def test_symmetric_pose_error_is_the_geodesic_error_modulo_turns_about_up():
    R = RT.uniform_so3(3, np.random.default_rng(1))
    half = RT.z_angle_to_matrix(np.pi)
    assert np.allclose(RT.symmetric_pose_error_deg(R @ half, R, 2), 0, atol=1e-5)   # a 2-fold symmetry
    assert np.allclose(RT.symmetric_pose_error_deg(R @ half, R, 1), 180)            # none: the raw error
    assert np.allclose(RT.symmetric_pose_error_deg(R @ half, R, 0), 180)
    turn = RT.z_angle_to_matrix(np.radians(100))                                       # 4-fold: 100 = 90 + 10
    assert np.allclose(RT.symmetric_pose_error_deg(R @ turn, R, 4), 10)


def test_yaw_elevation_roll_is_the_documented_order():
    """R = Rz(roll) @ E(elevation) @ Rz(yaw): roll 0 is the upright view, the roll turns about the
    optical axis (the camera's axis in object axes stays put), and a quarter roll moves the object's
    up axis from the image's top (-y) to its right (+x)."""
    from hbeo.rotations import yaw_elevation_roll_to_matrix, yaw_elevation_to_matrix, z_angle_to_matrix
    y, e = np.array([0.3, 2.0, 5.0]), np.array([0.4, -0.7, 1.2])
    assert np.array_equal(yaw_elevation_roll_to_matrix(y, e, 0.0), yaw_elevation_to_matrix(y, e))
    R = yaw_elevation_roll_to_matrix(y, e, np.array([0.5, 1.0, 4.0]))
    assert R.shape == (3, 3, 3) and np.allclose(R @ np.swapaxes(R, 1, 2), np.eye(3)) and np.allclose(np.linalg.det(R), 1)
    axis = np.stack([np.sin(y) * np.cos(e), np.cos(y) * np.cos(e), -np.sin(e)], -1)
    assert np.allclose(np.swapaxes(R, 1, 2)[:, :, 2], axis)
    assert np.allclose(R, z_angle_to_matrix([0.5, 1.0, 4.0]) @ yaw_elevation_to_matrix(y, e))
    up = yaw_elevation_roll_to_matrix(0.0, 0.0, np.pi / 2) @ [0, 0, 1]
    assert np.allclose(up, [1, 0, 0])
