"""The flip table: error turns in the object's frame, and which large errors turn about the up axis."""
import numpy as np
import pytest

from hbeo.evaluation.flips import error_turns, flip_table
from hbeo.rotations import axis_and_angle_to_matrix, uniform_so3


def test_error_turns_are_measured_in_the_object_frame():
    R_true = uniform_so3(4, np.random.default_rng(0))
    turns = [((0, 0, 1), np.pi), ((1, 0, 0), np.radians(170)), ((0, 1, 0), np.radians(20)), ((0, 0, 1), 0.0)]
    R_pred = np.stack([R @ axis_and_angle_to_matrix(np.array(a, float), t) for R, (a, t) in zip(R_true, turns)])
    deg, axis = error_turns(R_pred, R_true)
    assert deg == pytest.approx([180, 170, 20, 0], abs=1e-6)
    assert np.abs(axis[0]) == pytest.approx([0, 0, 1], abs=1e-6) and axis[1] == pytest.approx([1, 0, 0], abs=1e-6)
    assert axis[3] == pytest.approx([0, 0, 0])
    with pytest.raises(ValueError, match="R_pred"):
        error_turns(np.ones((1, 3, 3)), R_true[:1])
    with pytest.raises(ValueError, match="2 predicted rotations for 1"):
        error_turns(R_pred[:2], R_true[:1])


def test_the_flip_table_counts_flips_and_their_axes_per_class():
    R_true = uniform_so3(6, np.random.default_rng(1))
    z = lambda t: axis_and_angle_to_matrix(np.array([0, 0, 1.0]), np.radians(t))
    x = lambda t: axis_and_angle_to_matrix(np.array([1, 0, 0.0]), np.radians(t))
    turns = [("chair", z(180)), ("chair", x(175)), ("chair", z(10)), ("chair", z(0)), ("sofa", x(5)), ("sofa", z(30))]
    rows = [{"class": c, "R_true": R, "R_pred": R @ E} for R, (c, E) in zip(R_true, turns)]
    table = {r["class"]: r for r in flip_table(rows)}
    assert table["chair"] == {"class": "chair", "n": 4, "flips": 0.5, "about_up": 0.5}
    assert table["sofa"] == {"class": "sofa", "n": 2, "flips": 0.0, "about_up": None}
    assert table["all"]["n"] == 6 and table["all"]["flips"] == pytest.approx(2 / 6) and table["all"]["about_up"] == 0.5
    with pytest.raises(ValueError, match="no queries"):
        flip_table([])


@pytest.mark.slow
def test_pose_flips_scores_the_evaluation_s_own_views(ci_model):
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.evaluation.evaluate import evaluate_model
    from hbeo.evaluation.flips import BIG_DEG, pose_flips
    from hbeo.model.inference import HBEO
    model = HBEO.load(ci_model)
    ds = datasets.get_dataset("procedural", profile=config.get_profile("ci"))
    out = pose_flips(model, ds, split="test", views=2, per_class=1, progress=False)
    ref = evaluate_model(model, ds, split="test", views=2, per_class=1, progress=False)
    every = out["classes"][-1]
    assert every["class"] == "all" and every["n"] == ref["n_queries"] == 20 and out["n_objects"] == 10
    # the same images as the evaluation: the same share of errors at or above BIG_DEG, class by class
    deg, cls = np.array(ref["per_query"]["pose_deg"]), np.array(ref["per_query"]["class"])
    assert every["flips"] == pytest.approx(np.mean(deg >= BIG_DEG), abs=1e-9)
    for row in out["classes"][:-1]:
        assert row["flips"] == pytest.approx(np.mean(deg[cls == row["class"]] >= BIG_DEG), abs=1e-9)
