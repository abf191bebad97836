import numpy as np
import pytest
import trimesh

from hbeo.errors import DataError
from hbeo.data.voxel import sample_triangles, voxelize


def iou(a, b):
    return (a & b).sum() / (a | b).sum()


def test_box_has_exact_known_grid():
    # extents 2 x 0.9 x 0.55 -> 24 x 10.8 x 6.6 voxels, centred on 15: x 3..26, y 9..20, z 11..18
    g = voxelize(trimesh.creation.box((2.0, 0.9, 0.55)))
    expected = np.zeros((30, 30, 30), bool)
    expected[3:27, 9:21, 11:19] = True
    assert g.dtype == bool and g.shape == (30, 30, 30)
    assert np.array_equal(g, expected)


def test_sphere_is_a_solid_ball():
    g = voxelize(trimesh.creation.icosphere(subdivisions=4))
    c = np.stack(np.meshgrid(*[np.arange(30) + 0.5] * 3, indexing="ij"), -1)
    r = np.linalg.norm(c - 15, axis=-1)                  # radius 12 voxels, centre 15
    assert g[r <= 12 - np.sqrt(3) / 2].all()              # every voxel wholly inside is filled
    assert not g[r > 12 + np.sqrt(3) / 2].any()           # no voxel the sphere cannot touch


def test_mesh_with_open_faces_is_still_filled():
    s = trimesh.creation.icosphere(subdivisions=2)
    full = voxelize(s)
    holed = voxelize(trimesh.Trimesh(s.vertices, s.faces[3:], process=False))   # three faces missing
    assert holed.sum() >= 0.99 * full.sum()
    assert holed[15, 15, 15]


def test_open_basin_stays_empty():
    box = trimesh.creation.box((1, 1, 1))
    top = box.triangles_center[:, 2] > 0.49
    basin = voxelize(trimesh.Trimesh(box.vertices, box.faces[~top], process=False))
    assert not basin[15, 15, 15]                       # the tub's inside is not filled
    assert basin[15, 15, 3] and basin[3, 15, 15]       # floor and walls are there
    assert basin.sum() < 0.3 * voxelize(box).sum()


def test_overlapping_and_self_intersecting_parts():
    a = trimesh.creation.box((1, 1, 1))
    b = trimesh.creation.box((1, 1, 1))
    b.apply_translation((0.5, 0.0, 0.0))
    g = voxelize(trimesh.util.concatenate([a, b]))
    assert g[3:27, 10:19, 10:19].all()                 # union filled, no cavity at the overlap


@pytest.mark.parametrize("verts, faces, msg", [
    (np.zeros((3, 3)), [[0, 1, 2]], "all vertices coincide"),
    (np.zeros((0, 3)), np.zeros((0, 3), int), "no vertices"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), int), "no triangle faces"),
    ([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]], "NaN"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 5]], "face 0 refers to vertex 5 but the mesh has 3 vertices"),
])
def test_degenerate_meshes_raise(verts, faces, msg):
    with pytest.raises(DataError, match=msg):
        voxelize((np.asarray(verts, float), np.asarray(faces)))


def test_degenerate_file_is_named(tmp_path):
    p = tmp_path / "flat.off"
    p.write_text("OFF\n3 1 0\n1 1 1\n1 1 1\n1 1 1\n3 0 1 2\n")
    with pytest.raises(DataError, match=r"flat\.off: degenerate"):
        voxelize(p)


def test_sampling_covers_every_point_within_step():
    from scipy.spatial import cKDTree
    rng = np.random.default_rng(0)
    tri = rng.normal(size=(100, 3, 3)) * 4
    tri[:30, 2] = (tri[:30, 0] + tri[:30, 1]) / 2 + 0.01      # needles
    pts = sample_triangles(tri, 0.5)
    r1, r2 = rng.random((2, 100, 64))
    flip = r1 + r2 > 1
    r1[flip], r2[flip] = 1 - r1[flip], 1 - r2[flip]
    q = tri[:, None, 0] + r1[..., None] * (tri[:, None, 1] - tri[:, None, 0]) \
        + r2[..., None] * (tri[:, None, 2] - tri[:, None, 0])
    assert cKDTree(pts).query(q.reshape(-1, 3))[0].max() <= 0.5
    assert len(sample_triangles(tri[:30], 0.5)) < 30 * 200   # needles cost little


def test_real_modelnet_bathtubs_match_3dshapenets_grids(sample_dir, vox30):
    """Voxelizing the real .off files reproduces the published 30^3 grids (mean IoU >= 0.6)."""
    names = list(vox30["names_train"])
    ious = {}
    for i in range(1, 6):
        name = f"bathtub_{i:04d}"
        ref = vox30["X_train"][names.index(name)].astype(bool)
        ious[name] = iou(voxelize(sample_dir / "bathtub" / "train" / f"{name}.off"), ref)
    print("IoU per object:", {k: round(float(v), 3) for k, v in ious.items()})
    assert np.mean(list(ious.values())) >= 0.6, ious
    assert min(ious.values()) > 0.3, ious
