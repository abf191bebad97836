import numpy as np
import pandas as pd
import torch

from hbeo import conventions as C
from hbeo.model.network import LossWeights, NetConfig
from hbeo.render.poses import uniform_so3
from hbeo.model.train import CHECKPOINT, LOG, TrainConfig, train

CFG = NetConfig(image_size=(16, 16), n_classes=3, n_coeffs=4, conv_channels=(4, 8, 8, 8), fc=(16, 16, 16))


class Toy(torch.utils.data.Dataset):
    """Class = which quadrant holds the blob; easy enough to beat chance in two epochs."""

    def __init__(self, n, seed):
        rng = np.random.default_rng(seed)
        self.labels = rng.integers(0, 3, n)
        self.R = uniform_so3(n, rng).astype(np.float32)
        self.depth = np.zeros((n, 1, 16, 16), np.float32)
        for i, c in enumerate(self.labels):
            r0, c0 = [(2, 2), (2, 9), (9, 5)][c]
            self.depth[i, 0, r0:r0 + 5, c0:c0 + 5] = 1.5 + 0.1 * rng.random()
        self.coeffs = rng.normal(size=(n, 4)).astype(np.float32)

    def __len__(self):
        return len(self.labels)

    def __getitem__(self, i):
        return {"depth": torch.from_numpy(self.depth[i]), "label": int(self.labels[i]),
                "rotation": torch.from_numpy(self.R[i]),
                "axis_angle": torch.tensor(C.rotation_to_axis_angle(self.R[i]), dtype=torch.float32),
                "coeffs": torch.from_numpy(self.coeffs[i])}


def weights(net):
    return torch.cat([p.detach().flatten() for p in net.state_dict().values() if p.dtype.is_floating_point])


def test_learns_and_resumes_exactly(tmp_path):
    tr, va = Toy(96, 0), Toy(48, 1)
    tc = TrainConfig(epochs=4, batch_size=16, lr=1e-2, warmup_steps=2, progress=False,
                     loss=LossWeights(pose=0.1, coeffs=0.1))     # pose and coeffs are noise here
    full = train(CFG, tr, va, tmp_path / "a", tc)
    log = pd.read_csv(tmp_path / "a" / LOG)
    assert list(log.epoch) == [1, 2, 3, 4] and log.val_accuracy.iloc[-1] > 0.8     # chance is 1/3
    train(CFG, tr, va, tmp_path / "b", tc, stop_after_epoch=1)                   # "interrupted"
    assert list(pd.read_csv(tmp_path / "b" / LOG).epoch) == [1]
    resumed = train(CFG, tr, va, tmp_path / "b", tc)
    assert torch.equal(weights(full), weights(resumed))
    assert pd.read_csv(tmp_path / "b" / LOG).drop(columns="images_per_s").equals(log.drop(columns="images_per_s"))
    assert (tmp_path / "b" / CHECKPOINT).exists()


def test_resume_refuses_another_network(tmp_path):
    import pytest
    tc = TrainConfig(epochs=1, batch_size=16, progress=False)
    train(CFG, Toy(16, 0), Toy(8, 1), tmp_path, tc)
    other = NetConfig(image_size=(16, 16), n_classes=3, n_coeffs=5, conv_channels=(4, 8, 8, 8), fc=(16, 16, 16))
    with pytest.raises(ValueError, match="another network configuration"):
        train(other, Toy(16, 0), Toy(8, 1), tmp_path, tc)
    # the same network with other loss weights or other data would silently mix two runs
    with pytest.raises(ValueError, match="trained with loss"):
        train(CFG, Toy(16, 0), Toy(8, 1), tmp_path, TrainConfig(epochs=1, batch_size=16, progress=False,
                                                               loss=LossWeights(pose=5.0)))
    with pytest.raises(ValueError, match="trained with data"):
        train(CFG, Toy(16, 0), Toy(8, 1), tmp_path, TrainConfig(epochs=1, batch_size=16, progress=False,
                                                               data={"augment_roll": True}))


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
    tc = TrainConfig(epochs=4, batch_size=16, lr=1e-2, warmup_steps=2, progress=False, loss=LossWeights(coeffs=0.1))
    full = train(cfg, tr, va, tmp_path / "a", tc)
    log = pd.read_csv(tmp_path / "a" / LOG)
    assert log.val_pose_median_deg.iloc[-1] < 20 < log.val_pose_median_deg.iloc[0]   # chance ~126 degrees
    train(cfg, tr, va, tmp_path / "b", tc, stop_after_epoch=2)
    assert torch.equal(weights(full), weights(train(cfg, tr, va, tmp_path / "b", tc)))
