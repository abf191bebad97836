"""The training loop (hbeo.model.loop) with HBEONet's task: learning, exact resume, max_steps,
refusing a checkpoint made with other settings, checkpoints that load with weights_only."""
import numpy as np
import pandas as pd
import pytest
import torch
from torch import nn

from hbeo.errors import DataError
from hbeo.model.fit import HBEONetTask
from hbeo.model.network import LossWeights, NetConfig
from hbeo.model.loop import TrainConfig, load_checkpoint, lr_at, train, training_history
from hbeo.rotations import uniform_so3
from hbeo.rundir import CHECKPOINT, TRAIN_LOG as LOG
from resume_job import Blobs

CFG = NetConfig(image_size=(16, 16), n_classes=3, n_coeffs=4, conv_channels=(4, 8, 8, 8), fc=(16, 16, 16))


Toy = Blobs     # class = which quadrant holds the blob; easy enough to beat chance in two epochs


def weights(net):
    return torch.cat([p.detach().flatten() for p in net.state_dict().values() if p.dtype.is_floating_point])


def test_learns_and_resumes_exactly(tmp_path):
    tr, va = Toy(96, 0), Toy(48, 1)
    tc = TrainConfig(epochs=4, batch_size=16, lr=1e-2, warmup_steps=2, progress=False)
    task = HBEONetTask(CFG, LossWeights(pose=0.1, coeffs=0.1))     # pose and coeffs are noise here
    full = train(task, tr, va, tmp_path / "a", tc)
    log = pd.read_csv(tmp_path / "a" / LOG)
    assert list(log.epoch) == [1, 2, 3, 4] and log.val_accuracy.iloc[-1] > 0.8     # chance is 1/3
    train(task, tr, va, tmp_path / "b", tc, stop_after_epoch=1)                   # "interrupted"
    assert list(pd.read_csv(tmp_path / "b" / LOG).epoch) == [1]
    resumed = train(task, tr, va, tmp_path / "b", tc)
    assert torch.equal(weights(full), weights(resumed))
    assert pd.read_csv(tmp_path / "b" / LOG).drop(columns="images_per_s").equals(log.drop(columns="images_per_s"))
    assert (tmp_path / "b" / CHECKPOINT).exists()


def test_resume_refuses_other_settings(tmp_path):
    tc = TrainConfig(epochs=1, batch_size=16, progress=False)
    train(HBEONetTask(CFG), Toy(16, 0), Toy(8, 1), tmp_path, tc)
    other = NetConfig(image_size=(16, 16), n_classes=3, n_coeffs=5, conv_channels=(4, 8, 8, 8), fc=(16, 16, 16))
    ck = str(tmp_path / CHECKPOINT)
    with pytest.raises(DataError, match=rf"{ck}: .*other settings \(model\.net\.n_coeffs 4 there, 5 now\)"):
        train(HBEONetTask(other), Toy(16, 0), Toy(8, 1), tmp_path, tc)
    # the same network with other loss weights, data or schedule would silently mix two runs
    with pytest.raises(DataError, match=r"model\.loss\.pose 1\.0 there, 5\.0 now"):
        train(HBEONetTask(CFG, LossWeights(pose=5.0)), Toy(16, 0), Toy(8, 1), tmp_path, tc)
    with pytest.raises(DataError, match=r"train\.data\.augment_roll None there, True now"):
        train(HBEONetTask(CFG), Toy(16, 0), Toy(8, 1), tmp_path,
              TrainConfig(epochs=1, batch_size=16, progress=False, data={"augment_roll": True}))
    with pytest.raises(DataError, match=r"train\.epochs 1 there, 2 now"):
        train(HBEONetTask(CFG), Toy(16, 0), Toy(8, 1), tmp_path, TrainConfig(epochs=2, batch_size=16, progress=False))
    # another kind of model
    task = HBEONetTask(CFG)
    task.kind = "voxcnn"
    with pytest.raises(DataError, match="checkpoint is for a hbeonet model, not voxcnn"):
        train(task, Toy(16, 0), Toy(8, 1), tmp_path, tc)
    # the machine's settings may change: the finished run is read back, nothing is trained
    same = train(HBEONetTask(CFG), Toy(16, 0), Toy(8, 1), tmp_path,
                 TrainConfig(epochs=1, batch_size=16, progress=False, threads=1, device="cpu"))
    assert torch.equal(weights(same), weights(train(HBEONetTask(CFG), Toy(16, 0), Toy(8, 1), tmp_path, tc)))


def test_checkpoints_hold_only_tensors_and_plain_values(tmp_path):
    train(HBEONetTask(CFG), Toy(16, 0), Toy(8, 1), tmp_path, TrainConfig(epochs=1, batch_size=16, progress=False))
    ck = torch.load(tmp_path / CHECKPOINT, map_location="cpu", weights_only=True)
    assert ck["kind"] == "hbeonet" and ck["settings"]["model"]["net"]["n_coeffs"] == 4
    assert isinstance(ck["rng"]["numpy"]["keys"], list) and torch.is_tensor(ck["rng"]["torch"])
    assert ck["history"][0]["epoch"] == 1 and isinstance(ck["history"][0]["val_loss"], float)
    # anything that weights_only refuses, and files that are not checkpoints: DataError naming the file
    bad = tmp_path / "pickled" / CHECKPOINT
    bad.parent.mkdir()
    torch.save({**ck, "extra": np.arange(3)}, bad)     # a numpy array needs unpickling
    with pytest.raises(DataError, match=f"{bad}: not a readable checkpoint"):
        load_checkpoint(bad)
    with pytest.raises(DataError, match=f"{bad}: not a readable checkpoint"):
        train(HBEONetTask(CFG), Toy(16, 0), Toy(8, 1), bad.parent, TrainConfig(epochs=1, batch_size=16, progress=False))
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match=f"{junk}: not a readable checkpoint"):
        load_checkpoint(junk)
    torch.save({"format_version": 99}, junk)
    with pytest.raises(DataError, match=f"{junk}: checkpoint format 99"):
        load_checkpoint(junk)


def test_max_steps_stops_inside_an_epoch_with_a_full_schedule(tmp_path):
    tr, va = Toy(96, 0), Toy(16, 1)                  # 6 steps per epoch
    tc = TrainConfig(epochs=3, batch_size=16, lr=1e-2, warmup_steps=2, max_steps=8, progress=False)
    net = train(HBEONetTask(CFG), tr, va, tmp_path, tc)
    log = pd.read_csv(tmp_path / LOG)
    assert list(log.epoch) == [1, 2] and list(log.step) == [6, 8]
    assert log.lr.iloc[-1] == pytest.approx(tc.lr * tc.min_lr_ratio)        # the schedule ends at max_steps
    assert lr_at(7, 8, tc) < lr_at(6, 8, tc)
    again = train(HBEONetTask(CFG), tr, va, tmp_path, tc)                  # done: nothing more to train
    assert torch.equal(weights(net), weights(again)) and len(pd.read_csv(tmp_path / LOG)) == 2


class ToyPose(Toy):
    """The blob's quadrant fixes both the class and the rotation (one of three)."""

    def __init__(self, n, seed):
        super().__init__(n, seed)
        fixed = uniform_so3(3, np.random.default_rng(42)).astype(np.float32)
        self.R = fixed[self.labels]


def test_rotation_bins_head_learns_a_pose_and_resumes_exactly(tmp_path):
    cfg = NetConfig(image_size=(16, 16), n_classes=3, n_coeffs=4, conv_channels=(4, 8, 8, 8), fc=(16, 16, 16),
                    rotation="bins", rotation_bins=512)
    tr, va = ToyPose(96, 0), ToyPose(48, 1)
    tc = TrainConfig(epochs=4, batch_size=16, lr=1e-2, warmup_steps=2, progress=False)
    task = HBEONetTask(cfg, LossWeights(coeffs=0.1))
    full = train(task, tr, va, tmp_path / "a", tc)
    log = pd.read_csv(tmp_path / "a" / LOG)
    assert log.val_pose_median_deg.iloc[-1] < 20 < log.val_pose_median_deg.iloc[0]   # chance ~126 degrees
    train(task, tr, va, tmp_path / "b", tc, stop_after_epoch=2)
    assert torch.equal(weights(full), weights(train(task, tr, va, tmp_path / "b", tc)))


def test_training_steps_never_wait_to_read_a_loss(tmp_path, monkeypatch):
    """hbeo's step reads nothing back from the device (no .item() of the loss or its parts: on a GPU each such
    read makes the host wait; torch's own reads of host tensors, AdamW's step counts, are not ours); the
    epoch's loss is read once, at its end, and the log keeps its value."""
    import sys
    from pathlib import Path
    import hbeo
    package = str(Path(hbeo.__file__).resolve().parent)
    reads = []
    real = torch.Tensor.item

    def item(self):
        caller = str(Path(sys._getframe(1).f_code.co_filename).resolve())
        if caller.startswith(package):
            reads.append(caller)
        return real(self)
    monkeypatch.setattr(torch.Tensor, "item", item)
    tc = TrainConfig(epochs=1, batch_size=4, lr=1e-2, warmup_steps=2, progress=False)
    train(HBEONetTask(CFG), Toy(32, 0), None, tmp_path, tc)          # 8 steps, no validation
    assert reads == []
    log = training_history(tmp_path)
    assert len(log) == 1 and np.isfinite(log[0]["train_loss"]) and log[0]["train_loss"] > 0


def test_the_loops_optimizer_on_cuda_is_fused_so_the_amp_scaler_steps_without_reading_back(monkeypatch):
    """On CUDA the loop's AdamW is fused; with it the AMP gradient scaler's step (after ``unscale_`` and the
    gradient clipping, as the loop does) hands the inf/NaN flag to the optimizer on the device instead of
    reading it back, a host wait every step with torch's default AdamW. Checked here with the CPU's scaler
    (the same ``GradScaler.step`` code): the default optimizer reads back, the fused one does not; on the
    CPU the loop keeps torch's default, so the CPU's trainings are unchanged."""
    from hbeo.model.loop import optimizer
    cfg = TrainConfig(lr=1e-3)
    assert optimizer(nn.Linear(2, 2).parameters(), cfg, torch.device("cuda")).defaults["fused"] is True
    assert not optimizer(nn.Linear(2, 2).parameters(), cfg, torch.device("cpu")).defaults["fused"]
    reads, real = [], torch.Tensor.item
    monkeypatch.setattr(torch.Tensor, "item", lambda self: reads.append(1) or real(self))

    def steps(device_kind):
        torch.manual_seed(0)
        net = nn.Linear(5, 3)
        opt, scaler = optimizer(net.parameters(), cfg, torch.device(device_kind)), torch.amp.GradScaler("cpu")
        reads.clear()
        for _ in range(3):
            loss = net(torch.randn(4, 5)).pow(2).mean()
            opt.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            scaler.unscale_(opt)
            torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            scaler.step(opt)
            scaler.update()
        return len(reads), net.weight.detach().clone()
    n_default, w_default = steps("cpu")
    n_fused, w_fused = steps("cuda")                 # the CUDA choice, made on CPU tensors
    assert n_default > 0 and n_fused == 0
    torch.testing.assert_close(w_fused, w_default)   # the same update, to rounding


def test_the_loss_keeps_its_constants_on_the_device_instead_of_copying_them_every_step():
    """The voxel loss's coefficient scale and the class weights reach the loss's device once (a host array
    copied to a GPU every step makes the host wait for the device each time): the second step gets the same
    tensor, with the values of the formula, in the output's dtype."""
    coeff_std = np.array([0.5, 1.0, 2.0], np.float32)
    task = HBEONetTask(CFG, coeff_std=coeff_std, class_weights=(1.0, 2.0, 0.5))
    like = torch.zeros(4, 3, dtype=torch.float64)
    first = task._scale(like)
    assert task._scale(like) is first and first.dtype == torch.float64
    rms = np.sqrt(np.mean(coeff_std.astype(np.float64) ** 2))
    np.testing.assert_allclose(first.numpy(), rms / coeff_std.astype(np.float64), rtol=1e-12)
    assert task._scale(like.float()) is not first and task._scale(like.float()).dtype == torch.float32
    w = task._class_weights(like)
    assert task._class_weights(like) is w and w.tolist() == [1.0, 2.0, 0.5]
    assert HBEONetTask(CFG)._scale(like) == 1.0 and HBEONetTask(CFG)._class_weights(like) is None


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_the_gpu_step_never_waits_for_the_device():
    """On a GPU the loop's step (hbeo.model.loop.train_step: bfloat16 autocast without a gradient scaler, the
    fused AdamW, gradient clipping) runs under torch's sync debug mode set to "error": any host wait (a read of a
    device value, a nonzero, a non-pinned copy) raises. The batch is copied pinned and non-blocking, as the
    loop's ``_to`` does with a DataLoader's pinned batches."""
    from hbeo.model.loop import _to, optimizer, train_step
    device = torch.device("cuda")
    cfg = TrainConfig(lr=1e-3)
    task = HBEONetTask(CFG)
    module = task.build().to(device)
    opt = optimizer(module.parameters(), cfg, device)
    scaler = torch.amp.GradScaler("cuda", enabled=False)
    loader = torch.utils.data.DataLoader(Toy(8, 0), batch_size=4, pin_memory=True)
    batches = [_to(b, device) for b in loader]
    torch.cuda.synchronize()
    torch.cuda.set_sync_debug_mode("error")
    try:
        for b in batches * 2:
            loss = train_step(task, module, module, b, opt, scaler, 1e-3, 1.0, torch.bfloat16)
    finally:
        torch.cuda.set_sync_debug_mode("default")
    assert torch.isfinite(loss).item()


def test_a_cpu_checkpoint_records_no_autocast_type_so_older_ones_resume(tmp_path):
    """Autocast's type matters on CUDA only: a CPU run's checkpoint does not record it, so a checkpoint written
    before the setting existed (without the key) resumes."""
    tc = TrainConfig(epochs=2, batch_size=8, lr=1e-2, warmup_steps=2, progress=False)
    train(HBEONetTask(CFG), Toy(16, 0), None, tmp_path, tc, stop_after_epoch=1)
    ck = load_checkpoint(tmp_path / CHECKPOINT)
    assert "amp_dtype" not in ck["settings"]["train"] and ck["epoch"] == 0
    train(HBEONetTask(CFG), Toy(16, 0), None, tmp_path, tc)              # resumes: the same settings
    assert load_checkpoint(tmp_path / CHECKPOINT)["epoch"] == 1
