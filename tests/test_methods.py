"""The Method contract (hbeo.evaluation.method), checked like scikit-learn's check_estimator: every
registered method (HBEO through its adapter, BEO, ICP, the 3-D CNN) built small on synthetic boxes
answers one rendered view at each of its pose settings with a well-formed, deterministic answer.
A new baseline adds a factory to FACTORIES and must pass every check here."""
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from hbeo.baselines.beo import BEO
from hbeo.baselines.icp import ICPBaseline
from hbeo.baselines.methods import GIVEN_CLASS, METHODS
from hbeo.baselines.voxcnn import VoxCNN, VoxCNNBaseline, VoxCNNConfig
from hbeo.conventions import Intrinsics
from hbeo.evaluation.evaluate import EvaluationSetup, evaluate_method
from hbeo.evaluation.method import HBEOMethod, Method, answer_label
from hbeo.model.inference import HBEO
from hbeo.model.network import HBEONet, NetConfig
from hbeo.model.verify import VerifyConfig
from hbeo.render.renderer import Renderer, grid_mesh
from hbeo.rotations import check_rotation_matrices, yaw_elevation_to_matrix
from hbeo.subspace.basis import ObjectSubspace

K = Intrinsics.kinect(64, 48)
CLASSES = ("chair", "table")


@pytest.fixture(scope="module")
def boxes():
    grids = np.zeros((8, 30, 30, 30), bool)
    for i, g in enumerate(grids):                      # boxes of varied size, two classes
        a, b = 8 + i % 4, 14 + i
        g[a:30 - a, 10:20, a:b] = True
    labels = np.arange(8) % 2
    sub = ObjectSubspace(n_components=2).fit(grids, labels, CLASSES, progress=False)
    return grids, labels, sub


def _hbeo(boxes, verify=None):
    grids, _, sub = boxes
    torch.manual_seed(0)
    net = HBEONet(NetConfig(image_size=(K.width, K.height), n_classes=2, n_coeffs=sub.dim_,
                            conv_channels=(4, 4, 4, 4), fc=(8, 8, 8)))
    model = HBEO(net, sub, K, CLASSES, {"render": {"distance": [1.5, 1.9]}})
    return HBEOMethod(model, verify=verify)


#: one small, prepared instance of every registered method (and HBEO verified)
FACTORIES = {
    "hbeo": _hbeo,
    "hbeo+verify": lambda b: _hbeo(b, VerifyConfig()),
    "beo": lambda b: BEO(b[2], so3_grid=64, pose_bins_1dof=8).fit(b[0], b[1]),
    "icp": lambda b: ICPBaseline(n_init=8, max_iter=5, n_points=100, n_yaw=4, n_model=300).fit(b[0], b[1], CLASSES),
    "voxcnn": lambda b: (torch.manual_seed(0), VoxCNNBaseline(
        VoxCNN(VoxCNNConfig(channels=(2, 2, 2), n_classes=2, bottleneck=4)), CLASSES))[1],
}


def test_every_registered_method_has_a_factory():
    assert set(METHODS) <= {f.split("+")[0] for f in FACTORIES}


@pytest.fixture(scope="module")
def view(boxes):
    """One rendered view of box 3 (a table): depth, R, t."""
    R = yaw_elevation_to_matrix(0.7, 0.4)
    t = np.array([0.02, -0.01, 1.7])
    with Renderer(K, backend="embree") as r:
        depth = r.render(grid_mesh(boxes[0][3], 1.0), R, t)
    assert (depth > 0).sum() > 50
    return depth.astype(np.float32), R, t


CASES = [(f, p) for f in FACTORIES for p in METHODS[f.split("+")[0]]]


@pytest.mark.parametrize("factory, pose", CASES, ids=[f"{f}-{p}" for f, p in CASES])
def test_method_conformance(boxes, view, factory, pose):
    m = FACTORIES[factory](boxes)
    # the contract's members, and a registry entry matching them
    assert isinstance(m, Method), f"{type(m).__name__} lacks a Method member"
    assert m.name in METHODS and tuple(m.poses) == METHODS[m.name] and pose in m.poses
    extra = m.describe()
    assert isinstance(extra, dict) and set(extra) <= {"precision", "rolls", "mirror", "verify", "prior_tau", "class_prior", "ensemble",
                                                 "completion"}
    depth, R, t = view
    before = depth.copy()
    query = dict(R_true=R, t_true=t, object_size=1.0, pose=pose,
                 label_true=1 if (m.name, pose) in GIVEN_CLASS else None)
    out = m.predict_view(depth, K, rng=np.random.default_rng([0, 2, 3, 0]), **query)
    assert np.array_equal(depth, before), "predict_view must not change its input"
    # a well-formed answer
    p = np.asarray(out["probabilities"])
    assert p.shape == (len(CLASSES),) and np.isfinite(p).all() and (p >= 0).all() and p.sum() == pytest.approx(1, abs=1e-4)
    assert 0 <= answer_label(out) < len(CLASSES)
    assert np.asarray(out["rotation"]).shape == (3, 3)
    check_rotation_matrices(out["rotation"])
    g = np.asarray(out["grid"])
    assert g.shape == (30, 30, 30) and g.dtype == bool
    if "completion" in extra:                 # another rule than the paper's: its grid scored beside
        assert np.asarray(out["grid_paper"]).shape == (30, 30, 30) and g.any()
    assert "ms" not in out or out["ms"] >= 0
    if query["label_true"] is not None:                 # given the class, a method answers with it
        assert answer_label(out) == 1
    # deterministic for a given rng
    again = m.predict_view(depth, K, rng=np.random.default_rng([0, 2, 3, 0]), **query)
    assert answer_label(again) == answer_label(out)
    assert np.array_equal(again["rotation"], out["rotation"]) and np.array_equal(again["grid"], out["grid"])


def test_the_loop_refuses_what_is_not_a_method_and_an_unknown_pose(boxes):
    setup = EvaluationSetup(K, {}, CLASSES)

    class NoDescribe:
        name, poses = "mine", ("3dof",)

        def predict_view(self, depth, intrinsics, **query):
            return {}

    with pytest.raises(TypeError, match="NoDescribe does not implement the Method protocol"):
        evaluate_method(NoDescribe(), SimpleNamespace(name="boxes"), setup)
    with pytest.raises(ValueError, match="method 'voxcnn' does not take pose '3dof'"):
        evaluate_method(FACTORIES["voxcnn"](boxes), SimpleNamespace(name="boxes"), setup, pose="3dof")


def test_hbeo_adapters_sharing_a_prediction_answer_as_alone(boxes, view):
    depth, R, t = view
    alone, verified = _hbeo(boxes), _hbeo(boxes, VerifyConfig())
    model = alone.model
    first = HBEOMethod(model)
    shared = HBEOMethod(model, verify=VerifyConfig(), share=first)
    derived = HBEOMethod(model, verify=VerifyConfig(), share=shared, min_agreement=2.0)   # never reached
    a, b = first.predict_view(depth, K), shared.predict_view(depth, K)
    assert answer_label(a) == answer_label(alone.predict_view(depth, K))
    assert np.array_equal(a["grid"], alone.predict_view(depth, K)["grid"])
    v = verified.model.predict(depth, K)
    assert np.array_equal(b["rotation"], verified._verifier.verify(depth, K, v)["rotation"])
    d = derived.predict_view(depth, K)
    assert np.array_equal(d["rotation"], a["rotation"]) and d["ms"] == b["ms"]
    assert derived.describe()["verify"]["min_agreement"] == 2.0
    with pytest.raises(ValueError, match="min_agreement derives from a verified HBEOMethod"):
        HBEOMethod(model, share=first, min_agreement=0.5)
