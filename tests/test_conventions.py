import numpy as np
import pytest

from hbeo import conventions as C


def test_layout_constants():
    assert C.RESOLUTION == 30 and C.OBJECT_VOXELS == 24 and C.MARGIN == 3
    assert C.CLASSES[0] == "bathtub" and C.CLASSES[-1] == "toilet" and len(C.CLASSES) == 10
    assert C.class_index("night_stand") == 6
    with pytest.raises(ValueError, match="unknown class 'lamp'"):
        C.class_index("lamp")


def test_grid_transform_longest_side_spans_24_voxels_centred():
    v = np.array([[-1.0, 0, 2], [3, 1, 4], [0, 0.5, 3]])        # extents 4, 1, 2
    center, scale = C.grid_transform(v)
    u = C.object_to_grid(v, center, scale)
    assert np.allclose(u.min(0)[0], 3) and np.allclose(u.max(0)[0], 27)
    assert np.allclose((u.min(0) + u.max(0)) / 2, 15)          # centred on every axis
    assert np.allclose(C.grid_to_object(u, center, scale), v)   # round trip


def test_grid_transform_rejects_degenerate():
    with pytest.raises(ValueError, match="degenerate"):
        C.grid_transform(np.zeros((4, 3)))


def test_voxel_centers_match_index_order():
    c = C.voxel_centers()
    assert c.shape == (30, 30, 30, 3)
    assert np.allclose(c[2, 5, 7], [2.5, 5.5, 7.5])
