"""Issue 14, `predict` and `evaluate`: inputs the model cannot have understood are refused (exit 2,
one line naming the file or option) or answered with warnings and ``low_confidence``; output
paths are checked before any work and never overwrite an input.

Unit tests use a tiny untrained HBEO (a 2-class subspace of box grids); the CLI tests use the
session's trained ci model (conftest ``ci_model``) and are marked slow."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from hbeo.conventions import Intrinsics
from hbeo.errors import DataError
from hbeo.model.inference import HBEO
from hbeo.model.preprocess import to_model_view
from hbeo.model.depthfile import parse_intrinsics, read_depth
from hbeo.subspace.basis import ObjectSubspace

K_MODEL = Intrinsics.kinect(32, 24)


@pytest.fixture(scope="module")
def tiny(tiny_model):
    """conftest's untrained tiny HBEO (32x24 camera), its own shapes, no recentring, trained
    (nominally) at 1.4..2.0 m."""
    g = np.zeros((8, 30, 30, 30), bool)
    for i in range(8):
        g[i, 5:25 - i, 5:25, 5:20 + i] = True
    sub = ObjectSubspace(n_components=2).fit(g, np.array([0, 1] * 4), ("bathtub", "bed"), progress=False)
    return tiny_model({"recenter": False, "render": {"distance": [1.4, 2.0], "object_size": 1.0}},
                      classes=("bathtub", "bed"), subspace=sub)


def box(K, rows, cols, z=1.7):
    d = np.zeros((K.height, K.width))
    d[rows, cols] = z
    return d


# ----------------------------------------------------------------------------- case 1: the model's view

def test_view_measures_coverage_and_filled_pixels():
    K_user = Intrinsics.kinect(64, 48)
    centred = to_model_view(box(K_user, slice(16, 32), slice(24, 40)), K_user, K_MODEL, recenter=False)
    assert centred.coverage == 1.0 and centred.filled > 0
    wide = Intrinsics(20.0, 20.0, 31.5, 23.5, 64, 48)               # 116 degrees: wider than the model's 62
    half = to_model_view(box(wide, slice(16, 32), slice(32, 64)), wide, K_MODEL, recenter=False)
    assert 0.3 < half.coverage < 0.7 and half.filled > 0


def test_object_outside_the_model_view_is_an_error(tiny):
    K_user = Intrinsics(65.6, 65.6, 39.5, 29.5, 800, 600)          # the model's f on a huge image
    with pytest.raises(DataError, match="outside the model's view.*intrinsics"):
        tiny.predict(box(K_user, slice(280, 320), slice(380, 420)), K_user)


def test_object_partly_outside_or_tiny_is_low_confidence(tiny):
    K = K_MODEL
    ok = tiny.predict(box(K, slice(6, 18), slice(8, 24)), K)
    assert not ok.low_confidence[0] and ok.to_dict()["warnings"] == [] and ok.to_dict()["low_confidence"] is False
    wide = Intrinsics(20.0, 20.0, 31.5, 23.5, 64, 48)
    edge = tiny.predict(box(wide, slice(16, 32), slice(32, 64)), wide).to_dict()
    assert edge["low_confidence"] and any("inside the model's view" in w for w in edge["warnings"])
    small = tiny.predict(box(K, slice(10, 12), slice(10, 12)), K).to_dict()
    assert small["low_confidence"] and any("fills only 4" in w for w in small["warnings"])
    coarse = Intrinsics(K.fx / 4, K.fy / 4, (K.width / 4 - 1) / 2, (K.height / 4 - 1) / 2, K.width // 4, K.height // 4)
    few = tiny.predict(box(coarse, slice(2, 5), slice(3, 6)), coarse).to_dict()     # 9 pixels, stretched
    assert few["low_confidence"] and any("seen by only 9 pixels of the image" in w for w in few["warnings"])
    assert not any("seen by only" in w for w in ok.to_dict()["warnings"] + small["warnings"])


def test_depth_far_from_training_distances_is_low_confidence(tiny):
    K = K_MODEL
    far = tiny.predict(box(K, slice(10, 14), slice(13, 19), z=6.0), K).to_dict()
    assert far["low_confidence"] and any("trained at 1.4..2 m" in w for w in far["warnings"])


# ----------------------------------------------------------------------------- case 2: depth range

def test_millimetres_given_as_metres_is_an_error(tiny):
    with pytest.raises(DataError, match=r"2.23e\+03 m away, outside the plausible 0.1..20 m"):
        tiny.predict(box(K_MODEL, slice(6, 18), slice(8, 24), z=1700.0), K_MODEL)


def mm_png(path, value, shape=(24, 32)):
    a = np.zeros(shape, np.uint16)
    a[6:18, 8:24] = value
    Image.fromarray(a).save(path)
    return path


@pytest.mark.parametrize("value, scale", [(2, None), (1700, 1.0), (1700, 1e30), (1700, 1e-6)])
def test_implausible_depth_range_names_the_file_and_the_scale(tmp_path, value, scale):
    p = mm_png(tmp_path / "d.png", value)
    with pytest.raises(DataError, match=r"d\.png: median depth .* implausible .*--depth-scale"):
        read_depth(p, scale)
    assert read_depth(mm_png(tmp_path / "ok.png", 1700)).max() == pytest.approx(1.7)


@pytest.mark.parametrize("text, msg", [
    ("1e-9,1e-9,319.5,239.5", "field of view"),
    ("1e6,1e6,319.5,239.5", "field of view"),
    ("525,5,319.5,239.5", "non-square"),
    ("0,525,319.5,239.5", "fx, fy > 0"),
    ("nan,525,319.5,239.5", "finite"),
    ("525,525,319.5,1e9", "principal point"),
])
def test_absurd_intrinsics_are_refused(text, msg):
    with pytest.raises(ValueError, match=msg):
        parse_intrinsics(text, 640, 480)


# ----------------------------------------------------------------------------- cases 3 and 6: output paths

def test_check_outputs(tmp_path):
    from hbeo.storage import check_outputs
    src = tmp_path / "d.png"
    src.write_bytes(b"x")
    check_outputs({"--out": tmp_path / "r.json", "--mesh": None}, {"--depth": src})
    for outs, msg in [({"--out": tmp_path / "no" / "r.json"}, "does not exist"),
                      ({"--out": tmp_path}, "names a folder"),
                      ({"--out": src / "r.json"}, "is not a folder"),
                      ({"--out": src}, "same file as --depth"),
                      ({"--out": tmp_path / "." / "d.png"}, "same file as --depth"),
                      ({"--out": tmp_path / "a", "--mesh": tmp_path / "a"}, "--mesh is the same file as --out")]:
        with pytest.raises(DataError, match=msg):
            check_outputs(outs, {"--depth": src})
    os.link(src, tmp_path / "hard.png")
    with pytest.raises(DataError, match="same file"):
        check_outputs({"--out": tmp_path / "hard.png"}, {"--depth": src})
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    if not os.access(locked, os.W_OK):                       # not when running as root
        with pytest.raises(DataError, match="no permission"):
            check_outputs({"--out": locked / "r.json"})


# ----------------------------------------------------------------------------- the CLI (trained ci model)

def run(*args):
    return subprocess.run([sys.executable, "-m", "hbeo", *args], capture_output=True, text=True)


def one_line_error(out, *words):
    assert out.returncode == 2, out.stderr
    assert out.stderr.startswith("error: ") and out.stderr.strip().count("\n") == 0, out.stderr
    for w in words:
        assert w in out.stderr, out.stderr


@pytest.fixture
def files(tmp_path):
    depth = tmp_path / "d.png"
    a = np.zeros((60, 80), np.uint16)
    a[20:40, 30:50] = 1700
    Image.fromarray(a).save(depth)
    return tmp_path, depth


@pytest.mark.slow
def test_cli_object_outside_the_view_exits_2(ci_model, tmp_path):
    a = np.zeros((600, 800), np.uint16)
    a[280:320, 380:420] = 1700
    Image.fromarray(a).save(tmp_path / "big.png")
    out = run("predict", "--model", str(ci_model), "--depth", str(tmp_path / "big.png"),
              "--intrinsics", "65.6,65.6,39.5,29.5", "--out", str(tmp_path / "r.json"))
    one_line_error(out, "big.png", "outside the model's view", "intrinsics")
    assert not (tmp_path / "r.json").exists()


@pytest.mark.slow
def test_cli_partly_outside_warns_on_stderr_and_in_the_json(ci_model, files):
    tmp, _ = files
    a = np.zeros((60, 80), np.uint16)
    a[10:50, 55:80] = 1700
    Image.fromarray(a).save(tmp / "edge.png")
    out = run("predict", "--model", str(ci_model), "--depth", str(tmp / "edge.png"),      # wider than the model's
              "--intrinsics", "25,25,39.5,29.5", "--out", str(tmp / "r.json"))
    assert out.returncode == 0, out.stderr
    r = json.loads((tmp / "r.json").read_text())
    assert r["low_confidence"] is True and r["warnings"]
    assert "warning:" in out.stderr and "low confidence" in out.stderr


@pytest.mark.slow
@pytest.mark.parametrize("scale, intr", [("1", "65.6,65.6,39.5,29.5"), ("1e30", "65.6,65.6,39.5,29.5"),
                                         (None, "1e-9,1e-9,39.5,29.5")])
def test_cli_implausible_depth_or_intrinsics_exit_2(ci_model, files, scale, intr):
    tmp, depth = files
    args = ["--depth-scale", scale] if scale else []
    out = run("predict", "--model", str(ci_model), "--depth", str(depth), "--intrinsics", intr, *args,
              "--out", str(tmp / "r.json"))
    one_line_error(out, "depth-scale" if scale else "intrinsics")
    assert not (tmp / "r.json").exists()


@pytest.mark.slow
@pytest.mark.parametrize("out_name, mesh_name, msg", [
    ("missing/r.json", None, "does not exist"),
    (".", "m.ply", "names a folder"),                 # --mesh fine, --out a folder: no mesh written either
    ("d.png", None, "same file as --depth"),
    ("r.json", "d.png", "same file as --depth"),
    ("r.json", "r.json", "same file as --out"),
    ("model", None, "same file as --model"),
])
def test_cli_bad_outputs_exit_2_before_any_work_and_overwrite_nothing(ci_model, files, out_name, mesh_name, msg):
    tmp, depth = files
    model = tmp / "model.hbeo"
    model.write_bytes(ci_model.read_bytes())
    before = {p.name: p.read_bytes() for p in tmp.iterdir() if p.is_file()}
    out_path = model if out_name == "model" else tmp / out_name
    mesh = ["--mesh", str(tmp / mesh_name)] if mesh_name else []
    out = run("predict", "--model", str(model), "--depth", str(depth), "--intrinsics", "65.6,65.6,39.5,29.5",
              "--out", str(out_path), *mesh)
    one_line_error(out, msg)
    assert {p.name: p.read_bytes() for p in tmp.iterdir() if p.is_file()} == before
    # checked before the model is read: a junk model file is not what the error names
    (tmp / "junk.hbeo").write_bytes(b"junk")
    out = run("predict", "--model", str(tmp / "junk.hbeo"), "--depth", str(depth),
              "--intrinsics", "65.6,65.6,39.5,29.5", "--out", str(tmp / "no" / "r.json"))
    one_line_error(out, "--out")


@pytest.mark.parametrize("command", ["predict", "evaluate"])
def test_cli_bad_out_exits_2_before_torch_is_imported(tmp_path, command):
    """A wrong output path is answered at once: torch (seconds to import) is not loaded for it."""
    model = tmp_path / "model.hbeo"
    model.write_bytes(b"never read")
    args = ["--depth", str(tmp_path / "d.png"), "--intrinsics", "65.6,65.6,39.5,29.5"] if command == "predict" else []
    argv = [command, "--model", str(model), *args, "--out", str(tmp_path / "missing" / "r.json")]
    code = ("import sys; from hbeo.cli import main; rc = main(sys.argv[1:]); "
            "print('torch imported' if 'torch' in sys.modules else 'no torch'); sys.exit(rc)")
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
    assert out.returncode == 2, out.stderr
    assert "does not exist" in out.stderr and out.stdout.strip() == "no torch", (out.stdout, out.stderr)


@pytest.mark.slow
def test_cli_evaluate_out_over_model_and_unknown_class(ci_model, tmp_path):
    model = tmp_path / "model.hbeo"
    model.write_bytes(ci_model.read_bytes())
    out = run("evaluate", "--model", str(model), "--out", str(model), "--quiet")
    one_line_error(out, "same file as --model")
    assert model.read_bytes() == ci_model.read_bytes()
    lamp = tmp_path / "ds" / "lamp" / "test"
    lamp.mkdir(parents=True)
    import trimesh
    trimesh.creation.box((1, 1, 2)).export(lamp / "lamp_0001.off")
    out = run("evaluate", "--model", str(model), "--dataset", str(tmp_path / "ds"), "--out",
              str(tmp_path / "m.json"), "--quiet")
    one_line_error(out, "lamp", "unknown to the model")
    assert not (tmp_path / "m.json").exists() and not (tmp_path / "beo.npz").exists()
