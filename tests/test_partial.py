"""Partial grids from depth: rendered shapes whose voxelization is known analytically.

Renders with embree in this process; no torch here (embree's threads slow torch down)."""
import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from hbeo import conventions as C
from hbeo.render import renderer as render
from hbeo.subspace.partial import depth_to_partial, depth_to_partial_many, iter_partial, voxel_size
from hbeo.render.renderer import Renderer, prepare_mesh

pytestmark = pytest.mark.skipif(not render.embree_available(), reason="embreex not installed")

K = C.Intrinsics.kinect(160, 120)
T = np.array([0.03, -0.02, 1.7])
R0 = Rotation.from_euler("xyz", [-115, 8, 35], degrees=True).as_matrix()   # looking down at the top
U = C.voxel_centers(30)          # voxel centres, grid coordinates
BOX = np.array([1.0, 0.6, 0.4])  # box extents (metres); longest side 1 -> 24 voxels


@pytest.fixture(scope="module")
def renderer():
    r = Renderer(K, backend="embree")
    yield r
    r.close()


def box_solid():
    """Analytic voxelization of the box (object_size 1): ``touch`` = voxels whose cube meets the
    solid, ``inside`` = voxels whose centre lies inside it, ``shell`` = voxels meeting its surface."""
    half = BOX / BOX.max() * 12.0                        # half extents in voxels
    a = np.abs(U - 15.0)
    touch = (a - 0.5 < half).all(-1)
    inside = (a < half).all(-1)
    core = (a + 0.5 < half).all(-1)                       # cube entirely inside
    return touch, inside, touch & ~core


def sphere_solid():
    r = np.linalg.norm(U - 15.0, axis=-1)
    dmin = np.linalg.norm(np.maximum(np.abs(U - 15.0) - 0.5, 0), axis=-1)   # nearest point of the voxel
    dmax = np.linalg.norm(np.abs(U - 15.0) + 0.5, axis=-1)                  # farthest point
    return dmin < 12, r < 12, (dmin < 12) & (dmax > 12)


@pytest.fixture(scope="module")
def box_view(renderer):
    mesh = prepare_mesh(trimesh.creation.box(BOX), 1.0)
    return renderer.render(mesh, R0, T)


@pytest.fixture(scope="module")
def sphere_view(renderer):
    mesh = prepare_mesh(trimesh.creation.icosphere(subdivisions=4, radius=1.0), 1.0)
    R = Rotation.from_rotvec([0.4, -1.1, 0.3]).as_matrix()
    return mesh, R, renderer.render(mesh, R, T)


def disagreement(filled, known, touch, inside):
    """Known voxels the analytic solid contradicts (filled but not meeting the solid, or empty
    with the centre inside it), per filled voxel."""
    empty = known & ~filled
    return ((filled & ~touch).sum() + (empty & inside).sum()) / max(1, filled.sum())


def test_box_filled_on_surface_and_empty_outside(box_view):
    filled, known = depth_to_partial(box_view, K, R0, T)
    assert filled.dtype == bool and known.dtype == bool and filled.shape == known.shape == (30, 30, 30)
    assert not (filled & ~known).any()
    touch, inside, shell = box_solid()
    # faces lie exactly on voxel faces, so a hit may fall into the voxel just outside: "near" = 1 voxel
    from scipy import ndimage
    near_shell = ndimage.binary_dilation(shell, iterations=1)
    assert filled.sum() > 300
    assert (filled & ~near_shell).sum() == 0
    assert (filled & shell).sum() / filled.sum() > 0.7
    empty = known & ~filled
    assert empty.sum() > 5000
    assert (empty & inside).sum() == 0                         # carving never enters the solid
    assert (empty & touch).sum() <= 0.005 * empty.sum()
    # the three faces turned to the camera are seen: most of their voxels are known
    n = R0.T @ (-T / np.linalg.norm(T))                        # direction to the camera, object frame
    half = BOX / BOX.max() * 12.0
    faces = np.zeros_like(shell)
    for ax in range(3):
        side = np.sign(n[ax])
        faces |= shell & (side * (U[..., ax] - 15.0) > half[ax] - 1.0) & (abs(n[ax]) > 0.3)
    assert known[faces].mean() > 0.8 and filled[faces].mean() > 0.7
    # the interior is occluded
    assert known[inside & ~shell].mean() < 0.02


def test_sphere_front_known_back_unknown(sphere_view):
    _, R, depth = sphere_view
    filled, known = depth_to_partial(depth, K, R, T)
    touch, inside, shell = sphere_solid()
    assert (filled & ~touch).sum() <= 0.005 * filled.sum() and (filled & shell).sum() >= 0.99 * filled.sum()
    empty = known & ~filled
    assert (empty & inside).sum() == 0
    assert (empty & touch).sum() <= 0.003 * empty.sum()
    # depth of each voxel centre along the viewing direction, relative to the sphere's centre (voxels)
    view = R.T @ (T / np.linalg.norm(T))                       # camera -> object direction, object frame
    along = (U - 15.0) @ view                                  # < 0: toward the camera
    front_shell = shell & (along < -4)
    assert known[front_shell].mean() > 0.85 and filled[front_shell].mean() > 0.8
    assert known[inside & (along > 0)].sum() == 0              # the back half's interior is unknown
    assert known[shell & (along > 4)].mean() < 0.02            # and so is its far surface
    # the space between camera and sphere is carved: voxels whose centre ray meets the sphere
    # (analytically) more than a voxel beyond the centre, and those whose ray misses it
    cam = -R.T @ T * 24 + 15.0                                 # camera centre, grid coordinates
    ray = U - cam
    dist = np.linalg.norm(ray, axis=-1)
    ray = ray / dist[..., None]
    b = (ray * (cam - 15.0)).sum(-1)
    disc = b ** 2 - ((cam - 15.0) ** 2).sum() + 12.0 ** 2    # |cam + s ray - c|^2 = 12^2
    hit_at = -b - np.sqrt(np.maximum(disc, 0))
    uvz = C.project((U.reshape(-1, 3) - 15.0) / 24 @ R.T + T, K).reshape(U.shape)
    in_image = (uvz[..., 0] > -0.5) & (uvz[..., 0] < 159.5) & (uvz[..., 1] > -0.5) & (uvz[..., 1] < 119.5)
    # (voxels whose cube stays clear of the sphere; near the silhouette carving keeps a margin)
    front_free = (disc > 0) & (hit_at > dist + 1.0) & ~touch
    assert front_free.sum() > 1000 and (known & ~filled)[front_free].mean() > 0.97
    miss = in_image & (np.sqrt(144.0 - disc) > 12 + 2.0)      # the ray passes > 2 voxels outside
    assert miss.sum() > 5000 and (known & ~filled)[miss].mean() > 0.97


def test_wrong_pose_disagrees_clearly(box_view):
    touch, inside, _ = box_solid()
    f, k = depth_to_partial(box_view, K, R0, T)
    good = disagreement(f, k, touch, inside)
    assert good < 0.01
    for axis, deg in (([0, 0, 1], 30), ([0, 0, 1], 90), ([1, 0, 0], 25)):
        Rw = R0 @ Rotation.from_rotvec(np.radians(deg) * np.array(axis, float)).as_matrix()
        fw, kw = depth_to_partial(box_view, K, Rw, T)
        bad = disagreement(fw, kw, touch, inside)
        assert bad > 0.3, (axis, deg, good, bad)
        assert ((kw & ~fw) & inside).sum() > 50               # carving cuts into the solid


def test_many_equals_single(sphere_view, box_view):
    rng = np.random.default_rng(3)
    Rs = Rotation.random(7, random_state=rng.integers(1 << 31)).as_matrix()
    Rs[0] = R0
    F, Kn = depth_to_partial_many(box_view, K, Rs, T, chunk=3)
    assert F.shape == Kn.shape == (7, 30, 30, 30)
    for i in range(len(Rs)):
        f, k = depth_to_partial(box_view, K, Rs[i], T)
        assert np.array_equal(f, F[i]) and np.array_equal(k, Kn[i])
    F2, K2 = depth_to_partial_many(box_view, K, Rs, T, chunk=64)
    assert np.array_equal(F, F2) and np.array_equal(Kn, K2)
    e, ek = depth_to_partial_many(box_view, K, np.zeros((0, 3, 3)), T)
    assert e.shape == ek.shape == (0, 30, 30, 30)


def test_iter_partial_counts_surface_outside_the_grid(renderer):
    """A unit cube fills the grid's 24-voxel box; turned 45 degrees about z under a wrong
    hypothesis its seen corners land outside the 30^3 grid, and iter_partial counts them."""
    cube = prepare_mesh(trimesh.creation.box((1, 1, 1)), 1.0)
    depth = renderer.render(cube, R0, T)
    Rs = np.stack([R0, R0 @ Rotation.from_rotvec([0, 0, np.pi / 4]).as_matrix()])
    chunks = list(iter_partial(depth, K, Rs, T, chunk=1))
    assert [c[0] for c in chunks] == [0, 1]
    (_, f0, k0, out0), (_, f1, k1, out1) = chunks
    assert f0.shape == (1, 27000) and out0.tolist() == [0] and out1[0] > 20
    F, Kn = depth_to_partial_many(depth, K, Rs, T)
    assert np.array_equal(F[1].ravel(), f1[0]) and np.array_equal(Kn[0].ravel(), k0[0])


def test_object_size_scales_the_frame(renderer):
    """A sphere half the size, rendered and read with object_size 0.5, gives the same grid
    as the unit sphere at half the distance."""
    R = Rotation.from_rotvec([0.2, 0.5, -0.1]).as_matrix()
    ico = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    small = renderer.render(prepare_mesh(ico, 0.5), R, T / 2)
    big = renderer.render(prepare_mesh(ico, 1.0), R, T)
    f1, k1 = depth_to_partial(small, K, R, T / 2, object_size=0.5)
    f2, k2 = depth_to_partial(big, K, R, T)
    assert (f1 != f2).sum() <= 0.01 * f2.sum() and (k1 != k2).sum() <= 0.01 * k2.sum()
    assert voxel_size(0.5) == pytest.approx(0.5 / 24)


def test_bad_input(box_view):
    good = box_view
    with pytest.raises(ValueError, match="intrinsics are for 160x120"):
        depth_to_partial(good[:, :100], K, R0, T)
    with pytest.raises(ValueError, match="one image"):
        depth_to_partial(good[None], K, R0, T)
    with pytest.raises(ValueError, match="not a rotation"):
        depth_to_partial(good, K, 2 * R0, T)
    with pytest.raises(ValueError, match="not a rotation"):
        depth_to_partial(good, K, R0 @ np.diag([1, 1, -1.0]), T)    # a reflection
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        depth_to_partial(good, K, np.eye(4), T)
    with pytest.raises(ValueError, match="t must be finite"):
        depth_to_partial(good, K, R0, [0, np.nan, 1.7])
    with pytest.raises(ValueError, match=r"t must have shape \(3,\)"):
        depth_to_partial(good, K, R0, [0, 1.7])
    with pytest.raises(ValueError, match="behind the camera"):
        depth_to_partial(good, K, R0, [0, 0, -1.7])
    for size in (0, -1, np.inf, "big"):
        with pytest.raises(ValueError, match="object_size"):
            depth_to_partial(good, K, R0, T, object_size=size)
    with pytest.raises(ValueError, match="all zero"):
        depth_to_partial(np.zeros_like(good), K, R0, T)
    bad = good.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        depth_to_partial(bad, K, R0, T)
    bad[0, 0] = -1
    with pytest.raises(ValueError, match="negative"):
        depth_to_partial(bad, K, R0, T)
    with pytest.raises(ValueError, match=r"\(M, 3, 3\)"):
        depth_to_partial_many(good, K, R0, T)
    with pytest.raises(ValueError, match="chunk"):
        depth_to_partial_many(good, K, R0[None], T, chunk=0)
    with pytest.raises(TypeError, match="Intrinsics"):
        depth_to_partial(good, (1, 2, 3), R0, T)
