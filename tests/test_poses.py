"""The readings of the view protocol (hbeo.render.poses.SAMPLERS): each sampler's distribution, its
determinism, the pairing of query views under each, and the names everywhere a sampler is named."""
import json

import numpy as np
import pytest
from scipy import stats

from hbeo.render.poses import SAMPLERS, ViewSampler, check_sampler, sample_rotations
from hbeo.rotations import matrix_to_axis_angle, uniform_so3, yaw_elevation_to_matrix

N = 4000


def angles(R):
    """(yaw, elevation, roll) of rotations R = Rz(roll) @ E(elevation) @ Rz(yaw), read off R's entries:
    the camera's axis in object axes is R[2, :] = (sin y cos e, cos y cos e, -sin e); the object's up
    axis in camera axes is R[:, 2] = (cos e sin r, -cos e cos r, -sin e)."""
    yaw = np.arctan2(R[:, 2, 0], R[:, 2, 1]) % (2 * np.pi)
    elev = np.arcsin(np.clip(-R[:, 2, 2], -1, 1))
    roll = np.arctan2(R[:, 0, 2], -R[:, 1, 2]) % (2 * np.pi)
    return yaw, elev, roll


def haar_angle_cdf(theta):
    """CDF of the rotation angle of a Haar-uniform rotation."""
    return (theta - np.sin(theta)) / np.pi


def rotation_angle(R):
    return np.linalg.norm(matrix_to_axis_angle(R), axis=1)


def uniform_cdf(lo, hi):
    return stats.uniform(lo, hi - lo).cdf


def test_the_sampler_names_and_their_check():
    assert SAMPLERS[0] == "so3" and set(SAMPLERS) == {"so3", "upright", "sphere", "floor"}
    for s in SAMPLERS:
        assert check_sampler(s) == s and ViewSampler(s).sampler == s
    for bad in ("random", "SO3", "", None):
        with pytest.raises(ValueError, match="unknown sampler"):
            check_sampler(bad)


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_every_sampler_draws_rotations_deterministically(sampler):
    a, ta = ViewSampler(sampler).sample(50, np.random.default_rng(3))
    b, tb = ViewSampler(sampler).sample(50, np.random.default_rng(3))
    c, _ = ViewSampler(sampler).sample(50, np.random.default_rng(4))
    assert np.array_equal(a, b) and np.array_equal(ta, tb) and not np.allclose(a, c)
    assert np.allclose(a @ np.swapaxes(a, 1, 2), np.eye(3), atol=1e-9) and np.allclose(np.linalg.det(a), 1)


@pytest.mark.parametrize("sampler", SAMPLERS)
def test_one_view_from_each_generator_is_each_generators_own_sample(sampler):
    """sample_each (a streamed batch: one generator per image) gives, bit for bit, sample(1, g) of each g."""
    vs = ViewSampler(sampler, distance=(1.5, 1.9), shift=0.1)
    R, t = vs.sample_each([np.random.default_rng([5, i]) for i in range(9)])
    one = [vs.sample(1, np.random.default_rng([5, i])) for i in range(9)]
    assert np.array_equal(R, np.concatenate([r for r, _ in one])) and np.array_equal(t, np.concatenate([x for _, x in one]))
    assert R.shape == (9, 3, 3) and t.shape == (9, 3) and len({r.tobytes() for r in R}) == 9


def test_so3_and_upright_draw_what_they_always_drew():
    """The existing readings' draws are unchanged (cached results and rendered sets stay valid): so3 is
    uniform_so3 then depths then offsets; upright is yaw then elevation, no roll."""
    vs = ViewSampler("so3")
    R, t = vs.sample(7, np.random.default_rng(11))
    g = np.random.default_rng(11)
    assert np.array_equal(R, uniform_so3(7, g)) and np.array_equal(t[:, 2], g.uniform(1.4, 2.0, 7))
    R, _ = ViewSampler("upright").sample(7, np.random.default_rng(12))
    g = np.random.default_rng(12)
    assert np.array_equal(R, yaw_elevation_to_matrix(g.uniform(0, 2 * np.pi, 7), g.uniform(*np.radians((10, 50)), 7)))


def test_sphere_is_the_same_distribution_as_so3():
    """A uniform direction on the view sphere plus a uniform roll is the Haar measure: the rotation angle
    follows (theta - sin theta) / pi, every entry of R has the Haar law, and the two-sample tests
    against so3's own draws find no difference (fixed seeds, generous thresholds)."""
    sphere = sample_rotations("sphere", N, np.random.default_rng(20))
    so3 = sample_rotations("so3", N, np.random.default_rng(21))
    assert stats.kstest(rotation_angle(sphere), haar_angle_cdf).pvalue > 0.01
    for i in range(3):
        for j in range(3):       # every entry of a Haar rotation is uniform on [-1, 1]
            assert stats.kstest(sphere[:, i, j], uniform_cdf(-1, 1)).pvalue > 0.001, (i, j)
            assert stats.ks_2samp(sphere[:, i, j], so3[:, i, j]).pvalue > 0.001, (i, j)
    assert stats.ks_2samp(rotation_angle(sphere), rotation_angle(so3)).pvalue > 0.01
    # pairs of entries: Haar is invariant under R -> R @ Q, so the angle of R @ Q is Haar too
    Q = yaw_elevation_to_matrix(0.7, 0.3)
    assert stats.kstest(rotation_angle(sphere @ Q), haar_angle_cdf).pvalue > 0.01


def test_the_same_distribution_test_can_fail():
    """The tests above reject floor (no view from below) and a sphere sampler whose elevation is
    uniform in angle instead of in area (views bunched at the poles)."""
    floor = sample_rotations("floor", N, np.random.default_rng(22))
    so3 = sample_rotations("so3", N, np.random.default_rng(21))
    assert stats.kstest(rotation_angle(floor), haar_angle_cdf).pvalue < 1e-6
    assert stats.ks_2samp(floor[:, 2, 2], so3[:, 2, 2]).pvalue < 1e-6
    from hbeo.rotations import yaw_elevation_roll_to_matrix
    g = np.random.default_rng(23)
    wrong = yaw_elevation_roll_to_matrix(g.uniform(0, 2 * np.pi, N), g.uniform(-np.pi / 2, np.pi / 2, N),
                                         g.uniform(0, 2 * np.pi, N))
    assert stats.kstest(wrong[:, 2, 2], uniform_cdf(-1, 1)).pvalue < 1e-6


@pytest.mark.parametrize("sampler", ["sphere", "floor"])
def test_roll_and_yaw_are_uniform_and_the_elevation_uniform_in_area(sampler):
    R = sample_rotations(sampler, N, np.random.default_rng(30))
    yaw, elev, roll = angles(R)
    assert stats.kstest(roll, uniform_cdf(0, 2 * np.pi)).pvalue > 0.01
    assert stats.kstest(yaw, uniform_cdf(0, 2 * np.pi)).pvalue > 0.01
    lo = -1.0 if sampler == "sphere" else 0.0
    assert stats.kstest(np.sin(elev), uniform_cdf(lo, 1.0)).pvalue > 0.01
    assert stats.kstest(elev, uniform_cdf(np.arcsin(lo), np.pi / 2)).pvalue < 1e-6   # not uniform in angle


def test_upright_has_no_roll_and_the_uniform_roll_test_can_fail():
    _, elev, roll = angles(sample_rotations("upright", 500, np.random.default_rng(31)))
    assert np.allclose(np.minimum(roll, 2 * np.pi - roll), 0, atol=1e-9)
    assert np.radians(10) <= elev.min() and elev.max() <= np.radians(50)
    assert stats.kstest(roll, uniform_cdf(0, 2 * np.pi)).pvalue < 1e-6


def test_floor_views_are_from_above_the_objects_horizon():
    """Every floor view looks down (elevation in (0, 90] degrees: the object's up axis points toward
    the camera); the camera's centre is above the object centre's horizon except by at most
    sqrt(2) * shift * depth at grazing elevations (the object's offset from the optical axis)."""
    vs = ViewSampler("floor")
    R, t = vs.sample(N, np.random.default_rng(32))
    _, elev, _ = angles(R)
    assert (elev > 0).all() and (elev <= np.pi / 2 + 1e-12).all() and (R[:, 2, 2] < 0).all()
    height = -np.einsum("nij,ni->nj", R, t)[:, 2]          # camera centre, object axes: -R^T t
    assert (height >= -np.sqrt(2) * vs.shift * t[:, 2] - 1e-12).all()
    assert (height[elev > np.arctan(np.sqrt(2) * vs.shift)] > 0).all()
    # so3 and sphere look from below half the time
    for s in ("so3", "sphere"):
        below = (sample_rotations(s, N, np.random.default_rng(33))[:, 2, 2] > 0).mean()
        assert 0.45 < below < 0.55, s


def test_query_views_are_paired_under_each_reading():
    """Under one sampler view j of an object is the same pose however many views are asked for;
    under two samplers the same stream gives different poses (paired by object and view, not image)."""
    from hbeo.data.datasets import ObjectRecord
    from hbeo.render.views import RenderSettings, query_rng
    rec = ObjectRecord(cls="chair", split="test", id="chair_0890")

    def poses(sampler, views):
        vs = RenderSettings(sampler=sampler).view_sampler
        return np.concatenate([vs.sample(1, query_rng(0, "test", rec, j))[0] for j in range(views)])

    for s in SAMPLERS:
        assert np.array_equal(poses(s, 3)[:1], poses(s, 1))
    for a in SAMPLERS:
        for b in SAMPLERS:
            if a != b:
                assert not np.allclose(poses(a, 2), poses(b, 2)), (a, b)


def test_the_rendered_query_views_follow_the_sampler(monkeypatch):
    """ObjectViews.query_views draws its poses with the settings' sampler from query_rng: the same
    arrays twice, view 0 the same for 1 or 2 views (the depth is not compared: the renderer is stubbed)."""
    from hbeo.data.datasets import ObjectRecord
    from hbeo.render.views import ObjectViews, RenderSettings, query_rng
    rec = ObjectRecord(cls="chair", split="test", id="chair_0890")
    rs = RenderSettings(image_size=(8, 6), sampler="floor")
    viewer = ObjectViews(rs)
    monkeypatch.setattr(viewer, "_mesh_depth", lambda record, R, t: np.ones((len(R), 6, 8), np.float32))
    a, b, one = viewer.query_views(rec, "test", 2), viewer.query_views(rec, "test", 2), viewer.query_views(rec, "test", 1)
    assert np.array_equal(a["rotation"], b["rotation"]) and np.array_equal(a["rotation"][:1], one["rotation"])
    want = rs.view_sampler.sample(1, query_rng(0, "test", rec, 1))[0][0]
    assert np.allclose(a["rotation"][1], want, atol=1e-6) and (a["rotation"][:, 2, 2] < 0).all()


@pytest.mark.parametrize("command", [
    ["evaluate", "--model", "m.hbeo", "--out", "o.json"], ["render"], ["train"]])
@pytest.mark.parametrize("sampler", SAMPLERS)
def test_the_command_line_takes_every_reading(command, sampler):
    from hbeo.cli import build_parser
    assert build_parser().parse_args(command + ["--sampler", sampler]).sampler == sampler


def test_the_command_line_refuses_an_unknown_reading(capsys):
    from hbeo.cli import build_parser
    with pytest.raises(SystemExit):
        build_parser().parse_args(["evaluate", "--model", "m.hbeo", "--out", "o.json", "--sampler", "hemisphere"])
    assert "invalid choice: 'hemisphere'" in capsys.readouterr().err


def test_model_settings_take_every_reading_and_refuse_others_naming_the_file(tmp_path):
    from hbeo.errors import DataError
    from hbeo.model.modelfile import ModelSettings
    for s in SAMPLERS:
        assert ModelSettings.from_dict({"render": {"sampler": s}}).render["sampler"] == s
    assert ModelSettings.from_dict({"render": {}}).render == {}     # files that record none
    f = tmp_path / "model.hbeo"
    with pytest.raises(DataError, match=r"model\.hbeo.*render\.sampler.*'hemisphere'"):
        ModelSettings.from_dict({"render": {"sampler": "hemisphere"}}, source=f)


def test_each_reading_has_its_own_evaluation_file(tmp_path):
    from hbeo.rundir import RunDir
    run = RunDir(tmp_path)
    assert run.evaluation("hbeo", "3dof") == tmp_path / "eval_hbeo_3dof.json"
    assert run.evaluation("hbeo", "3dof", "floor") == tmp_path / "eval_hbeo_3dof_floor.json"
    assert len({run.evaluation("beo", "known", s) for s in SAMPLERS}) == len(SAMPLERS)
    with pytest.raises(ValueError):
        run.evaluation("hbeo", "3dof", "../x")


def test_the_protocol_caches_each_reading_under_its_own_request(tmp_path, monkeypatch):
    """evaluation(sampler=...) reads eval_<method>_<pose>_<sampler>.json only when its request names that
    reading; the model's own sampler maps to the plain file; an unknown reading is refused."""
    from hbeo.errors import DataError
    from hbeo.evaluation import protocol
    from hbeo.run import Run
    from hbeo.rundir import RunDir

    class Fake:                                 # the model: its training sampler is all that is read
        settings = type("S", (), {"render": {"sampler": "so3"}})()

    run = RunDir(tmp_path).create()
    run.model.write_bytes(b"not a model")
    run.baseline("beo").write_bytes(b"not a baseline")
    r = Run.open("ci", "procedural", run.path)
    monkeypatch.setattr(Run, "model", lambda self, progress=True: Fake())
    for s in ("floor", "sphere", None):
        req = protocol.request(r, "beo", "3dof", s)
        assert req["sampler"] == s
        run.evaluation("beo", "3dof", s).write_text(json.dumps({"accuracy": {"floor": 0.1, "sphere": 0.2}.get(s, 0.3),
                                                                "request": req}))
    assert protocol.evaluation(r, "beo", "3dof", sampler="floor")["accuracy"] == 0.1
    assert protocol.evaluation(r, "beo", "3dof", sampler="sphere")["accuracy"] == 0.2
    assert protocol.evaluation(r, "beo", "3dof", sampler="so3")["accuracy"] == 0.3     # the model's own
    assert protocol.evaluation(r, "beo", "3dof")["accuracy"] == 0.3
    assert [m["accuracy"] for m in protocol.evaluations(r, [("beo", "3dof")], sampler="floor")] == [0.1]
    with pytest.raises(ValueError, match="unknown sampler"):
        protocol.evaluation(r, "beo", "3dof", sampler="hemisphere")
    # a file whose request names another reading is not read: the evaluation runs (and fails on the fake files)
    run.evaluation("beo", "3dof", "floor").write_text(json.dumps({"accuracy": 0.1,
                                                                  "request": protocol.request(r, "beo", "3dof", "sphere")}))
    with pytest.raises((DataError, AttributeError, TypeError)):
        protocol.evaluation(r, "beo", "3dof", sampler="floor")
