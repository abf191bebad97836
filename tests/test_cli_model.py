"""The model commands end to end on the ci profile: train -> predict -> evaluate.

The trained model is the session's (conftest ``ci_model``); every test here depends on it or
trains another run, so the module is marked slow."""
import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.slow


def run(*args, env=None):
    return subprocess.run([sys.executable, "-m", "hbeo", *args], capture_output=True, text=True, env=env)


@pytest.fixture(scope="module")
def trained(ci_model, copy_run, tmp_path_factory):
    """This module's copy of the shared ci run with its trained model: evaluate fits and trains the
    baselines beside the model, i.e. writes into the run."""
    return copy_run(ci_model.parent, tmp_path_factory.mktemp("run")).path


def depth_png(path, w=80, h=60):
    mm = np.zeros((h, w), np.uint16)
    mm[20:40, 30:50] = 1700
    Image.fromarray(mm).save(path)


def test_predict_on_a_16bit_png(trained, tmp_path):
    depth_png(tmp_path / "d.png")
    out = run("predict", "--model", str(trained / "model.hbeo"), "--depth", str(tmp_path / "d.png"),
              "--intrinsics", "65.6,65.6,39.5,29.5", "--out", str(tmp_path / "r.json"))
    assert out.returncode == 0, out.stderr
    r = json.loads((tmp_path / "r.json").read_text())
    assert r["class"] in ("bathtub", "bed", "chair", "desk", "dresser", "monitor", "night_stand", "sofa",
                          "table", "toilet")
    assert len(r["axis_angle"]) == 3 and np.isclose(sum(r["probabilities"]), 1, atol=1e-4)
    assert r["precision"] == "float32" and r["rolls"] == 1 and "verified" not in r
    assert len(r["classes"]) == len(r["probabilities"]) and r["classes"][r["label"]] == r["class"]
    fast = run("predict", "--model", str(trained / "model.hbeo"), "--depth", str(tmp_path / "d.png"),
               "--intrinsics", "65.6,65.6,39.5,29.5", "--precision", "bfloat16", "--out", str(tmp_path / "b.json"))
    assert fast.returncode == 0, fast.stderr
    b = json.loads((tmp_path / "b.json").read_text())
    assert b["precision"] == "bfloat16" and np.allclose(b["probabilities"], r["probabilities"], atol=0.05)
    assert "mirror" not in r
    mir = run("predict", "--model", str(trained / "model.hbeo"), "--depth", str(tmp_path / "d.png"),
              "--intrinsics", "65.6,65.6,39.5,29.5", "--mirror", "--out", str(tmp_path / "m.json"))
    assert mir.returncode == 0, mir.stderr
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["mirror"] is True and m["axis_angle"] == r["axis_angle"] and m["coeffs"] == r["coeffs"]


@pytest.mark.parametrize("what, args, msg", [
    ("missing depth", ["--depth", "nope.png", "--intrinsics", "65,65,39,29"], "no such depth file"),
    ("bad intrinsics", ["--depth", "d.png", "--intrinsics", "65,65"], "expected four numbers"),
    ("zero depth", ["--depth", "zero.png", "--intrinsics", "65,65,39,29"], "all zero"),
    ("mask size", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--mask", "small.png"], "mask is 4x4"),
    ("bad model", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--model", "junk.hbeo"],
     "not a readable hbeo model"),
    ("rolls", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--rolls", "4"], "needs a rotation-bins model"),
    ("depth folder", ["--depth", "dir.png", "--intrinsics", "65,65,39,29"], "is a folder, not a depth file"),
    ("model folder", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--model", "dir.hbeo"],
     "is a folder, not a model file"),
    ("NaN mask", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--mask", "nan.npy"], "mask has NaN"),
    ("0-d mask", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--mask", "scalar.npy"],
     "mask must be a 2-D image"),
    ("prior tau", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--prior-tau", "2"],
     "--prior-tau: expected a number >= 0 and <= 1"),
])
def test_predict_bad_input_exits_2_with_one_line_and_writes_nothing(trained, tmp_path, what, args, msg):
    depth_png(tmp_path / "d.png")
    Image.fromarray(np.zeros((60, 80), np.uint16)).save(tmp_path / "zero.png")
    Image.fromarray(np.ones((4, 4), np.uint8)).save(tmp_path / "small.png")
    (tmp_path / "junk.hbeo").write_bytes(b"junk")
    (tmp_path / "dir.png").mkdir()
    (tmp_path / "dir.hbeo").mkdir()
    np.save(tmp_path / "nan.npy", np.full((60, 80), np.nan))
    np.save(tmp_path / "scalar.npy", np.array(1.0))
    args = [a if not a.endswith((".png", ".hbeo", ".npy")) else str(tmp_path / a) for a in args]
    if "--model" not in args:
        args += ["--model", str(trained / "model.hbeo")]
    out = run("predict", *args, "--out", str(tmp_path / "r.json"), "--mesh", str(tmp_path / "m.ply"))
    assert out.returncode == 2, (what, out.stderr)
    assert msg in out.stderr and out.stderr.strip().count("\n") == 0
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "m.ply").exists()


def test_predict_file_writes_a_mesh_alone_and_the_api_names_bad_arguments(trained, tmp_path):
    """``predict_file`` with a mesh path and no JSON path writes the mesh; ``HBEO.predict`` refuses intrinsics
    that are not an Intrinsics and depth that is not an image or a batch, in words."""
    import trimesh
    from hbeo.conventions import Intrinsics
    from hbeo.model.answer import predict_file
    from hbeo.model.inference import HBEO
    depth_png(tmp_path / "d.png")
    a = predict_file(trained / "model.hbeo", tmp_path / "d.png", "65.6,65.6,39.5,29.5", mesh_path=tmp_path / "m.ply")
    assert a.extra["mesh"] == str(tmp_path / "m.ply") and len(trimesh.load(tmp_path / "m.ply").vertices) > 0
    model = HBEO.load(trained / "model.hbeo")
    with pytest.raises(TypeError, match="intrinsics must be an hbeo.conventions.Intrinsics, got tuple"):
        model.predict(np.full((60, 80), 1.7), (65.6, 65.6, 39.5, 29.5))
    for bad in (np.full(80, 1.7), np.zeros((0, 60, 80))):
        with pytest.raises(ValueError, match=r"depth must be one image \(H, W\) or a batch"):
            model.predict(bad, Intrinsics(65.6, 65.6, 39.5, 29.5, 80, 60))


def test_evaluate_writes_the_documented_keys(trained, tmp_path):
    out = run("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--per-class", "1",
              "--out", str(tmp_path / "m.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    m = json.loads((tmp_path / "m.json").read_text())
    for key in ("accuracy", "pose_error_deg", "completion", "runtime_ms", "per_class", "confusion", "n_queries"):
        assert key in m
    assert m["n_queries"] == 10 and 0 <= m["accuracy"] <= 1
    assert set(m["completion"]) == {"edt", "naive", "iou", "empty_fraction", "empty"}
    # the default completion never leaves a grid empty; the paper's rule is scored beside on the same coefficients
    from hbeo.model.completion_rule import NONEMPTY
    assert m["completion_rule"] == NONEMPTY.to_dict() and m["completion"]["empty"] == 0
    assert not any(m["per_query"]["empty"]) and '"empty": 0' in out.stdout and "completion_paper" in out.stdout
    paper = run("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--per-class", "1",
                "--completion", "paper", "--out", str(tmp_path / "p.json"), "--quiet")
    assert paper.returncode == 0, paper.stderr
    p = json.loads((tmp_path / "p.json").read_text())
    assert "completion_rule" not in p and "completion_paper" not in p
    assert m["completion_paper"]["per_query"] == {k: p["per_query"][k] for k in ("edt", "iou", "empty")}
    assert m["completion_paper"]["empty"] == sum(p["per_query"]["empty"]) == p["completion"]["empty"]
    assert m["per_query"]["pred"] == p["per_query"]["pred"]
    assert m["method"] == "hbeo" and m["pose"] == "3dof" and not m["given_class"] and m["precision"] == "float32"
    assert set(m["completion_baseline"]) == {"predicted_class", "true_class", "true_class_iou_t03"}
    assert len(m["per_query"]["pose_deg"]) == 10
    # queries are named by object and view: the same pair is the same image for every method (paired comparisons)
    from hbeo import config
    from hbeo.data import datasets
    ids = [r.id for r in datasets.get_dataset("procedural", profile=config.get_profile("ci")).records(
        split="test", per_class=1)]
    assert m["per_query"]["object"] == ids and m["per_query"]["view"] == [0] * 10


@pytest.mark.parametrize("method, pose, given", [("beo", "known", False), ("beo", "1dof", False),
                                                 ("icp", "3dof", True), ("voxcnn", "known", False)])
def test_evaluate_baselines_write_the_same_keys(trained, tmp_path, method, pose, given):
    """Every method answers through the same evaluate command and JSON; a missing baseline is built
    beside the model (BEO and ICP fitted on the run's grids, the voxel network trained)."""
    ref = run("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--per-class", "1",
              "--out", str(tmp_path / "h.json"), "--quiet")
    assert ref.returncode == 0, ref.stderr
    out = run("evaluate", "--model", str(trained / "model.hbeo"), "--method", method, "--pose", pose,
              "--dataset", "procedural", "--per-class", "1", "--out", str(tmp_path / "m.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    h, m = json.loads((tmp_path / "h.json").read_text()), json.loads((tmp_path / "m.json").read_text())
    # the same keys, less HBEO's completion rule and its paper's-rule scores beside (a baseline has one rule)
    assert set(m) == set(h) - {"completion_rule", "completion_paper"}
    assert (m["method"], m["pose"], m["given_class"]) == (method, pose, given) and m["precision"] is None
    assert m["n_queries"] == 10 and set(m["completion"]) == set(h["completion"])
    if pose == "known":
        # the rotation was given: only the float32 rounding of the stored rotation remains, which the arccos of
        # the geodesic angle magnifies to a few thousandths of a degree (a wrong pose would be degrees off)
        assert m["pose_error_deg"]["median"] < 0.05
    if given:
        assert m["accuracy"] == 1.0


def test_evaluate_under_another_threshold_records_it_and_the_paper_rule_takes_none(trained, tmp_path):
    base = ("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--per-class", "1",
            "--quiet")
    out = run(*base, "--completion-threshold", "0.35", "--out", str(tmp_path / "t.json"))
    assert out.returncode == 0, out.stderr
    m = json.loads((tmp_path / "t.json").read_text())
    assert m["completion_rule"] == {"name": "nonempty", "threshold": 0.35, "fallback": True}
    assert m["completion"]["empty"] == 0
    bad = run(*base, "--completion", "paper", "--completion-threshold", "0.35", "--out", str(tmp_path / "p.json"))
    assert bad.returncode == 2 and "the paper's rule is back-projection >= 0.5" in bad.stderr
    assert not (tmp_path / "p.json").exists()
    bad = run(*base, "--completion-threshold", "1.5", "--out", str(tmp_path / "q.json"))
    assert bad.returncode == 2 and "must be in (0, 1)" in bad.stderr and not (tmp_path / "q.json").exists()


def test_evaluate_refuses_a_pose_setting_the_method_lacks(trained, tmp_path):
    out = run("evaluate", "--model", str(trained / "model.hbeo"), "--method", "voxcnn", "--pose", "3dof",
              "--out", str(tmp_path / "m.json"))
    assert out.returncode == 2 and "does not take pose '3dof'" in out.stderr
    assert not (tmp_path / "m.json").exists()


def _numbers(m: dict) -> dict:
    """A metrics dict without what depends on the machine's speed (runtimes) or the file paths."""
    drop = {"runtime_ms", "model"}
    out = {k: v for k, v in m.items() if k not in drop}
    out["per_query"] = {k: v for k, v in m["per_query"].items() if k != "ms"}
    return out


def test_two_runs_with_the_same_seed_give_the_same_numbers(trained, tmp_path):
    """A second ci run (grids, subspace, rendering, training, evaluation), all by the CLI in a fresh
    folder with a fresh voxel cache, gives the same metrics for HBEO and BEO as the session's run
    (its stages built by the package functions, its model by the CLI), to the last digit (runtimes
    aside)."""
    import os
    second = tmp_path / "run2"
    env = dict(os.environ, HBEO_CACHE=str(tmp_path / "cache"))
    out = run("train", "--dataset", "procedural", "--profile", "ci", "--out", str(second), "--epochs", "1",
              "--quiet", env=env)
    assert out.returncode == 0, out.stderr
    for method, pose in [("hbeo", "3dof"), ("beo", "1dof")]:
        ms = []
        for r in (trained, second):
            res = run("evaluate", "--model", str(r / "model.hbeo"), "--method", method, "--pose", pose,
                      "--per-class", "1", "--out", str(tmp_path / f"{r.name}_{method}.json"), "--quiet")
            assert res.returncode == 0, res.stderr
            ms.append(_numbers(json.loads((tmp_path / f"{r.name}_{method}.json").read_text())))
        assert ms[0] == ms[1], method


def test_evaluate_refuses_roll_averaging_for_a_regression_model(trained, tmp_path):
    out = run("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--rolls", "4",
              "--out", str(tmp_path / "m.json"), "--quiet")
    assert out.returncode == 2 and "rotation-bins model" in out.stderr and out.stderr.strip().count("\n") == 0
    assert not (tmp_path / "m.json").exists()


def test_train_max_steps_stops_early_and_writes_a_normal_model(trained, tmp_path):
    from hbeo.model.inference import HBEO
    from hbeo.rundir import RunDir
    rd = RunDir(trained)
    res = run("train", "--dataset", "procedural", "--profile", "ci", "--out", str(trained), "--epochs", "3",
              "--max-steps", "2", "--name", "model_steps.hbeo", "--quiet")
    assert res.returncode == 0, res.stderr
    log = rd.train_log("model_steps.hbeo").read_text().splitlines()
    header, rows = log[0].split(","), [r.split(",") for r in log[1:]]
    assert len(rows) == 1 and int(rows[0][header.index("step")]) == 2, log
    assert HBEO.load(rd.model_file("model_steps.hbeo")).net.n_params() > 0


def test_evaluate_max_steps_bounds_the_3d_cnn_it_trains(ci_model, copy_run, tmp_path):
    """Every training command takes --max-steps: the 3-D CNN is trained by evaluate when missing."""
    import pandas as pd
    from hbeo.rundir import RunDir
    rd = copy_run(ci_model.parent, tmp_path / "run")
    out = run("evaluate", "--model", str(rd.model), "--method", "voxcnn", "--max-steps", "3", "--dataset",
              "procedural", "--per-class", "1", "--out", str(tmp_path / "v.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    log = pd.read_csv(RunDir(rd.path).train_log(rd.baseline("voxcnn")))
    assert log.step.iloc[-1] == 3 and rd.baseline("voxcnn").is_file()


def test_evaluate_on_the_validation_split_scores_held_out_training_objects_and_logs_them(ci_model, copy_run,
                                                                                        tmp_path):
    """The validation protocol: ``--split val`` scores the training objects that training held out
    (fixed, seeded, per class), never test objects, and every evaluation leaves a row."""
    import pandas as pd
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.model.trainingdata import training_data, ViewOptions
    from hbeo.rundir import RunDir
    rd = copy_run(ci_model.parent, tmp_path / "run")
    for seed in (0, 1):
        out = run("evaluate", "--model", str(rd.model), "--split", "val", "--seed", str(seed), "--dataset",
                  "procedural", "--out", str(tmp_path / f"val{seed}.json"), "--quiet", *(["--noise"] if seed else []))
        assert out.returncode == 0, out.stderr
    m = json.loads((tmp_path / "val0.json").read_text())
    ds = datasets.get_dataset("procedural", profile=config.get_profile("ci"))
    val = datasets.validation_records(ds, "ci")
    assert m["split"] == "val" and m["n_queries"] == len(val) == 10            # one object per class of 6
    assert {r.split for r in val} == {"train"}
    # the same objects the training held out of the run's rendered set
    data = training_data(rd, ViewOptions(), progress=False)
    held = {data.manifest.object_ids[p] for p in np.unique(data.manifest.image_objects()[data.val.indices])}
    assert held == {r.id for r in val}
    log = pd.read_csv(RunDir(rd.path).validation_log)
    assert list(log.seed) == [0, 1] and set(log.model) == {"model.hbeo"} and (log.n_queries == 10).all()
    assert list(log.noise) == [False, True] and set(log.sampler) == {"so3"}    # a noisy evaluation says so
    assert log.accuracy.iloc[0] == m["accuracy"]


def test_predict_and_evaluate_verify_with_settings(trained, tmp_path):
    """``--verify`` in predict and evaluate, ``--verify-set`` over the defaults, recorded in the output;
    bad settings exit 2 with one line before any work."""
    depth_png(tmp_path / "d.png")
    base = ["predict", "--model", str(trained / "model.hbeo"), "--depth", str(tmp_path / "d.png"),
            "--intrinsics", "65.6,65.6,39.5,29.5"]
    out = run(*base, "--verify", "--verify-set", "classes=2,rotations=2", "--out", str(tmp_path / "v.json"))
    assert out.returncode == 0, out.stderr
    r = json.loads((tmp_path / "v.json").read_text())
    assert r["verify"]["classes"] == 2 and r["verify"]["rotations"] == 2 and "verify" in r["timing_ms"]
    plain = run(*base, "--out", str(tmp_path / "p.json"))
    assert plain.returncode == 0 and json.loads((tmp_path / "p.json").read_text())["verify"] is None
    for bad, msg in ((["--verify", "--verify-set", "clases=2"], "clases=2"),
                     (["--verify-set", "classes=2"], "needs --verify"),
                     (["--verify", "--verify-set", "noise_var=0"], "out of range")):
        out = run(*base, *bad, "--out", str(tmp_path / "x.json"))
        assert out.returncode == 2 and msg in out.stderr and out.stderr.strip().count("\n") == 0, out.stderr
        assert not (tmp_path / "x.json").exists()
    out = run("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--per-class", "1",
              "--verify", "--verify-set", "classes=1", "--out", str(tmp_path / "e.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    m = json.loads((tmp_path / "e.json").read_text())
    assert m["verify"]["classes"] == 1 and m["n_queries"] == 10


def test_verify_sweep_scores_every_candidate_on_the_same_queries_and_refuses_the_test_split(trained):
    """The sweep's HBEO-alone row is ``evaluate --split val``'s; a one-class verify keeps HBEO's classes."""
    from hbeo import config
    from hbeo.data import datasets
    from hbeo.model.inference import HBEO
    from hbeo.model.verify import VerifyConfig
    from hbeo.evaluation.evaluate import evaluate_model
    from hbeo.evaluation.sweep import sweep_rows, verify_sweep
    model = HBEO.load(trained / "model.hbeo")
    ds = datasets.get_dataset("procedural", profile=config.get_profile("ci"))
    one = VerifyConfig(classes=1, rotations=2, min_agreement=0)
    res = verify_sweep(model, ds, {"hbeo": None, "one class": one}, progress=False, thresholds=(0, 1.01))
    ref = evaluate_model(model, ds, split="val", progress=False)
    assert res["hbeo"]["per_query"]["pred"] == ref["per_query"]["pred"]
    assert res["hbeo"]["per_query"]["iou"] == ref["per_query"]["iou"]
    assert res["one class"]["per_query"]["pred"] == ref["per_query"]["pred"]
    assert res["one class"]["per_query"]["iou"] != ref["per_query"]["iou"]
    # derived thresholds: 0 keeps every verified answer, above 1 none (HBEO's own everywhere)
    assert res["one class min_agreement=0"]["per_query"]["iou"] == res["one class"]["per_query"]["iou"]
    assert res["one class min_agreement=1.01"]["per_query"]["iou"] == ref["per_query"]["iou"]
    assert res["one class min_agreement=1.01"]["verify"]["min_agreement"] == 1.01
    rows = sweep_rows(res, "abc")
    assert [r["name"] for r in rows][:2] == ["hbeo", "one class"] and rows[0]["verify"] == "null"
    with pytest.raises(ValueError, match="never on the test split"):
        verify_sweep(model, ds, {"hbeo": None}, split="test", progress=False)


def test_evaluate_mirror_averages_only_the_class_and_is_refused_for_a_baseline(trained, tmp_path):
    args = ("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--per-class", "2",
            "--quiet")
    plain, mirror = (run(*args, *extra, "--out", str(tmp_path / f"{name}.json"))
                     for name, extra in (("plain", ()), ("mirror", ("--mirror",))))
    assert plain.returncode == 0 and mirror.returncode == 0, mirror.stderr
    a, b = (json.loads((tmp_path / f"{n}.json").read_text()) for n in ("plain", "mirror"))
    assert a["mirror"] is False and b["mirror"] is True
    for col in ("pose_deg", "iou", "edt"):                # the rotation and completion are the unmirrored pass's
        assert a["per_query"][col] == b["per_query"][col], col
    out = run("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--method", "beo",
              "--mirror", "--out", str(tmp_path / "beo.json"), "--quiet")
    assert out.returncode == 2 and "--mirror" in out.stderr and out.stderr.strip().count("\n") == 0
    assert not (tmp_path / "beo.json").exists()


def test_an_object_far_off_the_axis_is_low_confidence_for_a_model_trained_without_recentering(trained, tmp_path):
    """The training renderings put the object's centre within ``shift`` (a fraction of the depth) of the axis;
    a centre beyond twice that is warned about, one on the axis is not."""
    from hbeo.conventions import Intrinsics
    from hbeo.model.inference import HBEO
    model = HBEO.load(trained / "model.hbeo")
    shift = model.settings.render["shift"]
    assert not model.settings.recenter and shift > 0
    K = Intrinsics.kinect(320, 240)

    def blob(u0):                                 # a 0.3 m square at 1.7 m, its centre at column u0
        d = np.zeros((240, 320), np.float32)
        half = int(0.15 * K.fx / 1.7)
        d[120 - half:120 + half, u0 - half:u0 + half] = 1.7
        return d

    centred = model.predict(blob(160), K)
    assert not any("off the optical axis" in w for w in centred.warnings[0])
    u_far = int(K.cx + K.fx * 3 * shift) + 1       # three times the training shift
    far = model.predict(blob(u_far), K)
    assert far.low_confidence[0] and any("off the optical axis" in w for w in far.warnings[0])
    assert np.array_equal(far.view_rotation[0], np.eye(3))
    # predict --face-object: the view turned toward the object, by the part of its offset beyond the training
    # shift (rotation Q about the camera's y axis), no warning
    from hbeo.model.answer import predict_file
    np.save(tmp_path / "far.npy", blob(u_far))
    a = predict_file(trained / "model.hbeo", tmp_path / "far.npy", f"{K.fx},{K.fy},{K.cx},{K.cy}",
                     face_object=True)
    Q = a.prediction.view_rotation[0]
    assert a.extra["face_object"] and not any("off the optical axis" in w for w in a.warnings)
    assert Q[0, 2] > shift and np.allclose(Q @ Q.T, np.eye(3))           # +z of the view toward the object


def test_notebook_08_loads_a_model_that_faces_the_object_as_predict_does(trained, tmp_path):
    """``yourdepth.load_model(..., face_object=True)`` (notebook 08's ``face_object``) is ``predict --face-object``:
    the model's views turn to the object, its answer says so, and its settings (what it was trained with, what
    ``save`` writes) stay as trained; without it the model is as trained."""
    from hbeo.lessons import yourdepth
    from hbeo.model.inference import HBEO
    plain, path = yourdepth.load_model(None, trained / "model.hbeo")
    faced, _ = yourdepth.load_model(None, trained / "model.hbeo", face_object=True)
    assert path == trained / "model.hbeo" and not plain.face_object and faced.face_object
    assert faced.settings == plain.settings and not faced.settings.recenter
    assert faced.answer_settings() == {**plain.answer_settings(), "face_object": True}
    assert list(plain.answer_settings()["classes"]) == list(plain.classes)
    assert not HBEO.load(faced.save(tmp_path / "faced.hbeo")).face_object       # the trained setting is saved
    with pytest.raises(ValueError, match="face_object must be True or False"):
        faced.set_face_object("yes")
    assert not faced.set_face_object(False).face_object
