"""The model commands end to end on the ci profile: train -> predict -> evaluate."""
import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image


def run(*args, env=None):
    return subprocess.run([sys.executable, "-m", "hbeo", *args], capture_output=True, text=True, env=env)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    import os
    run_dir = tmp_path_factory.mktemp("run")
    env = dict(os.environ, HBEO_CACHE=str(run_dir / "cache"))
    out = run("train", "--dataset", "procedural", "--profile", "ci", "--out", str(run_dir), "--epochs", "1",
              "--quiet", env=env)
    assert out.returncode == 0, out.stderr
    assert "model:" in out.stdout and (run_dir / "model.hbeo").exists()
    return run_dir


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


@pytest.mark.parametrize("what, args, msg", [
    ("missing depth", ["--depth", "nope.png", "--intrinsics", "65,65,39,29"], "no such depth file"),
    ("bad intrinsics", ["--depth", "d.png", "--intrinsics", "65,65"], "expected four numbers"),
    ("zero depth", ["--depth", "zero.png", "--intrinsics", "65,65,39,29"], "all zero"),
    ("mask size", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--mask", "small.png"], "mask is 4x4"),
    ("bad model", ["--depth", "d.png", "--intrinsics", "65,65,39,29", "--model", "junk.hbeo"],
     "not a readable hbeo model"),
])
def test_predict_bad_input_exits_2_with_one_line_and_writes_nothing(trained, tmp_path, what, args, msg):
    depth_png(tmp_path / "d.png")
    Image.fromarray(np.zeros((60, 80), np.uint16)).save(tmp_path / "zero.png")
    Image.fromarray(np.ones((4, 4), np.uint8)).save(tmp_path / "small.png")
    (tmp_path / "junk.hbeo").write_bytes(b"junk")
    args = [a if not a.endswith((".png", ".hbeo")) else str(tmp_path / a) for a in args]
    if "--model" not in args:
        args += ["--model", str(trained / "model.hbeo")]
    out = run("predict", *args, "--out", str(tmp_path / "r.json"), "--mesh", str(tmp_path / "m.ply"))
    assert out.returncode == 2, (what, out.stderr)
    assert msg in out.stderr and out.stderr.strip().count("\n") == 0
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "m.ply").exists()


def test_evaluate_writes_the_documented_keys(trained, tmp_path):
    out = run("evaluate", "--model", str(trained / "model.hbeo"), "--dataset", "procedural", "--per-class", "1",
              "--out", str(tmp_path / "m.json"), "--quiet")
    assert out.returncode == 0, out.stderr
    m = json.loads((tmp_path / "m.json").read_text())
    for key in ("accuracy", "pose_error_deg", "completion", "runtime_ms", "per_class", "confusion", "n_queries"):
        assert key in m
    assert m["n_queries"] == 10 and 0 <= m["accuracy"] <= 1
    assert set(m["completion"]) == {"edt", "naive", "iou"}
