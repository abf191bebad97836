"""Issue 29, the class imbalance: the prior correction of HBEO's class answer (logit adjustment) and
the class-balanced training options (sampler, weighted loss), on tiny inputs."""
import numpy as np
import pytest
import torch
import torch.nn.functional as F

import resume_job as job
from hbeo.errors import DataError
from hbeo.model.distributed import weights_sha256
from hbeo.model.fit import HBEONetTask
from hbeo.model.trainingdata import ClassBalanced, class_weights
from hbeo.model.inference import HBEO
from hbeo.model.loop import TrainConfig, epoch_order, train
from hbeo.model.modelfile import ModelSettings
from hbeo.model.network import LossWeights, NetConfig, hbeo_loss


def _depth(K):
    d = np.zeros((K.height, K.width), np.float32)
    d[8:16, 12:20] = 1.5
    return d


# --------------------------------------------------------------------------- prior correction

def test_prior_correction_is_logits_minus_tau_log_prior(tiny_model, tmp_path):
    counts = (30, 10)
    m = tiny_model({"class_counts": counts})
    depth = _depth(m.intrinsics)
    p0 = m.predict(depth, m.intrinsics).probabilities[0].astype(np.float64)
    prior = np.array(counts, np.float64) / sum(counts)
    for tau in (0.25, 1.0):
        p = m.set_prior_tau(tau).predict(depth, m.intrinsics).probabilities[0]
        want = np.exp(np.log(p0) - tau * np.log(prior))
        assert p == pytest.approx(want / want.sum(), abs=1e-6)
        assert m.prior_source == "model file" and m.class_counts == counts
    # dividing by the prior favours the rare class: its probability grows
    assert p[1] > p0[1]
    # the file keeps the counts; tau is chosen at load time (default 0: the paper's answer)
    path = m.save(tmp_path / "m.hbeo")
    assert HBEO.load(path).prior_tau == 0.0 and HBEO.load(path).settings.class_counts == counts
    again = HBEO.load(path, prior_tau=1.0).predict(depth, m.intrinsics).probabilities[0]
    assert again == pytest.approx(p, abs=1e-6)


def test_prior_correction_refuses_what_it_cannot_do(tiny_model, tmp_path):
    m = tiny_model({})
    assert m.set_prior_tau(0.0).prior_tau == 0.0          # no counts needed for the paper's answer
    with pytest.raises(ValueError, match="does not hold"):
        m.set_prior_tau(0.5)
    with pytest.raises(ValueError, match=r"in \[0, 1\]"):
        m.set_prior_tau(1.5)
    with pytest.raises(ValueError, match="no training images of class table"):
        m.set_prior_tau(1.0, class_counts=(5, 0))
    m.set_prior_tau(1.0, class_counts=(5, 5), source="hand")
    assert m.prior_source == "hand"
    path = tiny_model({}).save(tmp_path / "old.hbeo")
    with pytest.raises(DataError, match="old.hbeo.*does not hold"):
        HBEO.load(path, prior_tau=1.0)
    with pytest.raises(ValueError, match="class_counts has 3 entries for 2 classes"):
        tiny_model({"class_counts": (1, 2, 3)})
    for bad in ([1.5, 2], [-1, 2], [0, 0], "12"):
        with pytest.raises(ValueError, match="class_counts"):
            ModelSettings(class_counts=bad)
    # a class-balanced model saw its classes equally often: its file's counts are not its prior
    balanced = tiny_model({"class_counts": (30, 10), "class_balance": "sampler"})
    assert balanced.set_prior_tau(0.0).prior_tau == 0.0
    with pytest.raises(ValueError, match="class balance 'sampler'.*twice"):
        balanced.set_prior_tau(1.0)
    path = balanced.save(tmp_path / "bal.hbeo")
    assert HBEO.load(path).settings.class_balance == "sampler"
    with pytest.raises(DataError, match="bal.hbeo.*class balance 'sampler'"):
        HBEO.load(path, prior_tau=1.0)
    assert balanced.set_prior_tau(1.0, class_counts=(1, 1), source="uniform").prior_source == "uniform"
    with pytest.raises(ValueError, match="class_balance must be one of none, sampler, loss"):
        ModelSettings(class_balance="equal")


# --------------------------------------------------------------------------- class-balanced training

def test_class_weights_and_the_weighted_loss_match_a_hand_computation():
    w = class_weights([10, 30, 60])                   # 1/n normalized to mean 1
    inv = np.array([1 / 10, 1 / 30, 1 / 60])
    assert w == pytest.approx(inv / inv.mean()) and w.mean() == pytest.approx(1.0)
    assert class_weights([4, 0, 2]).tolist() == pytest.approx([2 / 3, 0.0, 4 / 3])
    cfg = NetConfig(image_size=(16, 16), n_classes=3, n_coeffs=2, rotation="axis_angle")
    torch.manual_seed(0)
    logits, labels = torch.randn(5, 3), torch.tensor([0, 1, 2, 2, 1])
    out = {"logits": logits, "pose": torch.zeros(5, 3), "coeffs": torch.zeros(5, 2)}
    batch = {"label": labels, "axis_angle": torch.zeros(5, 3), "coeffs": torch.zeros(5, 2)}
    _, parts = hbeo_loss(out, batch, cfg, class_weights=torch.as_tensor(w))
    ce = -F.log_softmax(logits.double(), 1)[torch.arange(5), labels].numpy()
    wi = w[labels.numpy()]
    assert parts["ce"] == pytest.approx(float((wi * ce).sum() / wi.sum()), rel=1e-5)
    _, plain = hbeo_loss(out, batch, cfg)
    assert plain["ce"] == pytest.approx(float(ce.mean()), rel=1e-5)
    # the task records its weights (a resumed run must use the same) and leaves unweighted runs' config alone
    assert "class_weights" not in HBEONetTask(cfg).config()
    assert HBEONetTask(cfg, class_weights=tuple(w)).config()["class_weights"] == pytest.approx(w.tolist())


def test_sampler_draws_classes_about_uniformly_and_repeats_from_the_seed():
    labels = np.repeat([0, 1, 2], [900, 90, 10])      # 90:9:1
    ds = ClassBalanced(torch.utils.data.TensorDataset(torch.arange(1000)), labels)
    cfg = TrainConfig(seed=3)
    order = epoch_order(ds, cfg, 0)
    assert len(order) == 1000 and order.min() >= 0 and order.max() < 1000
    share = np.bincount(labels[order], minlength=3) / 1000
    assert share == pytest.approx([1 / 3] * 3, abs=0.05)
    assert np.array_equal(order, epoch_order(ds, cfg, 0))                 # (seed, epoch) decide it all
    assert not np.array_equal(order, epoch_order(ds, cfg, 1))
    assert not np.array_equal(order, epoch_order(ds, TrainConfig(seed=4), 0))
    with pytest.raises(ValueError, match="3 labels for 1000 items"):
        ClassBalanced(ds.base, [0, 1, 2])


def test_training_with_the_sampler_resumes_exactly(tmp_path):
    def data():
        tr, va = job.data()
        return ClassBalanced(tr, tr.base.labels), va
    cfg = job.config(epochs=2, data={"class_balance": "sampler"})
    tr, va = data()
    whole = weights_sha256(train(job.TASK, tr, va, tmp_path / "a", cfg))
    tr, va = data()
    train(job.TASK, tr, va, tmp_path / "b", cfg, stop_after_step=5)        # killed after step 5 (checkpoint at 3)
    tr, va = data()
    assert weights_sha256(train(job.TASK, tr, va, tmp_path / "b", cfg)) == whole
    # the loss option trains too, with its weights in the checkpoint's settings
    task = HBEONetTask(job.CFG, LossWeights(pose=0.1, coeffs=0.1), class_weights=tuple(class_weights([20, 20, 20])))
    tr, va = job.data()
    train(task, tr, va, tmp_path / "c", job.config(epochs=1))


@pytest.mark.parametrize("balance", ["sampler", "loss"])
def test_train_command_balances_classes_and_records_the_counts(ci_render, ci_run, copy_run, tmp_path, balance,
                                                              capsys):
    import json
    from hbeo import cli
    from hbeo.model.loop import load_checkpoint
    from hbeo.render.torch_datasets import split_by_object
    run = copy_run(ci_run, tmp_path / "run", names=["grids_train.npz", "grids_test.npz", "subspace.npz",
                                                    "render_train"])
    args = ["train", "--dataset", "procedural", "--profile", "ci", "--out", str(run.path), "--epochs", "1",
            "--max-steps", "2", "--class-balance", balance, "--quiet"]
    assert cli.main(args) == 0
    model = HBEO.load(run.model)
    tr, _ = split_by_object(ci_render, 0.1, 0)
    assert model.settings.class_counts == tuple(np.bincount(ci_render.object_labels[ci_render.image_objects()][tr],
                                                            minlength=len(model.classes)).tolist())
    info = json.loads((run.training(run.model) / "provenance.json").read_text())
    assert info["class_balance"] == balance and info["options"]["class_balance"] == balance
    assert model.settings.class_balance == balance
    settings = load_checkpoint(run.training(run.model) / "checkpoint.pt")["settings"]
    assert ("class_weights" in settings["model"]) == (balance == "loss")
    assert settings["train"]["data"].get("class_balance") == ("sampler" if balance == "sampler" else None)
    if balance == "sampler":                          # the shards source reads a few shards at a time: refused
        assert cli.main([*args[:-1], "--data", "shards", "--name", "other.hbeo", "--quiet"]) == 2
        assert "class balance 'sampler'" in capsys.readouterr().err and not run.model_file("other.hbeo").exists()


def test_the_cpu_recipe_balances_classes_and_the_paper_option_does_not():
    """The cpu profile's model draws classes uniformly (chosen on validation, issue 29); notebook 04's
    ``paper`` option keeps the paper's class mix, and ``--class-balance none`` overrides the profile."""
    from hbeo import config
    from hbeo.lessons.training import PAPER_RECIPE
    from hbeo.model.fit import TrainOptions
    cpu, ci = config.get_profile("cpu"), config.get_profile("ci")
    assert TrainOptions().recipe(cpu)["class_balance"] == "sampler"
    assert TrainOptions(class_balance="none").recipe(cpu)["class_balance"] == "none"
    assert TrainOptions(**PAPER_RECIPE).recipe(cpu) == PAPER_RECIPE
    assert TrainOptions().recipe(ci)["class_balance"] == "none"
    assert set(PAPER_RECIPE) == set(config.RecipeConfig(epochs=1, batch_size=1).fit_kwargs())
