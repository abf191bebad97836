"""A small training job for tests/test_resume.py: ``python tests/resume_job.py OUT [STOP_STEP]``.

Trains a tiny HBEONet (with dropout and roll augmentation, so every random generator the loop
restores matters) on a synthetic set, checkpointing every 3 steps, into OUT; prints ``started``
once torch is imported (the test kills it at random moments after that) and, at the end, the
sha256 of the weights. Not a test module itself.
"""
import sys

import numpy as np
import torch

from hbeo.conventions import Intrinsics
from hbeo.model.augment import RollAugment
from hbeo.model.distributed import weights_sha256
from hbeo.model.fit import HBEONetTask
from hbeo.model.network import LossWeights, NetConfig
from hbeo.model.loop import TrainConfig, train
from hbeo.rotations import matrix_to_axis_angle, uniform_so3

CFG = NetConfig(image_size=(16, 16), n_classes=3, n_coeffs=4, conv_channels=(4, 8, 8, 8), fc=(16, 16, 16),
                dropout=0.3)
K = Intrinsics(fx=20.0, fy=20.0, cx=7.5, cy=7.5, width=16, height=16)
TASK = HBEONetTask(CFG, LossWeights(pose=0.1, coeffs=0.1))


def config(**kw) -> TrainConfig:
    return TrainConfig(**{"epochs": 3, "batch_size": 8, "lr": 1e-2, "warmup_steps": 2, "progress": False,
                          "checkpoint_every": 3, **kw})


class Blobs(torch.utils.data.Dataset):
    """Class = which quadrant holds the blob; rotations and coefficients are noise."""

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
                "axis_angle": torch.tensor(matrix_to_axis_angle(self.R[i]), dtype=torch.float32),
                "coeffs": torch.from_numpy(self.coeffs[i])}


def data():
    return RollAugment(Blobs(60, 0), K), Blobs(16, 1)          # 8 steps per epoch, the last one short


if __name__ == "__main__":
    out, stop = sys.argv[1], (int(sys.argv[2]) if len(sys.argv) > 2 else None)
    tr, va = data()
    print("started", flush=True)
    net = train(TASK, tr, va, out, config(), stop_after_step=stop)
    print(weights_sha256(net), flush=True)
