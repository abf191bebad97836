"""BEO baseline on the procedural dataset (ci profile): rendered views, known / 1-DOF / 3-DOF pose.

Renders with embree in this process; no torch here (embree's threads slow torch down)."""
import numpy as np
import pytest

from hbeo import conventions as C
from hbeo.data import datasets
from hbeo.render import renderer as render
from hbeo.baselines.beo import BEO, grid_spacing, so3_grid
from hbeo.errors import DataError
from hbeo.subspace.partial import depth_to_partial_many
from hbeo.render.poses import ViewSampler
from hbeo.render.renderer import Renderer, record_mesh
from hbeo.rotations import geodesic_deg, yaw_elevation_to_matrix, z_angle_to_matrix
from hbeo.subspace.basis import ObjectSubspace

pytestmark = pytest.mark.skipif(not render.embree_available(), reason="embreex not installed")

K = C.Intrinsics.kinect(160, 120)


@pytest.fixture(scope="module")
def data(ci_grids, ci_subspace):
    """The ci run's records, training grids and labels, and its subspace (conftest)."""
    ds = datasets.get_dataset("procedural", profile="ci")
    train, test = datasets.select(ds, "train", "ci"), datasets.select(ds, "test", "ci")
    gs = ci_grids["train"]
    assert list(gs.ids) == [r.id for r in train] and gs.classes == ds.classes
    G, L = gs.grids, np.asarray(gs.labels)
    assert list(L) == [ds.classes.index(r.cls) for r in train]
    return ds, train, test, G, L, ci_subspace


@pytest.fixture(scope="module")
def beo(data):
    _, _, _, G, L, sub = data
    return BEO(sub).fit(G, L)


@pytest.fixture(scope="module")
def views(data):
    """Two upright views of every test object: (label, R, t, depth)."""
    ds, _, test, *_ = data
    rng = np.random.default_rng(0)
    vs = ViewSampler("upright", distance=(1.6, 1.8))
    out = []
    with Renderer(K, backend="embree") as r:
        for rec in test:
            Rs, ts = vs.sample(2, rng)
            depth = r.render_many(record_mesh(rec, 1.0), Rs, ts)
            out += [(ds.classes.index(rec.cls), Rs[i], ts[i], depth[i]) for i in range(2)]
    return out


def render_one(rec, R, t):
    with Renderer(K, backend="embree") as r:
        return r.render(record_mesh(rec, 1.0), R, t)


def test_fit_attributes_and_density_matches_sklearn(beo, data):
    from sklearn.mixture import GaussianMixture
    _, _, _, G, L, sub = data
    k = sub.dim_
    assert beo.means_.shape == (10, 1, k) and beo.precisions_cholesky_.shape == (10, 1, k, k)
    assert np.allclose(beo.class_prior_, 0.1) and beo.noise_var_ > 0
    X = sub.project(G).astype(np.float64)
    gm = GaussianMixture(1, covariance_type="full", reg_covar=beo.reg_covar * beo.coef_scale_,
                         random_state=0).fit(X[L == 2])
    assert np.allclose(beo.log_density(X[:5])[:, 2], gm.score_samples(X[:5]), rtol=1e-6, atol=1e-6)
    two = BEO(sub, n_mixture=2).fit(G, L)
    assert two.means_.shape == (10, 2, k) and np.isfinite(two.log_density(X[:3])).all()


def test_fit_shows_progress_over_the_classes_and_fits_the_same(beo, data, capsys):
    _, _, _, G, L, sub = data
    quiet = capsys.readouterr().err
    again = BEO(sub).fit(G, L, progress=True)
    err = capsys.readouterr().err
    assert "BEO class densities" in err and "10/10" in err and "BEO class densities" not in quiet
    assert np.array_equal(again.means_, beo.means_)


def test_projection_solves_the_normal_equations(beo, data, views):
    """The batched projection equals ObjectSubspace.partial_project, and its residual is the
    squared error of the reconstruction on the known voxels."""
    *_, sub = data
    _, R, t, depth = views[0]
    Rs = np.stack([R, R @ z_angle_to_matrix(0.7), yaw_elevation_to_matrix(2.0, 0.3)])
    f, kn = depth_to_partial_many(depth, K, Rs, t)
    f, kn = f.reshape(3, -1), kn.reshape(3, -1)
    o, sse = beo._project(f, kn)
    ref = sub.partial_project(f, kn, ridge=beo.ridge)
    assert np.allclose(o, ref, atol=2e-3 * np.abs(ref).max())
    rec = o @ sub.basis_.T.astype(np.float64)
    direct = (((rec - f) ** 2) * kn).sum(axis=1)
    assert np.allclose(sse, direct, rtol=1e-3)


def test_known_pose_classifies_well_above_chance(beo, views):
    assert len(views) >= 60
    hits = []
    for label, R, t, depth in views:
        out = beo.predict_view(depth, K, R, t, pose="known")
        assert out["n_candidates"] == 1 and np.allclose(out["rotation"], R)
        p = out["probabilities"]
        assert p.shape == (10,) and abs(p.sum() - 1) < 1e-9 and int(np.argmax(p)) == out["label"]
        assert out["grid"].shape == (30, 30, 30) and out["grid"].dtype == bool
        hits.append(out["label"] == label)
    # chance is 10 %: P(>= 50 % of 60 by chance) < 1e-13 (measured: 87 %)
    assert np.mean(hits) >= 0.5, np.mean(hits)


def test_given_class_restricts_the_search(beo, views):
    label, R, t, depth = views[1]
    other = (label + 3) % 10
    out = beo.predict_view(depth, K, R, t, label_true=other)
    assert out["label"] == other and out["probabilities"][other] == 1.0 and out["probabilities"].sum() == 1.0
    by_name = beo.predict_view(depth, K, R, t, label_true=C.CLASSES[other])
    assert np.array_equal(by_name["coeffs"], out["coeffs"])
    free = beo.predict_view(depth, K, R, t, label_true=other, given_class=False)
    assert free["probabilities"][other] < 1.0


def test_1dof_recovers_a_planted_yaw(beo, data):
    ds, train, test, *_ = data
    rec = next(r for r in test if r.cls == "chair")
    n = beo.pose_bins_1dof
    rng = np.random.default_rng(5)
    for yaw in (0.9, 3.9):
        R_up = yaw_elevation_to_matrix(0.0, np.radians(35))   # fixes the up axis, not the yaw
        R = R_up @ z_angle_to_matrix(yaw)
        t = np.array([0.02, -0.03, 1.7])
        depth = render_one(rec, R, t)
        out = beo.predict_view(depth, K, R_up, t, pose="1dof", label_true="chair", rng=rng)
        assert out["n_candidates"] == n
        err = geodesic_deg(out["rotation"], R)
        assert err <= 360 / n, (yaw, err)


def test_1dof_candidates_are_off_grid_and_reproducible(beo):
    R = yaw_elevation_to_matrix(0.3, 0.5)
    c1 = beo.candidates(R, "1dof", np.random.default_rng(1))
    c2 = beo.candidates(R, "1dof", np.random.default_rng(1))
    assert c1.shape == (36, 3, 3) and np.array_equal(c1, c2)
    yaw = np.sort(np.mod(np.arctan2((R.T @ c1)[:, 1, 0], (R.T @ c1)[:, 0, 0]), 2 * np.pi))
    assert np.allclose(np.diff(yaw), 2 * np.pi / 36)
    assert 0 < yaw[0] < 2 * np.pi / 36                     # the truth (yaw 0) is not a candidate
    g = beo.candidates(R, "3dof", np.random.default_rng(2))
    assert g.shape == (beo.so3_grid, 3, 3)
    assert np.allclose(np.einsum("nji,njk->nik", g, g), np.eye(3), atol=1e-9)
    assert geodesic_deg(g, np.broadcast_to(R, g.shape)).min() > 0.01


def test_3dof_finds_an_easy_object_within_the_grid_spacing(data):
    ds, train, test, G, L, sub = data
    beo = BEO(sub, so3_grid=400).fit(G, L)
    spacing = grid_spacing(so3_grid(400), n_probe=2000)
    rec = next(r for r in test if r.cls == "bed")
    R = yaw_elevation_to_matrix(2.2, np.radians(30))
    t = np.array([0.0, 0.02, 1.7])
    depth = render_one(rec, R, t)
    out = beo.predict_view(depth, K, np.eye(3), t, pose="3dof", label_true="bed", rng=np.random.default_rng(9))
    assert out["n_candidates"] == 400
    err = geodesic_deg(out["rotation"], R)
    assert err <= spacing["nn_max"], (err, spacing)


def test_so3_grid_is_near_uniform():
    s = grid_spacing(so3_grid(512), n_probe=3000)
    assert s["nn_max"] < 1.3 * s["nn_mean"] and s["cover_max"] < 32 and s["nn_mean"] > 20


def test_surface_points_outside_the_grid_lower_the_joint_score(beo, views, monkeypatch):
    """Observed surface points that a candidate pose puts outside the grid count as unexplained filled voxels:
    each costs 1 / (2 s^2) of the joint score, so a candidate that loses points off the grid scores worse than
    one with the same partial grid that keeps them in."""
    from hbeo.baselines import beo as beo_module
    label, R, t, depth = views[0]
    real = beo_module.iter_partial
    extra = {}                                                       # candidate index -> points off the grid

    def off_grid(*args, **kwargs):
        for a, f, kn, outside in real(*args, **kwargs):
            add = np.array([extra.get(a + i, 0) for i in range(len(f))])
            yield a, f, kn, outside + add

    monkeypatch.setattr(beo_module, "iter_partial", off_grid)
    inside = beo.predict_view(depth, K, R, t, label_true=label, given_class=True)
    extra[0] = 40
    out = beo.predict_view(depth, K, R, t, label_true=label, given_class=True)
    assert np.array_equal(out["coeffs"], inside["coeffs"])          # the same grid: only the score moves
    assert out["score"] == pytest.approx(inside["score"] - 40 / (2 * beo.noise_var_), rel=1e-9)
    # 1-DOF: the candidate the search picks loses its points off the grid -> another candidate wins
    rng = 3
    extra.clear()
    first = beo.predict_view(depth, K, R, t, pose="1dof", label_true=label, given_class=True, rng=rng)
    Rs = beo.candidates(R, "1dof", np.random.default_rng(rng))
    best = int(np.argmin(geodesic_deg(Rs, np.broadcast_to(first["rotation"], Rs.shape))))
    assert np.allclose(Rs[best], first["rotation"])
    extra[best] = 10_000
    second = beo.predict_view(depth, K, R, t, pose="1dof", label_true=label, given_class=True, rng=rng)
    assert not np.allclose(second["rotation"], Rs[best]) and second["score"] < first["score"]


def test_paper_score_is_available(data, views, beo):
    *_, G, L, sub = data
    paper = BEO(sub, score="paper").fit(G, L)
    label, R, t, depth = views[2]
    a = paper.predict_view(depth, K, R, t)
    assert a["probabilities"].shape == (10,) and a["label"] == label          # an easy view: the true class
    # the paper's score is log D(o' | c) + log P(c) + log P(r) alone (no residual term), maximized over c
    d = paper.log_density(a["coeffs"].astype(np.float64))[0] + np.log(paper.class_prior_)
    assert a["label"] == int(np.argmax(d)) and a["score"] == pytest.approx(d.max(), rel=1e-5)
    assert np.allclose(a["probabilities"], np.exp(d - d.max()) / np.exp(d - d.max()).sum(), atol=1e-4)
    joint = beo.predict_view(depth, K, R, t, label_true=a["label"], given_class=True)      # the joint score
    assert np.allclose(joint["coeffs"], a["coeffs"])                 # the same projection ...
    assert joint["score"] < a["score"] - 1                           # ... less the residual's log-likelihood
    # known pose: the true class wins on most views (chance 10 %; measured 87 %)
    hits = [paper.predict_view(dep, K, Rv, tv)["label"] == lab for lab, Rv, tv, dep in views]
    assert np.mean(hits) >= 0.5, np.mean(hits)


def test_save_load_round_trip(beo, views, tmp_path):
    path = beo.save(tmp_path / "beo.npz")
    back = BEO.load(path)
    assert back.classes_ == beo.classes_ and back.get_params() == beo.get_params()
    assert back.noise_var_ == beo.noise_var_ and np.array_equal(back.subspace.basis_, beo.subspace.basis_)
    _, R, t, depth = views[3]
    for pose in ("known", "1dof"):
        a = beo.predict_view(depth, K, R, t, pose=pose, rng=4)
        b = back.predict_view(depth, K, R, t, pose=pose, rng=4)
        assert np.array_equal(a["probabilities"], b["probabilities"]) and np.array_equal(a["rotation"], b["rotation"])
        assert np.array_equal(a["grid"], b["grid"])
    assert not list(tmp_path.glob(".*.tmp"))               # atomic write left nothing behind


def test_bad_files(tmp_path, beo):
    with pytest.raises(DataError, match="no such BEO file"):
        BEO.load(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip file")
    with pytest.raises(DataError, match="junk.npz: not a readable BEO file"):
        BEO.load(junk)
    sub_only = tmp_path / "sub.npz"
    beo.subspace.save(sub_only)
    with pytest.raises(DataError, match="not a readable BEO file"):
        BEO.load(sub_only)


def test_bad_input(data, beo, views):
    *_, G, L, sub = data
    label, R, t, depth = views[0]
    with pytest.raises(RuntimeError, match="not fitted"):
        BEO(sub).predict_view(depth, K, R, t)
    with pytest.raises(ValueError, match="fitted ObjectSubspace"):
        BEO(ObjectSubspace())
    with pytest.raises(ValueError, match="score"):
        BEO(sub, score="best")
    with pytest.raises(ValueError, match="so3_grid"):
        BEO(sub, so3_grid=0)
    with pytest.raises(ValueError, match="reg_covar"):
        BEO(sub, reg_covar=0)
    with pytest.raises(ValueError, match=r"grids must be \(N, 30, 30, 30\)"):
        BEO(sub).fit(G[:, :10], L)
    with pytest.raises(ValueError, match="labels"):
        BEO(sub).fit(G, L[:-1])
    with pytest.raises(ValueError, match="no training grids"):
        BEO(sub).fit(G[L < 9], L[L < 9])
    with pytest.raises(ValueError, match="pose must be one of"):
        beo.predict_view(depth, K, R, t, pose="6dof")
    with pytest.raises(ValueError, match="unknown class"):
        beo.predict_view(depth, K, R, t, label_true="lamp")
    with pytest.raises(ValueError, match="label_true"):
        beo.predict_view(depth, K, R, t, label_true=10)
    with pytest.raises(ValueError, match=r"R_true must have shape \(3, 3\)"):
        beo.predict_view(depth, K, R[:2], t)
    with pytest.raises(ValueError, match="not a rotation"):
        beo.predict_view(depth, K, 2 * R, t)
    with pytest.raises(ValueError, match="intrinsics are for"):
        beo.predict_view(depth[:50], K, R, t)
    with pytest.raises(ValueError, match="all zero"):
        beo.predict_view(np.zeros_like(depth), K, R, t)
    with pytest.raises(TypeError, match="rng"):
        beo.predict_view(depth, K, R, t, pose="1dof", rng="seed")
