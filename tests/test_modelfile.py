"""Model files (hbeo.model.modelfile): round trips of HBEO and VoxCNN models, every malformed file
refused with one DataError line naming it, files carrying pickled code refused without running it
(library and CLI), and the conversion of the old torch-pickle format."""
import io
import json
import pickle
import subprocess
import sys
import zipfile

import numpy as np
import pytest
import safetensors.torch
import torch
from conftest import box_grids

from hbeo.baselines.voxcnn import VoxCNN, VoxCNNBaseline, VoxCNNConfig
from hbeo.conventions import Intrinsics
from hbeo.errors import DataError
from hbeo.model import modelfile as MF
from hbeo.model.inference import HBEO
from hbeo.storage import write_npz
from hbeo.subspace.basis import ObjectSubspace

K = Intrinsics.kinect(32, 24)


# Small synthetic models, not the session's ci run (conftest): the format tests save, rewrite and
# load them dozens of times, and need no trained network (the ci model takes ~10 s to train).

@pytest.fixture(scope="module")
def hbeo_model(tiny_model):
    """conftest's tiny model, its mean shape non-empty (boxes of varied size, two classes)."""
    rng = np.random.default_rng(0)
    return tiny_model(lambda sub: {"ref_distance": 1.7, "coeff_mean": rng.normal(size=sub.dim_),
                                   "coeff_std": np.ones(sub.dim_), "profile": "ci"}, mean_grids=box_grids())


@pytest.fixture(scope="module")
def vox_model():
    torch.manual_seed(0)
    return VoxCNNBaseline(VoxCNN(VoxCNNConfig(channels=(2, 2, 2), n_classes=3, bottleneck=4)), ("a", "b", "c"),
                          {"profile": "ci", "final": {"epoch": 1, "iou": 0.25}})


@pytest.fixture(scope="module")
def files(tmp_path_factory, hbeo_model, vox_model):
    d = tmp_path_factory.mktemp("models")
    return {"hbeo": hbeo_model.save(d / "model.hbeo"), "voxcnn": vox_model.save(d / "voxcnn.hbeo")}


LOADERS = {"hbeo": HBEO.load, "voxcnn": VoxCNNBaseline.load}


def depth_images():
    d = np.zeros((3, K.height, K.width))
    for i, z in enumerate((1.5, 1.7, 2.1)):
        d[i, 6 + i: 16, 9: 20 + i] = z
    return d


def members(path) -> dict:
    with zipfile.ZipFile(path) as z:
        return {n: z.read(n) for n in z.namelist()}


def rewrite(src, dst, replace=None, drop=(), compress=zipfile.ZIP_STORED):
    """``src``'s members into a new zip ``dst``, some replaced (name -> bytes, new names appended) or dropped."""
    m = {**members(src), **(replace or {})}
    with zipfile.ZipFile(dst, "w", compress) as z:
        for name, data in m.items():
            if name not in drop:
                z.writestr(name, data)
    return dst


def edit_meta(src, dst, fn):
    meta = json.loads(members(src)["meta.json"])
    fn(meta)
    return rewrite(src, dst, {"meta.json": json.dumps(meta).encode()})


def edit_weights(src, dst, fn):
    w = safetensors.torch.load(members(src)["weights.safetensors"])
    fn(w)
    return rewrite(src, dst, {"weights.safetensors": safetensors.torch.save(w)})


# ------------------------------------------------------------------ round trips

def test_hbeo_round_trip_is_exact(hbeo_model, files):
    path = files["hbeo"]
    assert zipfile.ZipFile(path).namelist() == ["meta.json", "weights.safetensors", "subspace.npz"]
    back = HBEO.load(path)
    a, b = hbeo_model.predict(depth_images(), K), back.predict(depth_images(), K)
    for f in ("probabilities", "rotation", "translation", "coeffs", "grids"):
        assert np.array_equal(getattr(a, f), getattr(b, f)), f
    assert back.classes == hbeo_model.classes and back.intrinsics == K and back.net.cfg == hbeo_model.net.cfg
    assert back.settings == hbeo_model.settings and back.settings.ref_distance == 1.7
    assert back.settings.recenter is True and back.settings.shape_loss == "coeffs"       # the defaults
    meta = json.loads(members(path)["meta.json"])
    assert (meta["format"], meta["format_version"], meta["kind"]) == ("hbeo-model", 2, "hbeo")
    assert np.array_equal(back.subspace.basis_, hbeo_model.subspace.basis_)


def test_model_settings_have_one_default_each_and_round_trip(hbeo_model, files, tmp_path):
    S = MF.ModelSettings
    assert S.from_dict({}) == S() and S().recenter is True and S().ref_distance is None
    s = hbeo_model.settings
    assert S.from_dict(s.to_dict()) == s and json.loads(members(files["hbeo"])["meta.json"])["settings"] == s.to_dict()
    assert isinstance(s.coeff_mean, tuple) and len(s.coeff_mean) == hbeo_model.subspace.dim_
    with pytest.raises(AttributeError):
        s.recenter = False                                                        # frozen
    # a file that lacks a key means that key's default: recenter was on unless a file said otherwise
    lacking = edit_meta(files["hbeo"], tmp_path / "lacking.hbeo",
                        lambda m: [m["settings"].pop(k) for k in ("recenter", "shape_loss", "augment_roll")])
    back = HBEO.load(lacking).settings
    assert (back.recenter, back.shape_loss, back.augment_roll) == (True, "coeffs", False)
    with pytest.raises(DataError, match=r"^meta\.json: settings: object_size must be a positive number"):
        S.from_dict({"object_size": 0})
    with pytest.raises(ValueError, match="settings: unknown keys fizz"):
        HBEO(hbeo_model.net, hbeo_model.subspace, K, hbeo_model.classes, {"fizz": 1})


def test_writing_is_deterministic(hbeo_model, files, tmp_path):
    again = members(hbeo_model.save(tmp_path / "again.hbeo"))
    first = members(files["hbeo"])
    assert again["meta.json"] == first["meta.json"] and again["weights.safetensors"] == first["weights.safetensors"]


def test_voxcnn_round_trip_is_exact(vox_model, files):
    back = VoxCNNBaseline.load(files["voxcnn"])
    assert zipfile.ZipFile(files["voxcnn"]).namelist() == ["meta.json", "weights.safetensors"]
    assert back.classes == vox_model.classes and back.net.cfg == vox_model.net.cfg
    assert back.settings["final"] == {"epoch": 1, "iou": 0.25}
    rng = np.random.default_rng(1)
    f = rng.random((3, 30, 30, 30)) < 0.1
    k = f | (rng.random((3, 30, 30, 30)) < 0.3)
    for a, b in zip(vox_model.predict_partial(f, k), back.predict_partial(f, k)):
        assert np.array_equal(a, b)


def test_nan_weights_are_not_written(vox_model, tmp_path):
    net = VoxCNN(vox_model.net.cfg)
    with torch.no_grad():
        net.class_head[1].bias[0] = float("nan")
    with pytest.raises(ValueError, match="class_head.1.bias holds NaN"):
        VoxCNNBaseline(net, vox_model.classes).save(tmp_path / "nan.hbeo")
    assert not (tmp_path / "nan.hbeo").exists()


# ------------------------------------------------------------------ malformed files

def _nan_weight(w):
    w[next(k for k in w if k.endswith("weight"))][0] = float("nan")


def _nan_basis(src, dst):
    sub = ObjectSubspace.load(io.BytesIO(members(src)["subspace.npz"]))
    sub.basis_ = sub.basis_.copy()
    sub.basis_[0, 0] = np.nan
    buf = io.BytesIO()
    sub.save(buf)
    return rewrite(src, dst, {"subspace.npz": buf.getvalue()})


def _write(dst, data: bytes):
    dst.write_bytes(data)
    return dst


def _npz_bytes() -> bytes:
    buf = io.BytesIO()
    np.savez(buf, a=np.zeros(3))
    return buf.getvalue()


def _flip_byte(src, dst):
    data = bytearray(src.read_bytes())
    data[len(data) // 2] ^= 0xFF                   # inside weights.safetensors or subspace.npz
    dst.write_bytes(bytes(data))
    return dst


MALFORMED = {
    # name: (kinds it applies to, make(src, dst) -> dst, expected problem)
    "missing": (("hbeo", "voxcnn"), lambda s, d: d, "no such model file"),
    "junk": (("hbeo", "voxcnn"), lambda s, d: _write(d, b"junk"), "not a readable hbeo model file"),
    "truncated": (("hbeo", "voxcnn"), lambda s, d: _write(d, s.read_bytes()[:len(s.read_bytes()) // 2]),
                  "not a readable hbeo model file"),
    "corrupt byte": (("hbeo", "voxcnn"), _flip_byte, "not a readable hbeo model file"),
    "npz container": (("hbeo", "voxcnn"), lambda s, d: _write(d, _npz_bytes()), "not an hbeo model file"),
    "meta not json": (("hbeo", "voxcnn"), lambda s, d: rewrite(s, d, {"meta.json": b"{net_cfg"}), "is not JSON"),
    "meta NaN": (("hbeo", "voxcnn"), lambda s, d: rewrite(s, d, {"meta.json": members(s)["meta.json"].replace(
        b'"settings": {', b'"settings": {"x": NaN, ', 1)}), "is not JSON"),
    "meta not a dict": (("hbeo", "voxcnn"), lambda s, d: rewrite(s, d, {"meta.json": b"[]"}), "not an hbeo model"),
    "format 99": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m.update(format_version=99)),
                  "model format 99"),
    "no net_cfg": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m.pop("net_cfg")), 'lacks "net_cfg"'),
    "no classes": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m.pop("classes")), 'lacks "classes"'),
    "no settings": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m.pop("settings")),
                    'lacks "settings"'),
    "no intrinsics": (("hbeo",), lambda s, d: edit_meta(s, d, lambda m: m.pop("intrinsics")), 'lacks "intrinsics"'),
    "bad intrinsics": (("hbeo",), lambda s, d: edit_meta(s, d, lambda m: m["intrinsics"].update(fx="65")),
                       '"intrinsics" must hold'),
    "settings a list": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m.update(settings=[])),
                        '"settings" must be a dict'),
    "unknown key": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m.update(code="x")),
                    "unknown keys code"),
    "unknown setting": (("hbeo",), lambda s, d: edit_meta(s, d, lambda m: m["settings"].update(recentre=True)),
                        "settings: unknown keys recentre (known: object_size, recenter"),
    "setting of a wrong type": (("hbeo",), lambda s, d: edit_meta(s, d, lambda m: m["settings"].update(recenter="yes")),
                                "settings: recenter must be true or false, got str 'yes'"),
    "coefficients half given": (("hbeo",), lambda s, d: edit_meta(s, d, lambda m: m["settings"].update(coeff_mean=None)),
                                "coeff_mean and coeff_std must be given together"),
    "class count": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m["classes"].append("zz")),
                    "class names for a network with"),
    "unknown kind": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m.update(kind="beo")),
                     "unknown kind 'beo'"),
    "bad net_cfg": (("hbeo", "voxcnn"), lambda s, d: edit_meta(s, d, lambda m: m["net_cfg"].update(fizz=1)),
                    "net_cfg builds no network"),
    "other net_cfg": (("hbeo", "voxcnn"), lambda s, d: edit_meta(
        s, d, lambda m: m["net_cfg"].update(fc=[8, 8, 9]) if "fc" in m["net_cfg"]
        else m["net_cfg"].update(bottleneck=5)), "does not match net_cfg"),
    "missing tensor": (("hbeo", "voxcnn"), lambda s, d: edit_weights(s, d, lambda w: w.pop(sorted(w)[0])),
                       "does not match net_cfg: missing"),
    "extra tensor": (("hbeo", "voxcnn"), lambda s, d: edit_weights(s, d, lambda w: w.update(x=torch.zeros(2))),
                     "does not match net_cfg: unexpected x"),
    "tensor shape": (("hbeo", "voxcnn"), lambda s, d: edit_weights(
        s, d, lambda w: w.update({sorted(w)[0]: torch.zeros(1, 2, 3)})), "does not match net_cfg"),
    "tensor dtype": (("hbeo", "voxcnn"), lambda s, d: edit_weights(
        s, d, lambda w: w.update({k: w[k].double() for k in sorted(w)[:1]})), "float64"),
    "NaN weight": (("hbeo", "voxcnn"), lambda s, d: edit_weights(s, d, _nan_weight), "holds NaN"),
    "weights not safetensors": (("hbeo", "voxcnn"), lambda s, d: rewrite(s, d, {"weights.safetensors": b"\0" * 64}),
                                "not a readable safetensors"),
    "NaN subspace": (("hbeo",), _nan_basis, "subspace.npz: basis holds NaN"),
    "subspace not npz": (("hbeo",), lambda s, d: rewrite(s, d, {"subspace.npz": b"PK\3\4junk"}),
                         "subspace.npz is not a readable subspace"),
    "no subspace": (("hbeo",), lambda s, d: rewrite(s, d, drop=("subspace.npz",)), "must hold exactly"),
    "extra member": (("hbeo", "voxcnn"), lambda s, d: rewrite(s, d, {"run.py": b"print(1)"}), "must hold exactly"),
    "compressed": (("hbeo", "voxcnn"), lambda s, d: rewrite(s, d, compress=zipfile.ZIP_DEFLATED),
                   "compressed member"),
}


@pytest.mark.parametrize("kind", ["hbeo", "voxcnn"])
@pytest.mark.parametrize("case", list(MALFORMED))
def test_malformed_files_give_one_line_naming_the_file(files, tmp_path, kind, case):
    kinds, make, problem = MALFORMED[case]
    if kind not in kinds:
        pytest.skip(f"{case} concerns {kinds} files only")
    bad = make(files[kind], tmp_path / f"bad_{case.replace(' ', '_')}.hbeo")
    with pytest.raises(DataError) as err:
        LOADERS[kind](bad)
    msg = str(err.value)
    assert msg.startswith(f"{bad}: ") and problem in msg and "\n" not in msg, msg


def test_the_other_kind_is_refused(files):
    with pytest.raises(DataError, match=r"voxcnn\.hbeo: holds a VoxCNN baseline .* not an HBEO model"):
        HBEO.load(files["voxcnn"])
    with pytest.raises(DataError, match=r"model\.hbeo: holds an HBEO model, not a VoxCNN"):
        VoxCNNBaseline.load(files["hbeo"])


# ------------------------------------------------------------------ files carrying code

class Payload:
    """Unpickling this creates ``marker`` (stands in for any code a model file could carry)."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "hbeo", *args], capture_output=True, text=True)


@pytest.fixture
def payload(tmp_path):
    """(marker path, raw pickle bytes, torch.save bytes); checks the payload does run when unpickled."""
    marker = tmp_path / "MARKER"
    raw = pickle.dumps(Payload(marker))
    pickle.loads(raw)                                    # the payload works: it creates the marker...
    assert marker.exists()
    marker.unlink()                                      # ...which every test below must not see again
    buf = io.BytesIO()
    torch.save({"format_version": 1, "net_cfg": Payload(marker), "state_dict": {}}, buf)
    return marker, raw, buf.getvalue()


@pytest.mark.slow
def test_a_torch_pickle_is_refused_without_running_it(payload, tmp_path):
    marker, _, blob = payload
    crafted = tmp_path / "crafted.hbeo"
    crafted.write_bytes(blob)
    for load in (HBEO.load, VoxCNNBaseline.load):
        with pytest.raises(DataError, match=r"crafted\.hbeo: a torch pickle, which hbeo does not open.*python -m hbeo convert-model"):
            load(crafted)
    with pytest.raises(DataError, match=r"crafted\.hbeo: not an old hbeo model file that can be read without "
                                        r"running code.*GLOBAL io.open was not an allowed global by default\)$"):
        MF.convert_legacy(crafted, tmp_path / "new.hbeo")
    assert not marker.exists() and not (tmp_path / "new.hbeo").exists()
    d = tmp_path / "d.npy"
    np.save(d, np.full((24, 32), 1.7))
    out = run_cli("predict", "--model", str(crafted), "--depth", str(d), "--intrinsics", "30,30,16,12",
                  "--out", str(tmp_path / "r.json"))
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0, out.stderr
    assert str(crafted) in out.stderr and "python -m hbeo convert-model" in out.stderr
    out = run_cli("convert-model", str(crafted), str(tmp_path / "new.hbeo"))
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0 and str(crafted) in out.stderr, out.stderr
    assert not marker.exists() and not (tmp_path / "r.json").exists() and not (tmp_path / "new.hbeo").exists()


@pytest.mark.parametrize("kind", [pytest.param("hbeo", marks=pytest.mark.slow), "voxcnn"])  # hbeo: + the CLI
def test_a_pickle_under_any_member_name_is_refused_without_running_it(files, payload, tmp_path, kind):
    marker, raw, blob = payload
    for member in MF.MEMBERS[kind]:
        for what, data in (("pickle", raw), ("torch", blob)):
            crafted = rewrite(files[kind], tmp_path / f"{what}_{member}.hbeo", {member: data})
            with pytest.raises(DataError) as err:
                LOADERS[kind](crafted)
            assert str(err.value).startswith(f"{crafted}: ") and "\n" not in str(err.value)
            assert not marker.exists(), (member, what)
    if kind == "hbeo":                  # and through the command line, one member each
        d = tmp_path / "d.npy"
        np.save(d, np.full((24, 32), 1.7))
        for member in MF.MEMBERS[kind]:
            crafted = tmp_path / f"pickle_{member}.hbeo"
            out = run_cli("predict", "--model", str(crafted), "--depth", str(d), "--intrinsics", "30,30,16,12",
                          "--out", str(tmp_path / "r.json"))
            assert out.returncode == 2 and out.stderr.strip().count("\n") == 0, out.stderr
            assert str(crafted) in out.stderr and not marker.exists()


# ------------------------------------------------------------------ the old format

def legacy_hbeo(model: HBEO, path):
    """A file exactly as hbeo's old HBEO.save wrote it (torch.save of a dict, format 1)."""
    buf = io.BytesIO()
    model.subspace.save(buf)
    torch.save({"format_version": 1, "hbeo_version": "0.1.0", "net_cfg": model.net.cfg.to_dict(),
                "state_dict": model.net.state_dict(), "subspace": buf.getvalue(),
                "intrinsics": model.intrinsics.as_tuple(), "classes": list(model.classes),
                "settings": model.settings.to_dict()},
               path)
    return path


def legacy_voxcnn(model: VoxCNNBaseline, path):
    """A file exactly as the old VoxCNNBaseline.save wrote it."""
    torch.save({"format_version": 1, "kind": "hbeo-voxcnn", "hbeo_version": "0.1.0",
                "net_cfg": model.net.cfg.to_dict(), "state_dict": model.net.state_dict(),
                "classes": list(model.classes), "settings": model.settings}, path)
    return path


@pytest.mark.slow
def test_old_hbeo_file_is_refused_then_converted_in_place(hbeo_model, tmp_path):
    old = legacy_hbeo(hbeo_model, tmp_path / "model.hbeo")
    with pytest.raises(DataError, match=r"model\.hbeo: a torch pickle, which hbeo does not open.*convert-model"):
        HBEO.load(old)
    d = tmp_path / "d.npy"
    np.save(d, depth_images()[1])
    args = ("predict", "--model", str(old), "--depth", str(d), "--intrinsics", "30,30,16,12")
    out = run_cli(*args, "--out", str(tmp_path / "r.json"))
    assert out.returncode == 2 and "python -m hbeo convert-model" in out.stderr, out.stderr
    assert out.stderr.strip().count("\n") == 0
    out = run_cli("convert-model", str(old), str(old))
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.npy", "model.hbeo"]       # no temporary left
    back = HBEO.load(old)
    meta = json.loads(members(old)["meta.json"])
    assert meta["converted_from"] == {"format_version": 1, "hbeo_version": "0.1.0"}
    a, b = hbeo_model.predict(depth_images(), K), back.predict(depth_images(), K)
    assert all(np.array_equal(getattr(a, f), getattr(b, f)) for f in ("probabilities", "rotation", "coeffs", "grids"))
    assert run_cli(*args, "--out", str(tmp_path / "r.json")).returncode == 0
    again = run_cli("convert-model", str(old), str(tmp_path / "x.hbeo"))
    assert again.returncode == 2 and "already in the current model file format" in again.stderr


def test_old_voxcnn_file_is_converted(vox_model, tmp_path):
    old = legacy_voxcnn(vox_model, tmp_path / "voxcnn.pt")
    with pytest.raises(DataError, match=r"voxcnn\.pt: a torch pickle, which hbeo does not open"):
        VoxCNNBaseline.load(old)
    kind, new = MF.convert_legacy(old, tmp_path / "voxcnn.hbeo")
    assert kind == "voxcnn" and old.exists()
    back = VoxCNNBaseline.load(new)
    f = np.random.default_rng(2).random((2, 30, 30, 30)) < 0.2
    for a, b in zip(vox_model.predict_partial(f, f), back.predict_partial(f, f)):
        assert np.array_equal(a, b)


def test_conversion_stops_when_the_check_fails(hbeo_model, tmp_path):
    old = legacy_hbeo(hbeo_model, tmp_path / "model.hbeo")
    before = old.read_bytes()

    def check(legacy, converted):
        assert converted.is_file() and converted != old
        raise DataError(converted, "predictions differ")

    with pytest.raises(DataError, match="predictions differ"):
        MF.convert_legacy(old, old, check=check)
    assert old.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["model.hbeo"]


# ------------------------------------------------------------------ through the command line (issue 14, case 4)

def _subspace_without(src, dst, key):
    """``src`` with its subspace member's meta lacking ``key`` (a subspace file of another writer)."""
    with np.load(io.BytesIO(members(src)["subspace.npz"]), allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays.pop("meta")))
    meta.pop(key)
    buf = io.BytesIO()
    write_npz(buf, meta, **arrays)
    return rewrite(src, dst, {"subspace.npz": buf.getvalue()})


CLI_CASES = {
    "no net_cfg": lambda s, d: edit_meta(s, d, lambda m: m.pop("net_cfg")),
    "no classes": lambda s, d: edit_meta(s, d, lambda m: m.pop("classes")),
    "another size": lambda s, d: edit_meta(s, d, lambda m: m["net_cfg"].update(conv_channels=[4, 4, 4, 8])),
    "another image size": lambda s, d: edit_meta(s, d, lambda m: m["net_cfg"].update(image_size=[64, 48])),
    "truncated": lambda s, d: _write(d, s.read_bytes()[:len(s.read_bytes()) * 2 // 3]),
    "truncated subspace": lambda s, d: rewrite(s, d, {"subspace.npz": members(s)["subspace.npz"][:200]}),
    "subspace meta lacks params": lambda s, d: _subspace_without(s, d, "params"),
    "subspace meta lacks classes": lambda s, d: _subspace_without(s, d, "classes"),
    "empty": lambda s, d: _write(d, b""),
    "a folder": lambda s, d: (d.mkdir(), d)[1],
}


@pytest.mark.parametrize("case", list(CLI_CASES))
def test_predict_with_a_malformed_model_exits_2_with_one_line(files, tmp_path, capsys, case):
    from hbeo.cli import main
    bad = CLI_CASES[case](files["hbeo"], tmp_path / "bad.hbeo")
    d = tmp_path / "d.npy"
    np.save(d, depth_images()[1])
    out = tmp_path / "r.json"
    code = main(["predict", "--model", str(bad), "--depth", str(d), "--intrinsics", "30,30,16,12",
                 "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"error: {bad}: ") and err.count("\n") == 1, err
    assert "Traceback" not in err and not out.exists()


def test_a_subspace_file_lacking_a_key_is_one_data_error(files, tmp_path):
    """ObjectSubspace.load on a file (the run's subspace.npz) whose meta lacks a key: a DataError
    naming the file, not KeyError; on an anonymous buffer a DataError without a name (not the
    buffer's repr)."""
    bad = tmp_path / "subspace.npz"
    bad.write_bytes(members(_subspace_without(files["hbeo"], tmp_path / "m.hbeo", "params"))["subspace.npz"])
    with pytest.raises(DataError, match=rf"^{bad}: not a valid subspace file \(KeyError: 'params'\)$"):
        ObjectSubspace.load(bad)
    with pytest.raises(DataError) as err:
        ObjectSubspace.load(io.BytesIO(bad.read_bytes()))
    assert err.value.path is None and str(err.value).startswith("not a valid subspace file")


# ------------------------------------------------------------------ meta.json values nothing later can use

def _meta_text(src, dst, old: str, new: str):
    """``src`` with one piece of its meta.json's text replaced (what json.dumps cannot write: 1e400, a
    repeated key)."""
    text = members(src)["meta.json"].decode()
    assert old in text, old
    return rewrite(src, dst, {"meta.json": text.replace(old, new, 1).encode()})


def _set(*keys_value):
    *keys, value = keys_value

    def fn(meta):
        d = meta
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value
    return fn


BAD_META = {
    # name: (edit(src, dst) -> dst, the field and problem the one line must name)
    "width a float": (lambda s, d: edit_meta(s, d, _set("intrinsics", "width", 32.0)),
                      "meta.json: intrinsics.width must be a whole positive number of pixels, got 32.0"),
    "height zero": (lambda s, d: edit_meta(s, d, _set("intrinsics", "height", 0)), "intrinsics.height must be"),
    "fx infinite": (lambda s, d: _meta_text(s, d, '"fx": ', '"fx": 1e400, "fx_": '), "intrinsics.fx is not a finite"),
    "render shift a string": (lambda s, d: edit_meta(s, d, _set("settings", "render", {"shift": "x"})),
                              "meta.json: settings: render: shift must be a number, got str 'x'"),
    "render distance a word": (lambda s, d: edit_meta(s, d, _set("settings", "render", {"distance": "far"})),
                               "settings: render: distance must be a pair of numbers, got 'far'"),
    "render distance digits": (lambda s, d: edit_meta(s, d, _set("settings", "render", {"distance": "12"})),
                               "settings: render: distance must be a pair of numbers"),
    "render distance negative": (lambda s, d: edit_meta(s, d, _set("settings", "render", {"distance": [-2, -1]})),
                                 "settings: render: distance must be finite metres with 0 < min <= max"),
    "render unknown key": (lambda s, d: edit_meta(s, d, _set("settings", "render", {"shift": 0.05, "fizz": 1})),
                           "settings: render: unknown keys fizz"),
    "render views a float": (lambda s, d: edit_meta(s, d, _set("settings", "render", {"views_per_object": 2.5})),
                             "settings: render: views_per_object must be an integer"),
    "coefficients of another length": (
        lambda s, d: edit_meta(s, d, lambda m: m["settings"].update(coeff_mean=[0.0] * 5, coeff_std=[1.0] * 5)),
        "settings: coeff_mean has 5 values for a network with"),
    "class counts of another length": (lambda s, d: edit_meta(s, d, _set("settings", "class_counts", [1, 2, 3])),
                                       "meta.json: settings: class_counts has 3 entries for 2 classes"),
    "object size infinite": (lambda s, d: _meta_text(s, d, '"object_size": 1.0', '"object_size": 1e400'),
                             "meta.json: settings.object_size is not a finite number"),
    "ref distance infinite": (lambda s, d: _meta_text(s, d, '"ref_distance": 1.7', '"ref_distance": 1e400'),
                              "meta.json: settings.ref_distance is not a finite number"),
    "unknown profile": (lambda s, d: edit_meta(s, d, _set("settings", "profile", "nosuch")),
                        "settings: profile must be a profile name"),
    "profile a list": (lambda s, d: edit_meta(s, d, _set("settings", "profile", ["ci"])),
                       "settings: profile must be a profile name (one of ci, cpu"),
    "unknown shape loss": (lambda s, d: edit_meta(s, d, _set("settings", "shape_loss", "nosuch")),
                           "settings: shape_loss must be one of coeffs, voxels"),
    "a repeated key": (lambda s, d: _meta_text(s, d, '"recenter": true', '"recenter": false, "recenter": true'),
                       "meta.json is not JSON (key \"recenter\" appears twice in one object)"),
    "an empty class name": (lambda s, d: edit_meta(s, d, lambda m: m["classes"].__setitem__(0, "")),
                            "meta.json: classes[0] must be a class name"),
    "a repeated class name": (lambda s, d: edit_meta(s, d, lambda m: m["classes"].__setitem__(1, m["classes"][0])),
                              "\"classes\" must be distinct class names; 'chair' appears twice"),
    "a class the subspace lacks": (lambda s, d: edit_meta(s, d, lambda m: m["classes"].__setitem__(0, "zebra")),
                                   "meta.json: classes 'zebra' are not classes of subspace.npz"),
}


@pytest.mark.parametrize("case", list(BAD_META))
def test_meta_values_nothing_later_can_use_are_one_line_naming_file_and_field(files, tmp_path, case):
    make, problem = BAD_META[case]
    bad = make(files["hbeo"], tmp_path / f"bad_{case.replace(' ', '_')}.hbeo")
    with pytest.raises(DataError) as err:
        HBEO.load(bad)
    msg = str(err.value)
    assert msg.startswith(f"{bad}: ") and problem in msg and "\n" not in msg, msg


def test_a_repeated_key_or_an_infinite_number_is_refused_in_a_voxcnn_file_too(files, tmp_path):
    bad = _meta_text(files["voxcnn"], tmp_path / "dup.hbeo", '"profile": "ci"', '"profile": "ci", "profile": "x"')
    with pytest.raises(DataError, match=r"dup\.hbeo: meta\.json is not JSON \(key \"profile\" appears twice"):
        VoxCNNBaseline.load(bad)
    bad = _meta_text(files["voxcnn"], tmp_path / "inf.hbeo", '"iou": 0.25', '"iou": 1e400')
    with pytest.raises(DataError, match=r"inf\.hbeo: meta\.json: settings\.final\.iou is not a finite number"):
        VoxCNNBaseline.load(bad)


@pytest.mark.parametrize("case", ["width a float", "render shift a string", "render distance negative",
                                  "object size infinite", "an empty class name"])
def test_predict_with_an_unusable_meta_value_exits_2_naming_the_file(files, tmp_path, capsys, case):
    from hbeo.cli import main
    make, problem = BAD_META[case]
    bad = make(files["hbeo"], tmp_path / "bad.hbeo")
    d = tmp_path / "d.npy"
    np.save(d, depth_images()[1])
    out = tmp_path / "r.json"
    code = main(["predict", "--model", str(bad), "--depth", str(d), "--intrinsics", "30,30,16,12", "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"error: {bad}: ") and problem in err and err.count("\n") == 1, err
    assert not out.exists()


def test_writing_refuses_what_reading_would(hbeo_model, tmp_path):
    """The one check runs before a file is written: a model whose settings its file could not hold is not saved."""
    m = HBEO(hbeo_model.net, hbeo_model.subspace, K, hbeo_model.classes, {"coeff_mean": [0.0] * 3,
                                                                         "coeff_std": [1.0] * 3})
    with pytest.raises(ValueError, match="settings: coeff_mean has 3 values for a network with"):
        m.save(tmp_path / "m.hbeo")
    assert not (tmp_path / "m.hbeo").exists()


# ------------------------------------------------------------------ damaged old files (convert-model)

def _legacy_blob(model: HBEO) -> dict:
    buf = io.BytesIO()
    model.subspace.save(buf)
    return {"format_version": 1, "hbeo_version": "0.1.0", "net_cfg": model.net.cfg.to_dict(),
            "state_dict": model.net.state_dict(), "subspace": buf.getvalue(),
            "intrinsics": model.intrinsics.as_tuple(), "classes": list(model.classes),
            "settings": model.settings.to_dict()}


def _shape(blob):
    name = next(k for k, v in blob["state_dict"].items() if v.ndim == 2)
    blob["state_dict"][name] = torch.zeros(3, 3)


DAMAGED_LEGACY = {
    # name: (damage(blob), what the one line must say after the old file's name)
    "a tensor of another shape": (_shape, "cannot be converted: weights.safetensors does not match net_cfg"),
    "subspace a str": (lambda b: b.update(subspace="junk"), "subspace must be bytes (a subspace .npz), got str"),
    "subspace a number": (lambda b: b.update(subspace=5), "subspace must be bytes (a subspace .npz), got int"),
    "subspace garbage bytes": (lambda b: b.update(subspace=b"\0junk" * 20), "subspace is not a readable subspace"),
    "four intrinsics": (lambda b: b.update(intrinsics=b["intrinsics"][:4]), "intrinsics must hold 6 numbers"),
    "seven intrinsics": (lambda b: b.update(intrinsics=(*b["intrinsics"], 1.0)), "intrinsics must hold 6 numbers"),
    "an unknown setting": (lambda b: b["settings"].update(fizz=1), "cannot be converted (ValueError: settings: unknown keys fizz"),
    "classes a string": (lambda b: b.update(classes="ab"), "classes must be a list of class names, got str"),
    "a width of a float": (lambda b: b.update(intrinsics=(*b["intrinsics"][:4], 32.0, 24)),
                           "intrinsics.width must be a whole positive number"),
}


@pytest.mark.parametrize("case", list(DAMAGED_LEGACY))
def test_converting_a_damaged_old_file_is_one_line_naming_it(hbeo_model, tmp_path, capsys, case):
    from hbeo.cli import main
    damage, problem = DAMAGED_LEGACY[case]
    blob = _legacy_blob(hbeo_model)
    damage(blob)
    old, new = tmp_path / "old.hbeo", tmp_path / "new.hbeo"
    torch.save(blob, old)
    code = main(["convert-model", str(old), str(new)])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"error: {old}: ") and problem in err and err.count("\n") == 1, err
    assert "Traceback" not in err and sorted(p.name for p in tmp_path.iterdir()) == ["old.hbeo"]
