"""Issue 14, batches: voxelize and render continue past bad objects, keep every good result, name
every bad file with its reason (returned, in the run's failures.json, printed), exit 2 only with
--strict or when nothing succeeded; degenerate meshes are refused by name; a render resume verifies
the shards' sha256 and renders again what does not match. Tiny folder datasets written in tmp_path."""
import json
import pickle

import numpy as np
import pytest
import trimesh

from hbeo import cli
from hbeo.data import datasets, gridset
from hbeo.data.gridset import build_gridset
from hbeo.data.meshio import check_mesh
from hbeo.data.voxel import voxelize
from hbeo.errors import BatchError, DataError
from hbeo.render.torch_datasets import DepthShards
from hbeo.render.renderset import Manifest, render_set
from hbeo.render.views import RenderSettings
from hbeo.rundir import RunDir

SMALL = RenderSettings(image_size=(32, 24), views_per_object=2)


def _off(mesh: trimesh.Trimesh) -> str:
    v, f = mesh.vertices, mesh.faces
    return ("OFF\n" + f"{len(v)} {len(f)} 0\n" + "".join(f"{a} {b} {c}\n" for a, b, c in v)
            + "".join(f"3 {a} {b} {c}\n" for a, b, c in f))


GOOD = {f"box{i}": _off(trimesh.creation.box((1.0, 0.5 + 0.2 * i, 0.7))) for i in range(4)}
BROKEN = "OFF\n3 1 0\n0 0 0\n1 0 0\n"                                 # truncated: a face missing
COLLINEAR = "OFF\n3 1 0\n0 0 0\n1 1 1\n2 2 2\n3 0 1 2\n"


def _folder(root, bad: dict, good=GOOD, cls="chair"):
    """root/cls/train/*.off: the good boxes, then the bad files (sorted names: bad ones in the middle)."""
    d = root / cls / "train"
    d.mkdir(parents=True)
    for name, text in {**good, **bad}.items():
        (d / f"{name}.off").write_text(text)
    return root


@pytest.fixture
def bad_folder(tmp_path):
    # ids sort as box0, box1, box2, box3, zbroken, zline: with chunk=2 each bad file has a chunk of its own
    # kind; with "box1a" it shares a chunk with a good one
    return _folder(tmp_path / "ds", {"box1a": BROKEN, "zline": COLLINEAR})


# --------------------------------------------------------------------------- case 7: voxelization batch

def test_voxelize_batch_keeps_every_good_grid_and_names_every_bad_file(bad_folder, tmp_path):
    ds = datasets.get_dataset(str(bad_folder))
    recs = ds.records("train")
    gs = build_gridset(ds, recs, "train", cache=tmp_path / "c", chunk=2, progress=False)
    assert list(gs.ids) == ["box0", "box1", "box2", "box3"]        # box1's chunk-mate box1a failed
    for r in recs:
        if r.id in gs.ids:
            assert np.array_equal(gs.grids[list(gs.ids).index(r.id)], gridset.record_grid(r))
    files = {f["file"]: f for f in gs.failures}
    assert set(files) == {str(bad_folder / "chair/train/box1a.off"), str(bad_folder / "chair/train/zline.off")}
    assert "truncated OFF" in files[str(bad_folder / "chair/train/box1a.off")]["reason"]
    assert "collinear" in files[str(bad_folder / "chair/train/zline.off")]["reason"]
    assert all(f["step"] == "voxelize" for f in gs.failures)
    saved = gridset.GridSet.load(gs.save(tmp_path / "g.npz"))      # the set says which objects it lacks
    assert [f["object"] for f in saved.meta["failed"]] == ["train/chair/box1a", "train/chair/zline"]


def test_voxelize_rerun_reuses_finished_work_and_retries_only_the_bad_items(bad_folder, tmp_path, monkeypatch):
    ds = datasets.get_dataset(str(bad_folder))
    build_gridset(ds, ds.records("train"), "train", cache=tmp_path / "c", chunk=2, progress=False)
    seen = []
    real = gridset.record_grid
    monkeypatch.setattr(gridset, "record_grid", lambda r, *a: seen.append(r.id) or real(r, *a))
    again = build_gridset(ds, ds.records("train"), "train", cache=tmp_path / "c", chunk=2, progress=False)
    assert sorted(seen) == ["box1a", "zline"] and len(again) == 4
    # the user repairs one file: only it is voxelized, the cache of the others still serves
    (bad_folder / "chair/train/box1a.off").write_text(GOOD["box0"])
    ds = datasets.get_dataset(str(bad_folder))
    seen.clear()
    fixed = build_gridset(ds, ds.records("train"), "train", cache=tmp_path / "c", chunk=2, progress=False)
    assert sorted(seen) == ["box1a", "zline"]
    assert list(fixed.ids) == ["box0", "box1", "box1a", "box2", "box3"]
    assert [f["object"] for f in fixed.failures] == ["train/chair/zline"]


def test_voxelize_nothing_succeeded_raises_with_the_failures(tmp_path):
    ds = datasets.get_dataset(str(_folder(tmp_path / "ds", {"a": BROKEN, "b": COLLINEAR}, good={})))
    with pytest.raises(DataError, match=r"none of the 2 train objects could be voxelized") as err:
        build_gridset(ds, ds.records("train"), "train", cache=tmp_path / "c", progress=False)
    assert isinstance(err.value, BatchError) and len(err.value.failures) == 2
    back = pickle.loads(pickle.dumps(err.value))          # crossing a process boundary keeps the list
    assert type(back) is BatchError and back.failures == err.value.failures and str(back) == str(err.value)


def test_batch_error_survives_pickling_with_its_failures():
    failures = [{"file": "a.off", "reason": "no faces", "step": "render", "object": "train/chair/a",
                 "split": "train", "position": 0}]
    err = BatchError("out/renders", "none of the 1 train objects could be rendered", failures)
    back = pickle.loads(pickle.dumps(err))
    assert isinstance(back, DataError) and back.failures == failures and back.path == "out/renders"
    assert str(back) == "out/renders: none of the 1 train objects could be rendered"
    assert BatchError(None, "x").failures == []


def _both_splits(root, bad):
    _folder(root, bad)
    (root / "chair" / "test").mkdir()
    (root / "chair" / "test" / "t0.off").write_text(GOOD["box2"])
    return root


def test_cli_voxelize_reports_failures_and_exits_2_only_when_strict(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("HBEO_CACHE", str(tmp_path / "cache"))
    root = _both_splits(tmp_path / "ds", {"box1a": BROKEN})
    run = tmp_path / "run"
    args = ["voxelize", "--dataset", str(root), "--profile", "ci", "--out", str(run)]
    assert cli.main(args) == 0
    err = capsys.readouterr().err
    assert "1 of 6 objects failed" in err and "box1a.off" in err and str(RunDir(run).failures) in err
    failures = json.loads(RunDir(run).failures.read_text())
    assert [(f["file"], f["step"]) for f in failures] == [(str(root / "chair/train/box1a.off"), "voxelize")]
    assert "truncated OFF" in failures[0]["reason"]
    assert len(gridset.GridSet.load(RunDir(run).grids("train"))) == 4
    assert cli.main(args + ["--strict"]) == 2
    # repaired: the failures of this step are gone from failures.json
    (root / "chair/train/box1a.off").write_text(GOOD["box0"])
    assert cli.main(args + ["--strict"]) == 0
    assert not RunDir(run).failures.exists() or json.loads(RunDir(run).failures.read_text()) == []


def test_cli_voxelize_exits_2_when_nothing_succeeded(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("HBEO_CACHE", str(tmp_path / "cache"))
    root = _folder(tmp_path / "ds", {"a": BROKEN}, good={})
    run = tmp_path / "run"
    assert cli.main(["voxelize", "--dataset", str(root), "--profile", "ci", "--out", str(run)]) == 2
    err = capsys.readouterr().err
    assert "a.off" in err and "truncated OFF" in err
    assert json.loads(RunDir(run).failures.read_text())[0]["file"] == str(root / "chair/train/a.off")


# --------------------------------------------------------------------------- case 9 (+8): degenerate meshes

@pytest.mark.parametrize("verts, faces, problem", [
    ([[0, 0, 0], [1, 1, 1], [2, 2, 2]], [[0, 1, 2]], r"all 3 vertices are collinear"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 1], [2, 3, 3]], r"faces have zero total area"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1e30, 0, 0]], [[0, 1, 2]], r"vertex 3 at \(1e\+30, 0, 0\)"),
    ([[0, 0, 0], [1, 0, 0], [0, np.inf, 0]], [[0, 1, 2]], r"vertex 2 has a NaN or infinite coordinate \(0, inf, 0\)"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.zeros((0, 3), int), r"no triangle faces"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 7]], r"face 0 refers to vertex 7 but the mesh has 3 vertices"),
    ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, -1, 2]], r"face 0 refers to vertex -1"),
])
def test_degenerate_meshes_are_refused_naming_the_file_and_the_value(verts, faces, problem):
    with pytest.raises(DataError, match=r"^obj\.off: .*" + problem):
        check_mesh(np.asarray(verts, float), np.asarray(faces).reshape(-1, 3), "obj.off")


def test_degenerate_mesh_files_are_refused_by_voxelize(tmp_path):
    p = tmp_path / "line.off"
    p.write_text(COLLINEAR)
    with pytest.raises(DataError, match=r"line\.off: degenerate mesh: all 3 vertices are collinear"):
        voxelize(p)
    far = tmp_path / "far.off"
    far.write_text("OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n1e30 0 0\n3 0 1 2\n")
    with pytest.raises(DataError, match=r"far\.off: .*vertex 3 at \(1e\+30, 0, 0\)"):
        voxelize(far)


# --------------------------------------------------------------------------- case 12: render resume

@pytest.fixture(scope="module")
def good_ds(tmp_path_factory):
    return datasets.get_dataset(str(_folder(tmp_path_factory.mktemp("good"), {})))


@pytest.fixture(scope="module")
def good_set(good_ds, tmp_path_factory):
    out = tmp_path_factory.mktemp("set")
    m = render_set(good_ds, good_ds.records("train"), "train", out, SMALL, objects_per_shard=2, progress=False)
    return m, {p.name: p.read_bytes() for p in m.shard_paths()}


@pytest.mark.slow
def test_render_resume_verifies_checksums_and_renders_damaged_shards_again(good_set, good_ds, tmp_path):
    m, original = good_set
    out = tmp_path / "set"
    out.mkdir()
    for p in m.root.iterdir():
        (out / p.name).write_bytes(p.read_bytes())
    truncated, flipped = out / "shard_00000.npz", out / "shard_00001.npz"
    truncated.write_bytes(original[truncated.name][:len(original[truncated.name]) // 2])
    data = bytearray(original[flipped.name])
    data[len(data) // 2] ^= 0xFF                          # same size, one byte changed
    flipped.write_bytes(bytes(data))
    with pytest.warns(UserWarning, match=r"shard_0000[01]\.npz: does not match its recorded sha256") as caught:
        again = render_set(good_ds, good_ds.records("train"), "train", out, SMALL, objects_per_shard=2,
                           progress=False)
    assert len([w for w in caught if "sha256" in str(w.message)]) == 2
    assert again.rendered == 4 * SMALL.views_per_object                    # those two shards, not "already rendered"
    assert {p.name: p.read_bytes() for p in again.shard_paths()} == original
    again.verify()


# --------------------------------------------------------------------------- case 7 for renders

@pytest.mark.slow
def test_render_batch_continues_past_a_bad_object_and_retries_it(tmp_path, capsys):
    root = _folder(tmp_path / "ds", {"box1a": BROKEN})
    run = RunDir(tmp_path / "run")
    args = ["render", "--dataset", str(root), "--profile", "ci", "--out", str(run.path), "--views", "2",
            "--objects-per-shard", "2", "--quiet"]
    assert cli.main(args) == 0                      # one bad object: named, recorded, exit 0
    err = capsys.readouterr().err
    assert "1 of 5 objects failed" in err and "box1a.off" in err and "truncated OFF" in err
    recorded = json.loads(run.failures.read_text())
    assert [(f["file"], f["step"], f["object"]) for f in recorded] == [
        (str(root / "chair/train/box1a.off"), "render", "train/chair/box1a")]
    m = Manifest.load(run.renders("train"))
    assert m.failures == recorded and m.n_images == 4 * 2
    shards = DepthShards(m)                         # the good objects' views, in order, consistent
    assert len(shards) == m.n_images
    ids = [shards.object_ids[p] for p in shards.image_objects]
    assert ids == [i for i in ("box0", "box1", "box2", "box3") for _ in range(2)]
    assert [str(i) for p in m.shard_paths() for i in np.load(p)["object_id"]] == ids
    # --strict: the shard of the failed object is tried again (still broken), exit 2
    assert cli.main(args + ["--strict"]) == 2
    printed = capsys.readouterr()
    assert "1 of 5 objects failed" in printed.err and "already rendered" not in printed.out
    assert Manifest.load(run.renders("train")).n_images == 4 * 2


# --------------------------------------------------------------------------- evaluate batch

@pytest.mark.slow
def test_evaluate_batch_scores_the_good_objects_and_names_the_bad(ci_model, copy_run, tmp_path, capsys):
    """A test split with a truncated mesh among good ones: every good object is scored, the bad one is
    named in the metrics, in the run's failures.json and on stderr; --strict turns it into exit 2."""
    root = tmp_path / "ds"
    d = root / "chair" / "test"
    d.mkdir(parents=True)
    for name, text in {**GOOD, "box1a": BROKEN}.items():
        (d / f"{name}.off").write_text(text)
    run = copy_run(ci_model.parent, tmp_path / "run", names=[ci_model.name])
    args = ["evaluate", "--model", str(run.model_file(ci_model.name)), "--dataset", str(root), "--quiet"]
    assert cli.main([*args, "--out", str(tmp_path / "m.json")]) == 0
    m = json.loads((tmp_path / "m.json").read_text())
    assert m["n_objects"] == 4 and m["n_queries"] == 4
    assert [f["object"] for f in m["failures"]] == ["test/chair/box1a"]
    assert "box1a.off" in m["failures"][0]["file"]
    assert [f["object"] for f in run.read_failures()] == ["test/chair/box1a"]
    assert "1 of 5 objects failed" in capsys.readouterr().err
    assert cli.main([*args, "--strict", "--out", str(tmp_path / "s.json")]) == 2
