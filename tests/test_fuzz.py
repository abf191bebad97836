"""Fuzz suite (issue 14): property tests with hypothesis over the files and options a user hands hbeo.

Inputs: depth images (shapes, dtypes float16..bool, NaN/inf, all zero, huge values, PNG/TIFF/.npy,
truncated or with flipped bytes), intrinsics strings, OFF meshes (random counts, NaN, truncation,
byte flips), grid files (ModelNet10 30^3 archives and grid sets: random dtypes/shapes/NaN,
truncated, flipped bytes) and model files (a real tiny model truncated, with flipped bytes, a
member removed or cut short). What must hold, whatever the input:

- the library raises only hbeo's errors (``DataError`` / ``HBEOError`` / ``ValueError``), one line,
  naming the file (or, for intrinsics, the option);
- ``python -m hbeo predict`` (run in-process through :func:`hbeo.cli.main`, to stay fast): no
  traceback escapes, the exit status is 0 or 2, a non-zero exit leaves no output file (nor a
  temporary), and no file that was there before is modified (hashed before and after).

Budget: the ``ci`` profile (a few dozen examples per property, derandomized so CI is
deterministic, no example database) keeps the file under a minute; the ``long`` profile
(``@slow``, ~10x the examples, random seeds) runs only when ``HBEO_FUZZ_LONG=1``: a local hunt for
new failures, e.g. ``HBEO_FUZZ_LONG=1 pytest tests/test_fuzz.py -m slow``.

The model is a tiny untrained one built here (as tests/test_modelfile.py builds its), not the
session's trained ci model: the properties need a valid file, not a good one.
"""
import collections
import errno
import contextlib
import hashlib
import io
import json
import os
import tempfile
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings, strategies as st
from hypothesis.extra import numpy as hnp

from hbeo.cli import main
from hbeo.conventions import Intrinsics
from hbeo.data.datasets import Vox30Dataset
from hbeo.data.gridset import GridSet
from hbeo.data.meshio import read_mesh
from hbeo.data.voxel import voxelize
from hbeo.errors import HBEOError
from hbeo.model.inference import HBEO
from hbeo.model.depthfile import parse_intrinsics, read_depth

K = Intrinsics.kinect(32, 24)
K_TEXT = f"{K.fx},{K.fy},{K.cx},{K.cy}"
LONG = os.environ.get("HBEO_FUZZ_LONG") == "1"
#: examples per property and profile; "ci" is what every test run does
EXAMPLES = {"ci": 1.0, "long": 10.0}
PROFILES = ["ci", pytest.param("long", marks=[pytest.mark.slow, pytest.mark.skipif(
    not LONG, reason="the long fuzz profile runs with HBEO_FUZZ_LONG=1")])]


#: outcomes seen by the running property (:func:`outcome`), so each test can check it reached both
#: sides (accepted and refused inputs; exit 0 and 2), i.e. that its generator is not degenerate
SEEN: collections.Counter = collections.Counter()


def outcome(what: str) -> None:
    SEEN[what] += 1
    event(what)


def fuzz(profile: str, n: int, strategy, prop) -> collections.Counter:
    """Check ``prop(example)`` over ``n`` examples of ``strategy`` (times the profile's factor);
    returns the outcomes counted over the run."""
    SEEN.clear()
    cfg = settings(max_examples=int(n * EXAMPLES[profile]), deadline=None, derandomize=profile == "ci",
                   database=None, print_blob=True,
                   suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                          HealthCheck.filter_too_much])
    cfg(given(strategy)(prop))()
    return collections.Counter(SEEN)


def assert_both_sides(seen: collections.Counter, cli: bool) -> None:
    """The examples reached both answers (else the generator, not the code, decides the result)."""
    want = {"library: accepted", "library: refused"} | ({"cli: exit 0", "cli: exit 2"} if cli else set())
    assert want <= set(seen), f"the examples never reached {sorted(want - set(seen))}: {dict(seen)}"


# ------------------------------------------------------------------ the tiny model

@pytest.fixture(scope="module")
def model_bytes(tmp_path_factory, tiny_model) -> bytes:
    """A valid HBEO model file (two classes, 32x24 images, untrained: conftest's tiny model), as bytes."""
    model = tiny_model(lambda sub: {"ref_distance": 1.7, "coeff_mean": np.zeros(sub.dim_),
                                     "coeff_std": np.ones(sub.dim_), "profile": "ci"})
    return model.save(tmp_path_factory.mktemp("fuzz") / "model.hbeo").read_bytes()


def good_depth() -> np.ndarray:
    d = np.zeros((K.height, K.width), np.float32)
    d[6:16, 9:21] = 1.7
    return d


# ------------------------------------------------------------------ checks

def snapshot(folder: Path) -> dict[str, str]:
    """{relative path: sha256} of every file under ``folder`` (folders as "dir")."""
    out = {}
    for p in sorted(folder.rglob("*")):
        out[str(p.relative_to(folder))] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def expect_clean(fn, name):
    """``fn()``'s value, or None when it raised one of hbeo's errors: one line naming ``name``.
    Any other exception propagates (and fails the property)."""
    try:
        value = fn()
        outcome("library: accepted")
        return value
    except (HBEOError, ValueError) as err:
        outcome("library: refused")
        msg = str(err)
        assert msg and "\n" not in msg, repr(msg)
        assert str(name) in msg, f"message does not name {name}: {msg}"
        return None


def run_cli(folder: Path, argv: list[str], outputs: list[Path]) -> tuple[int, str]:
    """``hbeo.cli.main(argv)`` in-process, in ``folder`` (which holds its inputs); checks that the
    exit status is 0 or 2, that no traceback or exception escaped, and that only ``outputs``
    changed: all of them on success, none (nor a temporary) on failure."""
    before = snapshot(folder)
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as e:              # argparse's usage errors: status 2
            code = e.code
    err = err.getvalue()
    outcome(f"cli: exit {code}")
    assert code in (0, 2), (code, err)
    assert "Traceback" not in err, err
    after = snapshot(folder)
    changed = {k for k in before.keys() | after.keys() if before.get(k) != after.get(k)}
    wanted = {str(p.relative_to(folder)) for p in outputs}
    if code == 2:
        assert err.strip().splitlines()[-1].split("error: ", 1)[-1], err      # says what is wrong
        assert not changed, f"exit 2 but changed {sorted(changed)}: {err}"
    else:
        assert changed == wanted, f"exit 0 changed {sorted(changed)}, expected {sorted(wanted)}: {err}"
    return code, err


# ------------------------------------------------------------------ mutations of bytes

mutations = st.one_of(
    st.none(),
    st.tuples(st.just("truncate"), st.floats(0, 1)),
    st.tuples(st.just("flip"), st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(1, 255)),
                                        min_size=1, max_size=4)),
)


def rarely(strategy):
    """None two times in three, else an example of ``strategy`` (a spoiler applied to some inputs)."""
    return st.one_of(st.none(), st.none(), strategy)


def mutate(data: bytes, m) -> bytes:
    if m is None or not data:
        return data
    if m[0] == "truncate":
        return data[:int(len(data) * m[1])]
    b = bytearray(data)
    for where, mask in m[1]:
        b[int(where * len(b))] ^= mask
    return bytes(b)


# ------------------------------------------------------------------ depth images

DEPTH_DTYPES = (np.float16, np.float32, np.float64, np.uint16, np.uint8, np.int8, np.int16, np.int32, np.bool_)


@st.composite
def depth_files(draw):
    """(file name, bytes, --depth-scale or None, whether to ask for --mesh) of a depth image,
    plausible or not."""
    dtype = np.dtype(draw(st.sampled_from(DEPTH_DTYPES)))
    kind = draw(st.sampled_from(["object", "object", "object", "random", "constant"]))
    if kind == "object":                         # an object at some distance in an image of some size
        h, w = draw(st.sampled_from([(K.height, K.width)] * 3 + [(48, 64), (3, 4), (1, 1), (300, 400)]))
        z = draw(st.sampled_from([1.7, 1.7, 2.5, 0.0, -1.0, 1e-9, 1e30, float("nan"), float("inf"), 1700.0]))
        a = np.zeros((h, w))
        a[h // 4: max(h // 4 + 1, 3 * h // 4), w // 4: max(w // 4 + 1, 3 * w // 4)] = z
        if draw(st.booleans()):
            a[0, 0] = draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e30, -5.0]))
        if dtype.kind in "iu":                   # integers hold millimetres
            info = np.iinfo(dtype)
            a = np.clip(np.nan_to_num(a * 1000, nan=0, posinf=info.max, neginf=info.min), info.min, info.max)
        with np.errstate(all="ignore"):
            arr = a.astype(dtype)
    elif kind == "constant":
        shape = draw(hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=40))
        arr = np.full(shape, draw(st.sampled_from([0, 1, 255])), dtype)
    else:
        shape = draw(hnp.array_shapes(min_dims=0, max_dims=3, min_side=0, max_side=24))
        arr = draw(hnp.arrays(dtype, shape))       # any values, NaN/inf/huge for floats
    suffix = ".npy"
    if arr.ndim == 2 and arr.size and dtype in (np.uint16, np.uint8) and draw(st.booleans()):
        suffix = ".png"
    elif arr.ndim == 2 and arr.size and dtype == np.float32 and draw(st.booleans()):
        suffix = ".tiff"
    buf = io.BytesIO()
    if suffix == ".npy":
        np.save(buf, arr, allow_pickle=False)
    else:
        from PIL import Image
        Image.fromarray(arr).save(buf, format="PNG" if suffix == ".png" else "TIFF")
    data = mutate(buf.getvalue(), draw(rarely(mutations)))
    scale = draw(rarely(st.sampled_from([0.001, 1.0, 0.0, -1.0, 1e30, 1e-30, float("nan")])))
    return "depth" + suffix, data, scale, draw(st.booleans())


@pytest.mark.parametrize("profile", PROFILES)
def test_depth_images(model_bytes, profile):
    def prop(example):
        name, data, scale, with_mesh = example
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            (tmp / "model.hbeo").write_bytes(model_bytes)
            depth = tmp / name
            depth.write_bytes(data)
            d = expect_clean(lambda: read_depth(depth, scale), depth)
            if d is not None:
                assert d.dtype == np.float32 and d.ndim == 2 and np.isfinite(d).all() and (d >= 0).all()
            out, mesh = tmp / "r.json", tmp / "shape.ply"
            argv = ["predict", "--model", str(tmp / "model.hbeo"), "--depth", str(depth), f"--intrinsics={K_TEXT}",
                    "--out", str(out)] + (["--mesh", str(mesh)] if with_mesh else []) \
                + ([f"--depth-scale={scale}"] if scale is not None else [])
            run_cli(tmp, argv, [out] + ([mesh] if with_mesh else []))
    seen = fuzz(profile, 80, depth_files(), prop)
    assert_both_sides(seen, cli=True)


# ------------------------------------------------------------------ intrinsics

_number = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                    st.integers(-10 ** 6, 10 ** 6).map(str),
                    st.sampled_from(["0", "1e-9", "1e30", "-1", "26.25", "15.5", "11.5", "nan", "inf", "", " "]))
intrinsics_texts = st.one_of(
    st.just(K_TEXT),
    st.lists(st.floats(0.2, 5), min_size=4, max_size=4).map(        # the right ones, scaled
        lambda f: ",".join(repr(float(v) * x) for v, x in zip(K_TEXT.split(","), f))),
    st.text(max_size=30),
    st.lists(_number, min_size=0, max_size=6).map(",".join),
    st.tuples(st.integers(0, 3), _number).map(                      # one field of the right values changed
        lambda t: ",".join(t[1] if i == t[0] else v for i, v in enumerate(K_TEXT.split(",")))),
)


@pytest.mark.parametrize("profile", PROFILES)
def test_intrinsics(model_bytes, profile):
    def prop(text):
        expect_clean(lambda: parse_intrinsics(text, K.width, K.height), "intrinsics")
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            (tmp / "model.hbeo").write_bytes(model_bytes)
            np.save(tmp / "depth.npy", good_depth())
            out = tmp / "r.json"
            run_cli(tmp, ["predict", "--model", str(tmp / "model.hbeo"), "--depth", str(tmp / "depth.npy"),
                          f"--intrinsics={text}", "--out", str(out)], [out])
    seen = fuzz(profile, 50, intrinsics_texts, prop)
    assert_both_sides(seen, cli=True)


# ------------------------------------------------------------------ meshes

_coord = st.one_of(st.floats(-2, 2), st.sampled_from([float("nan"), float("inf"), 1e30, -1e30, 0.0]))


@st.composite
def off_texts(draw):
    """OFF text: a small mesh (a box's corners, or random points) with valid faces, then maybe
    NaN/huge coordinates, bad indices, a wrong header, cut or flipped bytes."""
    n_v = draw(st.integers(3, 8))
    corners = [(x, y, z) for x in (0.0, 1.0) for y in (0.0, 0.5) for z in (0.0, 2.0)]
    verts = draw(st.one_of(st.just(corners[:n_v]), st.lists(st.tuples(*[st.floats(-2, 2)] * 3),
                                                              min_size=n_v, max_size=n_v)))
    faces = draw(st.lists(st.lists(st.integers(0, n_v - 1), min_size=3, max_size=4, unique=True),
                          min_size=1, max_size=8))
    hv, hf = n_v, len(faces)
    spoiler = draw(st.sampled_from(["none", "none", "coord", "index", "counts", "no faces"]))
    if spoiler == "coord":
        verts[draw(st.integers(0, n_v - 1))] = (draw(_coord), 0.0, 0.0)
    elif spoiler == "index":
        faces[0][0] = draw(st.sampled_from([-1, n_v, 10 ** 9]))
    elif spoiler == "counts":
        hv, hf = draw(st.integers(0, 10 ** 9)), draw(st.integers(-2, 10))
    elif spoiler == "no faces":
        faces, hf = [], 0
    header = draw(st.sampled_from(["OFF\n{} {} 0\n", "OFF{} {} 0\n", "{} {} 0\n", "OFF\n# c\n{} {}\n"]))
    body = "".join(f"{x!r} {y!r} {z!r}\n" for x, y, z in verts)
    body += "".join(f"{len(f)} {' '.join(map(str, f))}\n" for f in faces)
    return mutate((header.format(hv, hf) + body).encode(), draw(rarely(mutations)))


@pytest.mark.parametrize("profile", PROFILES)
def test_off_meshes(profile):
    def prop(data):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "m.off"
            path.write_bytes(data)
            mesh = expect_clean(lambda: read_mesh(path), path)
            if mesh is not None:
                g = expect_clean(lambda: voxelize(mesh), path)
                assert g is None or (g.shape == (30, 30, 30) and g.dtype == bool and g.any())
    seen = fuzz(profile, 80, off_texts(), prop)
    assert_both_sides(seen, cli=False)


# ------------------------------------------------------------------ grid files

GRID_DTYPES = (np.bool_, np.uint8, np.int8, np.int64, np.float16, np.float32, np.float64)


@st.composite
def vox30_files(draw):
    """A ModelNet10 30^3 archive (X_/y_/names_ per split, classes) of grids of some dtype, maybe
    with one array of another shape, values (NaN, 0.5, 2, labels out of range) or missing, the
    bytes maybe cut or flipped."""
    arrays = {"classes": np.array(["a", "b"])}
    for split in ("train", "test"):
        n = draw(st.integers(0, 3))
        X = np.zeros((n, 30, 30, 30), draw(st.sampled_from(GRID_DTYPES)))
        X[..., 3:9] = 1
        arrays.update({f"X_{split}": X, f"y_{split}": np.arange(n) % 2,
                       f"names_{split}": np.array([f"o{i}" for i in range(n)])})
    spoiler = draw(st.sampled_from(["none", "none", "value", "shape", "labels", "float labels", "missing"]))
    split = draw(st.sampled_from(["train", "test"]))
    X, y = arrays[f"X_{split}"], arrays[f"y_{split}"]
    if spoiler == "value" and X.size:
        bad = [np.nan, np.inf, 0.5, -1.0, 2.0] if X.dtype.kind == "f" else [2, 7, 3]
        X.flat[draw(st.integers(0, X.size - 1))] = draw(st.sampled_from(bad))
    elif spoiler == "shape":
        arrays[f"X_{split}"] = np.ones((len(X),) + draw(st.sampled_from([(30, 30), (2, 2, 2), (30, 30, 31)])), X.dtype)
    elif spoiler == "labels":
        arrays[f"y_{split}"] = draw(st.sampled_from([y + 2, y - 1, np.append(y, 0), y[:, None]]))
    elif spoiler == "float labels":
        arrays[f"y_{split}"] = np.full(len(y), np.nan)
    elif spoiler == "missing":
        arrays.pop(draw(st.sampled_from(sorted(arrays))))
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return mutate(buf.getvalue(), draw(rarely(mutations)))


@pytest.mark.parametrize("profile", PROFILES)
def test_vox30_files(profile):
    def prop(data):
        with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
            warnings.simplefilter("ignore")          # the count of skipped empty grids
            path = Path(tmp) / "vox30.npz"
            path.write_bytes(data)
            ds = expect_clean(lambda: Vox30Dataset(path), path)
            for r in ds or ():
                g = r.grid()
                assert g.shape == (30, 30, 30) and g.dtype == bool and g.any() and r.cls in ("a", "b")
    seen = fuzz(profile, 60, vox30_files(), prop)
    assert_both_sides(seen, cli=False)


@st.composite
def gridset_files(draw):
    n = draw(st.integers(0, 4))
    grids = np.zeros((n, 30, 30, 30), bool)
    grids[:, 4:9, 4:9, 4:9] = True
    labels = np.arange(n) % 2
    gs = GridSet(grids, labels, np.array([f"o{i}" for i in range(n)]), ("a", "b"), "train")
    buf = io.BytesIO()
    with tempfile.TemporaryDirectory() as tmp:
        data = gs.save(Path(tmp) / "g.npz").read_bytes()
    if draw(st.integers(0, 2)) == 0:          # members rewritten: labels of another dtype or range, ids cut
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        arrays["labels"] = draw(st.sampled_from([labels + 5, labels.astype(np.float32) * np.nan, labels[:1], -labels,
                                                 labels.astype(np.uint8), np.zeros((n, 2))]))
        if draw(st.booleans()):
            arrays["ids"] = arrays["ids"][:max(n - 1, 0)]
        np.savez(buf, **arrays)
        data = buf.getvalue()
    return mutate(data, draw(rarely(mutations)))


@pytest.mark.parametrize("profile", PROFILES)
def test_gridset_files(profile):
    def prop(data):
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / "grids_train.npz"
            path.write_bytes(data)
            gs = expect_clean(lambda: GridSet.load(path), path)
            if gs is not None:
                assert gs.grids.dtype == bool and gs.grids.shape[1:] == (30, 30, 30)
                assert len(gs.labels) == len(gs.ids) == len(gs) and set(gs.labels) <= {0, 1}
    seen = fuzz(profile, 60, gridset_files(), prop)
    assert_both_sides(seen, cli=False)


# ------------------------------------------------------------------ model files

MEMBERS = ("meta.json", "weights.safetensors", "subspace.npz")


@st.composite
def model_mutations(draw):
    """How to spoil the model file: its bytes (cut, flipped), or a member removed, cut or flipped."""
    return draw(st.one_of(
        mutations.map(lambda m: ("bytes", m)),
        st.tuples(st.just("drop"), st.sampled_from(MEMBERS)),
        st.tuples(st.just("member"), st.sampled_from(MEMBERS), mutations),
    ))


def spoil(data: bytes, how) -> bytes:
    if how[0] == "bytes":
        return mutate(data, how[1])
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        members = {n: z.read(n) for n in z.namelist()}
    if how[0] == "drop":
        members.pop(how[1])
    else:
        members[how[1]] = mutate(members[how[1]], how[2])
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_STORED) as z:
        for n, b in members.items():
            z.writestr(n, b)
    return buf.getvalue()


@pytest.mark.parametrize("profile", PROFILES)
def test_model_files(model_bytes, profile):
    def prop(how):
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            model = tmp / "model.hbeo"
            model.write_bytes(spoil(model_bytes, how))
            m = expect_clean(lambda: HBEO.load(model), model)
            np.save(tmp / "depth.npy", good_depth())
            out = tmp / "r.json"
            code, err = run_cli(tmp, ["predict", "--model", str(model), "--depth", str(tmp / "depth.npy"),
                                      f"--intrinsics={K_TEXT}", "--out", str(out)], [out])
            if m is None:                     # a file the library refuses, the command refuses, naming it
                assert code == 2 and str(model) in err, err
    seen = fuzz(profile, 60, model_mutations(), prop)
    assert_both_sides(seen, cli=True)


# ------------------------------------------------------------------ output paths

OUT_CHOICES = ("r.json", "old.json", "missing/r.json", ".", "depth.npy", "model.hbeo", "mask.npy")
MESH_CHOICES = (None, None, "s.ply", "s.obj", "s.xyz", "missing/s.ply", "depth.npy", "model.hbeo", "r.json", ".")


@pytest.mark.parametrize("profile", PROFILES)
def test_output_paths(model_bytes, profile):
    """--out and --mesh naming a fresh file, an old result, a missing folder, a folder, or one of
    the command's inputs (issue 14, cases 3 and 6): never an input overwritten, never a partial output."""
    def prop(choice):
        out_name, mesh_name = choice
        with tempfile.TemporaryDirectory() as tmp:
            tmp = Path(tmp)
            (tmp / "model.hbeo").write_bytes(model_bytes)
            np.save(tmp / "depth.npy", good_depth())
            np.save(tmp / "mask.npy", good_depth() > 0)
            (tmp / "old.json").write_text("{}")
            inputs = {"model.hbeo", "depth.npy", "mask.npy"}
            out = tmp / out_name
            outputs = [out] + ([tmp / mesh_name] if mesh_name else [])
            argv = ["predict", "--model", str(tmp / "model.hbeo"), "--depth", str(tmp / "depth.npy"),
                    "--mask", str(tmp / "mask.npy"), f"--intrinsics={K_TEXT}", "--out", str(out)] \
                + (["--mesh", str(tmp / mesh_name)] if mesh_name else [])
            may_succeed = (not {out_name, mesh_name} & (inputs | {"."}) and "missing" not in f"{out_name}{mesh_name}"
                           and out_name != mesh_name and not str(mesh_name).endswith(".xyz"))
            if not may_succeed:                      # run_cli checks nothing changed on exit 2
                code, err = run_cli(tmp, argv, outputs)
                assert code == 2, f"{choice}: exit 0 ({err})"
            else:
                run_cli(tmp, argv, outputs)
    seen = fuzz(profile, 30, st.tuples(st.sampled_from(OUT_CHOICES), st.sampled_from(MESH_CHOICES)), prop)
    assert {"cli: exit 0", "cli: exit 2"} <= set(seen), dict(seen)


# ------------------------------------------------------------------ issue 30: errors that point the right way
#
# Each case: exit 2, stderr exactly one line "error: PATH-or-OPTION: problem", no traceback, nothing
# half-written. Operating-system failures are faked (a full disk, a read-only file system), so the
# tests run without root or mounts.

def cli_error(argv: list[str]) -> str:
    """``main(argv)`` in-process: asserts exit 2 and one line on stderr, no traceback, nothing on stdout
    but what ran before the failure; returns the line (without ``error: ``)."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        try:
            code = main(argv)
        except SystemExit as e:              # argparse's usage errors
            code = e.code
    lines = err.getvalue().splitlines()
    assert code == 2, (code, err.getvalue())
    assert "Traceback" not in err.getvalue(), err.getvalue()
    assert len(lines) == 1 and lines[0].startswith("error: "), err.getvalue()
    return lines[0].removeprefix("error: ")


@pytest.fixture
def predict_folder(tmp_path, model_bytes):
    """tmp_path with model.hbeo and a good depth.npy; returns the predict argv without --out."""
    (tmp_path / "model.hbeo").write_bytes(model_bytes)
    np.save(tmp_path / "depth.npy", good_depth())
    return ["predict", "--model", str(tmp_path / "model.hbeo"), "--depth", str(tmp_path / "depth.npy"),
            f"--intrinsics={K_TEXT}"]


def _no_space(*a, **kw):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


@pytest.mark.parametrize("which", ["--out", "--mesh"])
def test_disk_full_while_writing_predict_outputs(predict_folder, tmp_path, monkeypatch, which):
    """A full disk while the result (or the mesh) is written: one line naming that file, nothing left."""
    import hbeo.storage
    real = hbeo.storage.os.fsync
    target = tmp_path / ("r.json" if which == "--out" else "s.ply")

    def fsync(fd):                           # the disk fills while this output's bytes go out
        if Path(os.readlink(f"/proc/self/fd/{fd}")).name.startswith(f".{target.name}."):
            _no_space()
        real(fd)
    monkeypatch.setattr(hbeo.storage.os, "fsync", fsync)
    import trimesh                           # the tiny untrained model completes nothing: a box stands in
    monkeypatch.setattr(HBEO, "to_mesh", lambda self, pred: trimesh.creation.box())
    before = snapshot(tmp_path)
    line = cli_error(predict_folder + ["--out", str(tmp_path / "r.json"), "--mesh", str(tmp_path / "s.ply")])
    assert line == f"{target}: no space left on the device", line
    assert snapshot(tmp_path) == before                      # neither output, no temporary


def test_read_only_file_system_voxelize_out(tmp_path, monkeypatch):
    import hbeo.storage
    ro = type("StatVFS", (), {"f_flag": os.ST_RDONLY})()
    monkeypatch.setattr(hbeo.storage.os, "access", lambda *a, **kw: False)
    monkeypatch.setattr(hbeo.storage.os, "statvfs", lambda p: ro)
    line = cli_error(["voxelize", "--profile", "ci", "--out", str(tmp_path / "v.npz")])
    assert str(tmp_path / "v.npz") in line and "read-only file system" in line, line
    assert not list(tmp_path.iterdir())


def test_read_only_file_system_when_writing(tmp_path, monkeypatch):
    """The file system turns read-only after the checks: atomic_file's temporary cannot be made."""
    import hbeo.storage

    def mkstemp(*a, dir=None, **kw):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(Path(dir) / ".v.npz.x.tmp"))
    monkeypatch.setattr(hbeo.storage.tempfile, "mkstemp", mkstemp)
    with pytest.raises(OSError) as info:
        hbeo.storage.atomic_text(tmp_path / "v.npz", "x")
    from hbeo.errors import os_error_line
    assert os_error_line(info.value) == f"{tmp_path / 'v.npz'}: read-only file system"


def test_predict_out_in_proc_names_the_real_problem(predict_folder):
    if not Path("/proc/version").is_file():
        pytest.skip("no /proc")
    line = cli_error(predict_folder + ["--out", "/proc/version"])
    assert line.startswith("/proc/version: ") and "tmp" not in line, line


@pytest.mark.parametrize("setting", ["HBEO_RESULTS", "HBEO_CACHE"])
def test_path_setting_naming_a_file(tmp_path, monkeypatch, setting):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    monkeypatch.setenv(setting, str(blocker))
    argv = ["voxelize", "--profile", "ci"] + (["--out", str(tmp_path / "run")] if setting == "HBEO_CACHE" else [])
    line = cli_error(argv)
    assert line == f"{blocker}: not a folder (a file is in the way) (set by {setting})", line


def test_unexpected_error_is_a_bug_with_its_traceback(monkeypatch, capsys):
    import hbeo.cli

    def boom(args):
        raise RuntimeError("boom")
    monkeypatch.setattr(hbeo.cli, "cmd_report", boom)
    assert main(["report", "--run", "x"]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "RuntimeError: boom" in err
    assert err.splitlines()[-1].startswith("error: unexpected RuntimeError: this is a bug in hbeo"), err


@pytest.mark.parametrize("missing, is_bug", [("torch", False), ("torch.cuda", False), ("hbeo.nothere", True)])
def test_missing_package_is_one_line_unless_it_is_hbeos_own(monkeypatch, capsys, missing, is_bug):
    import hbeo.cli

    def needs(args):
        raise ModuleNotFoundError(f"No module named '{missing}'", name=missing)
    monkeypatch.setattr(hbeo.cli, "cmd_report", needs)
    code = main(["report", "--run", "x"])
    err = capsys.readouterr().err
    if is_bug:
        assert code == 1 and "Traceback" in err and "this is a bug in hbeo" in err, err
    else:
        assert code == 2 and "Traceback" not in err, err
        line = err.strip()
        assert line.startswith("error: this Python (") and "has no package 'torch'" in line and "make setup" in line


@pytest.mark.parametrize("argv, option", [
    (["train", "--epochs", "-1"], "--epochs"),
    (["train", "--epochs", "0"], "--epochs"),
    (["train", "--ref-distance", "-1"], "--ref-distance"),
    (["train", "--ref-distance", "inf"], "--ref-distance"),
    (["train", "--max-steps", "0"], "--max-steps"),
    (["train", "--checkpoint-every", "1.5"], "--checkpoint-every"),
    (["train", "--loader-workers", "-1"], "--loader-workers"),
    (["train", "--seed", "-3"], "--seed"),
    (["train", "--views", "nan"], "--views"),
    (["render", "--workers", "-2"], "--workers"),
    (["render", "--objects-per-shard", "0"], "--objects-per-shard"),
    (["voxelize", "--workers", "x"], "--workers"),
    (["subspace", "--variance", "0"], "--variance"),
    (["subspace", "--variance", "1.5"], "--variance"),
    (["subspace", "--known", "1"], "--known"),
    (["subspace", "--components", "0"], "--components"),
    (["predict", "--model", "m", "--depth", "d", "--intrinsics", "1,1,1,1", "--out", "o", "--rolls", "0"], "--rolls"),
    (["predict", "--model", "m", "--depth", "d", "--intrinsics", "1,1,1,1", "--out", "o", "--depth-scale", "nan"],
     "--depth-scale"),
    (["evaluate", "--model", "m", "--out", "o", "--per-class", "0"], "--per-class"),
    (["evaluate", "--model", "m", "--out", "o", "--views", "-1"], "--views"),
])
def test_numeric_options_refused_at_parse_time(argv, option):
    line = cli_error(argv)
    assert line.startswith(f"{option}: expected "), line


def test_values_meaning_nothing_refused(predict_folder, tmp_path):
    out = tmp_path / "r.json"
    line = cli_error(predict_folder + ["--out", str(out), "--verify", "--verify-set", "noise_var=nan"])
    assert line.startswith("--verify-set: ") and "finite" in line, line
    line = cli_error(["train", "--loss-weights", "nan,1,1"])
    assert line.startswith("--loss-weights ") and "finite" in line, line
    line = cli_error(["train", "--loss-weights", "-1,1,1"])      # starts with "-": still the option's own check
    assert line.startswith("--loss-weights "), line
    for fc in ("512,256", "-1,2,3", "a,b,c"):                   # three positive widths, or the option's own line
        line = cli_error(["train", "--fc", fc])
        assert line.startswith("--fc ") and "three" in line, line
    assert not out.exists()


def test_strict_json_results():
    from hbeo.storage import json_text
    import json
    text = json_text({"a": float("nan"), "b": [1.0, float("inf")], "c": np.float64("-inf"), "d": 2.5}, indent=1)
    assert json.loads(text) == {"a": None, "b": [1.0, None], "c": None, "d": 2.5}
    with pytest.raises(ValueError):          # json.loads would accept "NaN": parse strictly
        json.loads(json_text({"x": float("nan")}).replace("null", "NaN"),
                   parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c)))


@pytest.mark.parametrize("case", ["missing", "png file", "manifest only"])
def test_report_refuses_what_is_not_a_finished_run(tmp_path, case):
    run = tmp_path / "run"
    if case == "png file":
        run = tmp_path / "figure.png"
        run.write_bytes(b"\x89PNG\r\n\x1a\n")
    elif case == "manifest only":
        run.mkdir()
        (run / "manifest.json").write_text('{"profile": "ci", "notebooks": {"04_train": {}}}')
    line = cli_error(["report", "--run", str(run)])
    want = {"missing": "no such run folder", "png file": "not a folder",
            "manifest only": "04_train.ipynb"}[case]
    assert str(run) in line and want in line, line
    assert not (tmp_path / "run" / "REPRODUCTION.md").exists()


def _finished_run(run: Path, **manifest) -> Path:
    """The least a finished run holds (a manifest recording a profile and one executed notebook, and that
    notebook), the manifest's entries ``manifest`` changed."""
    run.mkdir(exist_ok=True)
    man = {"profile": "ci", "dataset": "procedural", "notebooks": {"01_voxelize": {"wall_s": 1.0}}, **manifest}
    (run / "manifest.json").write_text(json.dumps(man))
    (run / "01_voxelize.ipynb").write_text("{}")
    return run


#: the resolution study's files REPRODUCTION.md reads (hbeo.report.reproduction_md.RESOLUTION_FILES), valid
_RESOLUTION = {"eval_val-basis143-e10.json": {"class_mean_accuracy": 0.5},
               **{f: {"class_mean_accuracy": 0.4} for f in ("eval_val-res120-e10.json", "eval_val-res160-e10.json")},
               **{f: {"contrasts": {"class_accuracy": {"value": -0.1, "low": -0.2, "high": 0.0, "n_objects": 9}}}
                  for f in ("res120-e10_vs_basis143-e10_val.json", "res160-e10_vs_basis143-e10_val.json")}}


@pytest.mark.parametrize("name", ["eval_hbeo_3dof.json", "res160-e10_vs_basis143-e10_val.json", "manifest.json"])
def test_report_names_a_truncated_json_file(tmp_path, name):
    """A truncated or damaged JSON file of the run: one line naming it, never json's bare words; nothing written."""
    run = _finished_run(tmp_path / "run")
    for f, content in _RESOLUTION.items():
        (run / f).write_text(json.dumps(content))
    (run / "eval_hbeo_3dof.json").write_text(json.dumps({"completion_rule": None, "views": 3, "seed": 0,
                                                         "per_query": {"object": ["a"] * 40}}, indent=1))
    whole = (run / name).read_text()
    (run / name).write_text(whole[: len(whole) // 2])                      # cut off mid-way, as a full disk leaves it
    line = cli_error(["report", "--run", str(run), "--out", str(tmp_path / "r.md")])
    assert line.startswith(f"{run / name}: ") and "not valid JSON" in line, line
    assert not (tmp_path / "r.md").exists()


def test_completion_decomposition_names_a_truncated_evaluation(tmp_path):
    run = _finished_run(tmp_path / "run")
    (run / "eval_beo_known.json").write_text(json.dumps({"per_query": {}}))
    (run / "eval_hbeo_3dof.json").write_text('{"dataset": "procedural", "views": 3, "se')
    line = cli_error(["report", "--completion-decomposition", str(run)])
    assert line.startswith(f"{run / 'eval_hbeo_3dof.json'}: not a readable metrics file: not valid JSON"), line


@pytest.mark.parametrize("change, key", [
    (dict(profile_settings="x"), "'profile_settings' holds text ('x'), not a JSON object"),
    (dict(profile_settings=None), "'profile_settings' holds null, not a JSON object"),
    (dict(hardware=[2]), "'hardware' holds a JSON list, not a JSON object"),
    (dict(hardware={"cores": "two"}), "'hardware.cores' holds text ('two'), not a whole number or null"),
    (dict(seeds={"training": "0"}), "'seeds.training' holds text ('0'), not a whole number"),
    (dict(notebooks={"01_voxelize": {"wall_s": "1.0"}}), "'notebooks.01_voxelize.wall_s' holds text ('1.0')"),
    (dict(notebooks={"01_voxelize": 60}), "'notebooks.01_voxelize' holds a number (60), not a JSON object"),
    (dict(training={"model.hbeo": {"n_params": True}}), "'training.model.hbeo.n_params' holds true/false (true)"),
    (dict(wall_time_total_s="long"), "'wall_time_total_s' holds text ('long'), not a number"),
    (dict(profile=3), "'profile' holds a number (3), not text"),
])
def test_report_names_a_wrong_typed_manifest_entry(tmp_path, change, key):
    """A hand-edited manifest whose entry has another type than its writer gives it: one line naming
    manifest.json and the key, never an AttributeError from deep inside the report; nothing written."""
    run = _finished_run(tmp_path / "run", **change)
    line = cli_error(["report", "--run", str(run), "--out", str(tmp_path / "r.md")])
    assert line.startswith(f"{run / 'manifest.json'}: key {key}"), line
    assert not (tmp_path / "r.md").exists()


def test_reproduce_only_refuses_unknown_notebooks(tmp_path):
    line = cli_error(["reproduce", "--profile", "ci", "--out", str(tmp_path / "run"), "--only", "99"])
    assert line.startswith("--only 99: no such notebook; the notebooks are 01_"), line
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("what, problem", [
    ("inf", "depth is all infinite"), ("empty", "depth image is empty (0x0 pixels)"), ("nan", "depth is all NaN"),
])
def test_depth_messages_say_what_is_wrong(predict_folder, tmp_path, what, problem):
    arr = {"inf": np.full((24, 32), np.inf, np.float32), "empty": np.zeros((0, 0), np.float32),
           "nan": np.full((24, 32), np.nan, np.float32)}[what]
    np.save(tmp_path / "depth.npy", arr)
    line = cli_error(predict_folder + ["--out", str(tmp_path / "r.json")])
    assert line == f"{tmp_path / 'depth.npy'}: {problem}", line


def test_all_zero_mask_names_the_mask(predict_folder, tmp_path):
    np.save(tmp_path / "mask.npy", np.zeros((K.height, K.width), bool))
    line = cli_error(predict_folder + ["--mask", str(tmp_path / "mask.npy"), "--out", str(tmp_path / "r.json")])
    assert line == f"{tmp_path / 'mask.npy'}: mask is all zero (no object pixel)", line
    off = np.zeros((K.height, K.width), bool)
    off[0, 0] = True                          # a mask beside the object: no measured pixel in it
    np.save(tmp_path / "mask.npy", off)
    line = cli_error(predict_folder + ["--mask", str(tmp_path / "mask.npy"), "--out", str(tmp_path / "r.json")])
    assert line.startswith(f"{tmp_path / 'mask.npy'}: the mask covers no measured pixel"), line


def test_negative_intrinsics_reach_the_intrinsics_check(predict_folder, tmp_path):
    argv = [a for a in predict_folder if not a.startswith("--intrinsics")]
    line = cli_error(argv + ["--intrinsics", "-262,262,16,12", "--out", str(tmp_path / "r.json")])
    assert line.startswith("intrinsics '-262,262,16,12': "), line


def test_every_method_from_a_run_folder_holding_only_the_model(ci_model, tmp_path, monkeypatch, capsys):
    """evaluate --method beo on a folder with nothing but model.hbeo (as the committed reference run):
    the run's grid sets and BEO's basis are built there, then BEO is fitted; voxcnn, whose rendered
    training set takes a long job, names the command that makes it."""
    import shutil
    run = tmp_path / "run"
    run.mkdir()
    shutil.copy2(ci_model, run / "model.hbeo")
    monkeypatch.setenv("HBEO_CACHE", str(tmp_path / "cache"))
    common = ["evaluate", "--model", str(run / "model.hbeo"), "--dataset", "procedural", "--per-class", "1", "--quiet"]
    line = cli_error(common + ["--method", "voxcnn", "--pose", "known", "--out", str(tmp_path / "v.json")])
    assert line.startswith(f"{run / 'voxcnn.hbeo'}: missing") and "python -m hbeo render --profile ci" in line, line
    assert main(common + ["--method", "beo", "--pose", "known", "--out", str(tmp_path / "b.json")]) == 0
    assert {"grids_train.npz", "grids_test.npz", "subspace.npz", "beo.npz"} <= {p.name for p in run.iterdir()}
    import json
    assert json.loads((tmp_path / "b.json").read_text())["method"] == "beo"
