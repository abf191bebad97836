"""SensorNoise computed in the window around the object equals the whole frame's, bit for bit, and the
grazing-angle normals (x, y, z kept apart) equal the (H, W, 3) vector form they replace."""
import numpy as np
import pytest

from hbeo import conventions as C
from hbeo.render.noise import SensorNoise, _grazing_cos

K = C.Intrinsics.kinect(80, 60)


def _frame(seed: int) -> np.ndarray:
    """A curved, tilted surface patch with holes, anywhere in the frame (often cut by its edge)."""
    g = np.random.default_rng(seed)
    v, u = np.mgrid[0:60, 0:80].astype(np.float32)
    r0, c0 = g.integers(-8, 58), g.integers(-8, 78)
    h, w = g.integers(1, 35, 2)
    inside = (v >= r0) & (v < r0 + h) & (u >= c0) & (u < c0 + w)
    d = (1.0 + 0.02 * (u - c0) + 0.3 * np.sin(v / 4.0) + 0.01 * g.random((60, 80))).astype(np.float32)
    d[~inside | (g.random((60, 80)) < 0.08)] = 0
    return d


def _grazing_cos_vectors(depth, K):
    """The vector form: points (H, W, 3), np.cross and norms over the last axis."""
    H, W = depth.shape
    z = depth.astype(np.float64)
    valid = z > 0
    u, v = (np.arange(W) - K.cx) / K.fx, (np.arange(H) - K.cy) / K.fy
    P = np.stack([z * u[None, :], z * v[:, None], z], -1)

    def tangent(axis):
        sa, sb = [slice(None)] * 2, [slice(None)] * 2
        sa[axis], sb[axis] = slice(0, -1), slice(1, None)
        sa, sb = tuple(sa), tuple(sb)
        fwd, ok_f = np.zeros_like(P), np.zeros((H, W), bool)
        fwd[sa], ok_f[sa] = P[sb] - P[sa], valid[sb] & valid[sa]
        bwd, ok_b = np.zeros_like(P), np.zeros((H, W), bool)
        bwd[sb], ok_b[sb] = fwd[sa], ok_f[sa]
        both = ok_f & ok_b
        return np.where(both[..., None], (fwd + bwd) / 2, np.where(ok_f[..., None], fwd, bwd)), ok_f | ok_b

    (tu, ok_u), (tv, ok_v) = tangent(1), tangent(0)
    n = np.cross(tu, tv)
    nn, pn = np.linalg.norm(n, axis=-1), np.linalg.norm(P, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        c = np.abs((n * P).sum(-1)) / (nn * pn)
    return np.where(valid & ok_u & ok_v & (nn > 0), c, 1.0)


@pytest.mark.parametrize("noise", [SensorNoise(), SensorNoise(seg_px=4, edge_p=0.6, grazing_deg=60),
                                   SensorNoise(seg_px=0)])
def test_window_equals_whole_frame(noise):
    cut = 0
    for seed in range(60):
        d = _frame(seed)
        if not (d > 0).any():
            continue
        cut += (d[0] > 0).any() or (d[:, 0] > 0).any() or (d[-1] > 0).any() or (d[:, -1] > 0).any()
        fast = noise.apply(d, K, np.random.default_rng(seed))
        whole = noise._apply_box(d, K, np.random.default_rng(seed), (0, 60, 0, 80))
        assert np.array_equal(fast, whole), seed
    assert cut >= 10                     # objects cut by the frame's edge were among them


def test_grazing_cos_window_and_vector_form_agree():
    for seed in range(30):
        d = _frame(seed)
        full = _grazing_cos(d, K)
        assert np.array_equal(full, _grazing_cos_vectors(d, K)), seed
        rows, cols = np.flatnonzero((d > 0).any(1)), np.flatnonzero((d > 0).any(0))
        if len(rows):
            r0, c0 = rows[0], cols[0]
            win = _grazing_cos(d[r0:rows[-1] + 1, c0:cols[-1] + 1], K, (r0, c0))
            assert np.array_equal(win, full[r0:rows[-1] + 1, c0:cols[-1] + 1]), seed
