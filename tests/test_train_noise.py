"""``train --noise``: training views carry the Kinect-like sensor noise, recorded in the rendered set, the
checkpoint, the provenance and the model file; a run folder's clean set is refused rather than mixed."""
import json

import numpy as np
import pytest


@pytest.mark.slow
def test_train_with_sensor_noise_renders_noisy_views_records_it_and_never_mixes_sets(ci_render, ci_run, copy_run,
                                                                                    tmp_path, capsys):
    from hbeo import cli
    from hbeo.model.inference import HBEO
    from hbeo.model.loop import load_checkpoint
    from hbeo.render.torch_datasets import DepthShards
    run = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz"])
    args = ["train", "--dataset", "procedural", "--profile", "ci", "--out", str(run.path), "--epochs", "1",
            "--max-steps", "2", "--quiet"]
    assert cli.main([*args, "--noise"]) == 0
    noisy = DepthShards(run.renders("train"))
    clean = DepthShards(ci_run.renders("train"))
    assert noisy.manifest.settings.noise and not clean.manifest.settings.noise
    assert noisy.object_ids == clean.object_ids
    a, b = noisy[0]["depth"].numpy(), clean[0]["depth"].numpy()
    assert a.shape == b.shape and not np.array_equal(a, b)        # the same view, with noise drawn on it
    assert np.array_equal(noisy[0]["rotation"].numpy(), clean[0]["rotation"].numpy())
    model = HBEO.load(run.model)
    assert model.settings.render["noise"] is True
    assert load_checkpoint(run.training(run.model) / "checkpoint.pt")["settings"]["train"]["data"]["noise"] is True
    info = json.loads((run.training(run.model) / "provenance.json").read_text())
    assert info["options"]["noise"] is True
    capsys.readouterr()
    assert cli.main([*args, "--name", "clean.hbeo"]) == 2          # the folder's set is noisy: refused, not mixed
    err = capsys.readouterr().err
    assert "different settings" in err and "noise" in err and not run.model_file("clean.hbeo").exists()


@pytest.mark.slow
def test_streamed_training_with_noise_keeps_it_in_the_checkpoint(ci_subspace, ci_run, copy_run, tmp_path):
    """--data stream renders as it trains: the noise is in the checkpoint's data settings, so a clean run never
    resumes a noisy one's checkpoint (or the other way round), and in the model file."""
    from hbeo import cli
    from hbeo.model.inference import HBEO
    from hbeo.model.loop import load_checkpoint
    run = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz"])
    assert cli.main(["train", "--dataset", "procedural", "--profile", "ci", "--out", str(run.path), "--epochs", "1",
                     "--max-steps", "1", "--data", "stream", "--noise", "--quiet"]) == 0
    data = load_checkpoint(run.training(run.model) / "checkpoint.pt")["settings"]["train"]["data"]
    assert data["noise"] is True and data["source"] == "stream"
    assert HBEO.load(run.model).settings.render["noise"] is True and not run.renders("train").exists()


@pytest.mark.slow
def test_train_noise_at_a_finer_sensor_renders_it_there_and_records_it(ci_render, ci_run, copy_run, tmp_path,
                                                                       capsys):
    """--noise-scale S: each training view rendered at S times the size, the noise applied there, read every S-th
    pixel; the set, the checkpoint, the provenance and the model file say S, and the option is checked first."""
    from hbeo import cli
    from hbeo.model.inference import HBEO
    from hbeo.model.loop import load_checkpoint
    from hbeo.render.torch_datasets import DepthShards
    from hbeo.render.views import ObjectViews
    from hbeo.run import Run
    run = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz"])
    args = ["train", "--dataset", "procedural", "--profile", "ci", "--out", str(run.path), "--epochs", "1",
            "--max-steps", "2", "--quiet"]
    for bad, says in ((["--noise-scale", "2"], "needs --noise"), (["--noise", "--noise-scale", "17"], "at most 16"),
                      (["--noise", "--noise-scale", "2", "--data", "stream", "--backend", "torch"], "--data memory")):
        capsys.readouterr()
        assert cli.main([*args, *bad]) == 2
        assert says in capsys.readouterr().err and not run.renders("train").exists()
    assert cli.main([*args, "--noise", "--noise-scale", "2"]) == 0
    fine, clean = DepthShards(run.renders("train")), DepthShards(ci_run.renders("train"))
    s = fine.manifest.settings
    assert s.noise and s.noise_scale == 2 and s.image_size == clean.manifest.settings.image_size
    a, b = fine[0]["depth"].numpy(), clean[0]["depth"].numpy()
    assert a.shape == b.shape and not np.array_equal(a, b)
    assert np.array_equal(fine[0]["rotation"].numpy(), clean[0]["rotation"].numpy())
    # the first object's views are those ObjectViews renders at the sensor's size with these settings
    opened = Run.open("ci", "procedural", run.path)
    record = opened.records("train")[0]
    assert fine.object_ids[0] == record.id
    want = ObjectViews(s, opened.subspace(False)).views(record, 0, 0, "train")["depth"]
    assert np.array_equal(a[0], np.asarray(want[0], a.dtype))
    assert HBEO.load(run.model).settings.render["noise_scale"] == 2
    data = load_checkpoint(run.training(run.model) / "checkpoint.pt")["settings"]["train"]["data"]
    assert data["noise"] is True and data["noise_scale"] == 2
    assert json.loads((run.training(run.model) / "provenance.json").read_text())["options"]["noise_scale"] == 2
    capsys.readouterr()
    assert cli.main([*args, "--noise", "--name", "coarse.hbeo"]) == 2      # the set's noise is at scale 2: refused
    assert "different settings" in capsys.readouterr().err


@pytest.mark.slow
def test_train_noise_on_a_share_of_the_views_keeps_the_rest_the_clean_set_s_and_records_it(ci_render, ci_run,
                                                                                          copy_run, tmp_path, capsys):
    """--noise-fraction F: each object's first F * views views carry the noise, the others are the clean set's own
    views; the set, the checkpoint, the provenance and the model file say F, and the option is checked first."""
    from hbeo import cli
    from hbeo.model.inference import HBEO
    from hbeo.model.loop import load_checkpoint
    from hbeo.render.torch_datasets import DepthShards
    run = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz"])
    args = ["train", "--dataset", "procedural", "--profile", "ci", "--out", str(run.path), "--epochs", "1",
            "--max-steps", "2", "--quiet"]
    for bad, says in ((["--noise-fraction", "0.5"], "needs --noise"),
                      (["--noise", "--noise-fraction", "0.3"], "2.4 views"),
                      (["--noise", "--noise-fraction", "0.5", "--data", "stream"], "--data memory")):
        capsys.readouterr()
        assert cli.main([*args, *bad]) == 2
        assert says in capsys.readouterr().err and not run.renders("train").exists()
    assert cli.main([*args, "--noise", "--noise-scale", "2", "--noise-fraction", "0.5"]) == 0
    mixed, clean = DepthShards(run.renders("train")), DepthShards(ci_run.renders("train"))
    s = mixed.manifest.settings
    assert s.noise and s.noise_scale == 2 and s.noise_fraction == 0.5 and s.noisy_views == 4
    assert s.views_per_object == clean.manifest.settings.views_per_object == 8
    for i in range(8):                                # object 0's views: the first four noisy, the rest clean's
        a, b = mixed[i]["depth"].numpy(), clean[i]["depth"].numpy()
        assert int(mixed[i]["object_index"]) == int(clean[i]["object_index"]) == 0
        assert np.array_equal(mixed[i]["rotation"].numpy(), clean[i]["rotation"].numpy())
        assert np.array_equal(a, b) == (i >= 4), i
    assert HBEO.load(run.model).settings.render["noise_fraction"] == 0.5
    data = load_checkpoint(run.training(run.model) / "checkpoint.pt")["settings"]["train"]["data"]
    assert data["noise_fraction"] == 0.5 and data["noise_scale"] == 2
    assert json.loads((run.training(run.model) / "provenance.json").read_text())["options"]["noise_fraction"] == 0.5
