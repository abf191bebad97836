"""predict --face-object (hbeo.model.facing): the view turns toward the estimated centre, only beyond the
training shift, and the two passes give answers in the camera's frame."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hbeo.conventions import Intrinsics
from hbeo.model import facing
from hbeo.model.verify import shape_depth, surface_points

K = Intrinsics.kinect(80, 60)
SHIFT = 0.05


def _box():
    g = np.zeros((30, 30, 30), bool)
    g[9:21, 9:21, 9:21] = True
    return g


def _stub(shape):
    """What :func:`facing.aims` reads of a model: settings (shift, object size), the model camera, the paper's grid."""
    return SimpleNamespace(settings=SimpleNamespace(render={"shift": SHIFT}, object_size=1.0), intrinsics=K,
                           paper_grids=lambda coeffs: shape[None])


def _first(t, n=1):
    """A step-1 answer: the true pose (identity), a centre off by 5 cm along the view ray's side, scale 1."""
    return SimpleNamespace(rotation=np.eye(3)[None].repeat(n, 0), translation=np.asarray(t, float)[None] + [0.05, 0, 0],
                           scale=np.ones(n), coeffs=np.zeros((n, 3)))


@pytest.mark.parametrize("off", [0.0, 0.03])
def test_an_object_within_the_training_shift_is_answered_as_it_is(off):
    t = np.array([off * 1.7, 0.0, 1.7])
    d = shape_depth(surface_points(_box(), 1.0), np.eye(3), t, K)
    assert facing.aims(_stub(_box()), d[None], [None], K, _first(t)) == [facing.PLAIN]


def test_an_object_far_off_is_turned_by_the_part_beyond_the_shift():
    """The estimate (the shape aligned to the depth) is the true centre, 3 shifts off; the turn is 2 shifts' worth,
    so the centre lands at the edge of the training range."""
    t = np.array([3 * SHIFT * 1.7, 0.0, 1.7])
    d = shape_depth(surface_points(_box(), 1.0), np.eye(3), t, K)
    (aim,) = facing.aims(_stub(_box()), d[None], [None], K, _first(t))
    assert aim[2] == 1.0 and aim[0] == pytest.approx(2 * SHIFT, abs=0.01) and abs(aim[1]) < 0.01
    mask = np.zeros_like(d, bool)                  # a mask that hides the object's left half: another estimate
    mask[:, : int(np.flatnonzero(d.any(0)).mean())] = True
    assert facing.aims(_stub(_box()), d[None], [~mask], K, _first(t))[0] is not facing.PLAIN


def test_no_shape_to_align_falls_back_to_the_points_median():
    t = np.array([3 * SHIFT * 1.7, 0.0, 1.7])
    d = shape_depth(surface_points(_box(), 1.0), np.eye(3), t, K)
    assert facing.aims(_stub(np.zeros((30, 30, 30), bool)), d[None], [None], K, _first(t)) == [facing.MEDIAN]


def test_face_object_answers_the_second_pass_in_the_cameras_frame(tiny_model):
    """predict with face_object: step 1 turned to the points' median, step 2 the view :func:`facing.aims` gives,
    its rotation brought back to the camera frame (Q @ the network's), and its timing counts both passes; without
    it, and for a model trained with recentering, face_object changes nothing."""
    import torch
    from conftest import box_grids
    for recenter in (False, True):
        m = tiny_model({"recenter": recenter, "render": {"shift": SHIFT}}, mean_grids=box_grids())
        Km = m.intrinsics
        t = np.array([3 * SHIFT * 1.7, 0.01, 1.7])
        d = shape_depth(surface_points(_box(), m.settings.object_size), np.eye(3), t, Km)
        plain = m.predict(d, Km)
        faced = m.set_face_object(True).predict(d, Km)
        if recenter:                                  # trained so: the model's own turn, one pass
            np.testing.assert_array_equal(faced.rotation, plain.rotation)
            continue
        with torch.inference_mode():                  # as predict runs them
            first = m._predict(d, Km, None, 1, 0.0, facing.MEDIAN)
            (aim,) = facing.aims(m, d[None], [None], Km, first)
            assert not isinstance(aim, str)            # 3 shifts off: turned
            second = m._predict(d, Km, None, 1, 0.0, [aim])
        np.testing.assert_allclose(faced.probabilities, second.probabilities)
        np.testing.assert_allclose(faced.rotation, second.rotation)
        Q = faced.view_rotation[0]
        np.testing.assert_allclose(Q[:, 2], aim / np.linalg.norm(aim), atol=1e-12)
        net = m.set_face_object(False).predict(m.view(d, Km, aim=aim).depth, Km)   # the turned view, plain
        np.testing.assert_allclose(faced.rotation[0], Q @ net.rotation[0], atol=1e-6)
        assert not np.allclose(faced.rotation, plain.rotation)
        assert faced.timing_ms["total"] > second.timing_ms["network"]


def test_notebook_08_shows_the_view_the_network_answered(tiny_model):
    """yourdepth.network_aim: the view of a face_object answer is its turned one (the same Q), an unturned answer's
    is the frame as it is, and without an answer the model's own setting."""
    from conftest import box_grids
    from hbeo.lessons.yourdepth import network_aim
    m = tiny_model({"recenter": False, "render": {"shift": SHIFT}}, mean_grids=box_grids()).set_face_object(True)
    Km = m.intrinsics
    d = shape_depth(surface_points(_box(), 1.0), np.eye(3), np.array([3 * SHIFT * 1.7, 0.01, 1.7]), Km)
    pred = m.predict(d, Km)
    Q = pred.view_rotation[0]
    assert not np.allclose(Q, np.eye(3))
    np.testing.assert_allclose(m.view(d, Km, aim=network_aim(m, pred)).Q, Q, atol=1e-12)
    plain = m.set_face_object(False).predict(d, Km)
    assert network_aim(m, plain) == "plain" and network_aim(m, None) is None
