"""HBEONet: one depth image -> class logits, pose and subspace coefficients, in one shot.

The paper's architecture: four shared stride-2 convolutions (no pooling), three shared
fully connected layers, then a separate linear head each for class, pose and subspace
projection. Input: a depth image (B, 1, H, W), metres, 0 = no object (see
:func:`normalize_depth`). Pose output, one of:

- ``axis_angle`` (the paper): a 3-element axis-angle vector (radians), regressed;
- ``6d``: the continuous 6-D representation (Zhou et al. 2019: the first two columns of the
  rotation matrix, Gram-Schmidt-orthonormalized), regressed; no discontinuity at pi;
- ``bins``: logits over a fixed near-uniform grid of ``rotation_bins`` rotations
  (:func:`hbeo.rotations.super_fibonacci`), trained with cross-entropy against a Gaussian-smoothed
  target around the true rotation; decoded as the most probable bin refined by the
  probability-weighted mean of its neighbours. A distribution can hold several modes (a table
  seen from above: turned by 0 or 180 degrees), where a regression falls between them.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

from hbeo.limits import MEMORY_FRACTION, TRAIN_BYTES_PER_PARAM, ResourceError, available_memory, human_bytes
from hbeo.rotations import axis_angle_to_matrix, matrix_to_sixd, project_to_so3, sixd_to_matrix, super_fibonacci

ROTATIONS = ("axis_angle", "6d", "bins")
NORMALIZATIONS = ("none", "center")


@dataclass(frozen=True)
class NetConfig:
    """Sizes of HBEONet. ``image_size`` is (width, height) in pixels."""

    image_size: tuple[int, int] = (320, 240)
    n_classes: int = 10
    n_coeffs: int = 344
    conv_channels: tuple[int, ...] = (32, 64, 128, 128)
    kernel: int = 5
    fc: tuple[int, ...] = (384, 256, 256)
    rotation: str = "axis_angle"     #: "axis_angle" (paper), "6d" or "bins"
    rotation_bins: int = 4096        #: grid size for rotation="bins" (neighbours about 14 degrees apart)
    bin_sigma_deg: float = 10.0      #: width of the smoothed target for rotation="bins", degrees
    normalization: str = "none"      #: "none" (paper: metres) or "center" (see normalize_depth)
    dropout: float = 0.0

    def __post_init__(self):
        if self.rotation not in ROTATIONS:
            raise ValueError(f"rotation must be one of {ROTATIONS}, got {self.rotation!r}")
        if self.normalization not in NORMALIZATIONS:
            raise ValueError(f"normalization must be one of {NORMALIZATIONS}, got {self.normalization!r}")
        if len(self.conv_channels) != 4 or len(self.fc) != 3:
            raise ValueError("HBEONet has four convolutions and three fully connected layers")
        if self.rotation_bins < 2 or self.bin_sigma_deg <= 0:
            raise ValueError(f"rotation_bins must be >= 2 and bin_sigma_deg > 0, got {self.rotation_bins}, "
                             f"{self.bin_sigma_deg}")

    @property
    def pose_dim(self) -> int:
        return {"axis_angle": 3, "6d": 6, "bins": self.rotation_bins}[self.rotation]

    def to_dict(self) -> dict:
        return asdict(self)


def normalize_depth(depth: torch.Tensor, mode: str) -> torch.Tensor:
    """Network input from depth (B, 1, H, W), metres, 0 = background.

    ``none``: depth as is (the paper). ``center``: subtract each image's median object depth
    from the object pixels (background stays 0), removing the dependence of the values on
    the object's distance; the apparent size still changes with distance.
    """
    if mode == "none":
        return depth
    mask = depth > 0
    flat = torch.where(mask, depth, torch.nan).flatten(1)
    med = torch.nanmedian(flat, dim=1).values.nan_to_num(0.0).view(-1, 1, 1, 1)
    return torch.where(mask, depth - med, torch.zeros_like(depth))


class HBEONet(nn.Module):
    def __init__(self, cfg: NetConfig):
        super().__init__()
        self.cfg = cfg
        convs, c_in = [], 1
        for c in cfg.conv_channels:
            convs += [nn.Conv2d(c_in, c, cfg.kernel, stride=2, padding=cfg.kernel // 2), nn.BatchNorm2d(c),
                      nn.ReLU(inplace=True)]
            c_in = c
        self.features = nn.Sequential(*convs)
        w, h = cfg.image_size
        for _ in range(4):
            w, h = (w + 1) // 2, (h + 1) // 2
        fcs, f_in = [], c_in * w * h
        for f in cfg.fc:
            fcs += [nn.Linear(f_in, f), nn.ReLU(inplace=True)]
            if cfg.dropout:
                fcs.append(nn.Dropout(cfg.dropout))
            f_in = f
        self.shared = nn.Sequential(*fcs)
        self.class_head = nn.Linear(f_in, cfg.n_classes)
        self.pose_head = nn.Linear(f_in, cfg.pose_dim)
        self.coeff_head = nn.Linear(f_in, cfg.n_coeffs)
        if cfg.rotation == "bins":   # fixed, derived from the configuration: not saved with the weights
            self.register_buffer("bin_rotations", torch.tensor(super_fibonacci(cfg.rotation_bins),
                                                               dtype=torch.float32), persistent=False)

    def forward(self, depth: torch.Tensor) -> dict[str, torch.Tensor]:
        """depth (B, 1, H, W), metres -> {"logits": (B, C), "pose": (B, 3|6|n_bins), "coeffs": (B, k)}."""
        x = normalize_depth(depth, self.cfg.normalization)
        x = self.shared(self.features(x).flatten(1))
        return {"logits": self.class_head(x), "pose": self.pose_head(x), "coeffs": self.coeff_head(x)}

    def pose_matrix(self, pose: torch.Tensor) -> torch.Tensor:
        """The network's pose output (B, 3|6|n_bins) -> rotation matrices (B, 3, 3), pose's dtype."""
        if self.cfg.rotation == "bins":
            return bins_to_matrix(pose, self.bin_rotations.to(pose.dtype), 4.0 * self.cfg.bin_sigma_deg)
        return pose_to_matrix(pose, self.cfg.rotation)

    def n_params(self) -> int:
        return sum(p.numel() for p in self.parameters())


def _feature_size(cfg: NetConfig) -> int:
    """Inputs of the first fully connected layer: the last convolution's channels x its output pixels."""
    w, h = cfg.image_size
    for _ in range(4):
        w, h = (int(w) + 1) // 2, (int(h) + 1) // 2
    return int(cfg.conv_channels[-1]) * w * h


def network_params(cfg: NetConfig) -> int:
    """HBEONet(cfg)'s parameter count from its sizes alone (nothing allocated): the convolutions with their
    biases and batch norms, the three shared layers and the three heads. Equals ``HBEONet(cfg).n_params()``."""
    n, c_in = 0, 1
    for c in cfg.conv_channels:
        n += c_in * c * cfg.kernel ** 2 + c + 2 * c
        c_in = c
    f_in = _feature_size(cfg)
    for f in (*cfg.fc, cfg.n_classes + cfg.pose_dim + cfg.n_coeffs):   # the heads: one layer of their widths
        n += f_in * f + f
        f_in = f
    return n


def check_network(cfg: NetConfig, option: str = "--fc", memory: int | None = None) -> int:
    """HBEONet(cfg)'s parameter count, or ResourceError before anything is allocated when training it
    (:data:`hbeo.limits.TRAIN_BYTES_PER_PARAM` a parameter: weights, gradients, Adam's two moments) needs
    more than :data:`hbeo.limits.MEMORY_FRACTION` of the available memory (``memory``: that figure, for
    tests). The message names ``option`` with the widths, the estimate and the largest value of the widest
    layer's width that fits with the other two as given."""
    params = network_params(cfg)
    mem = memory if memory is not None else available_memory()
    budget = mem * MEMORY_FRACTION
    need = params * TRAIN_BYTES_PER_PARAM
    if need <= budget:
        return params
    fc = tuple(int(w) for w in cfg.fc)
    # parameters are linear in each width: pick the width that adds the most, solve for its largest value
    ins = (_feature_size(cfg),) + fc[:2]
    outs = fc[1:] + (cfg.n_classes + cfg.pose_dim + cfg.n_coeffs,)
    per = [i + 1 + o for i, o in zip(ins, outs)]            # parameters one more unit of width i adds
    i = max(range(3), key=lambda j: fc[j] * per[j])
    rest = params - fc[i] * per[i]
    fit = int((budget / TRAIN_BYTES_PER_PARAM - rest) // per[i])
    what = (f"the largest W{i + 1} that fits (the other widths as given) is {fit:,}" if fit >= 1 else
            f"it does not fit even with W{i + 1} = 1: make the other widths smaller too")
    raise ResourceError(
        f"{option} {','.join(map(str, fc))}: HBEONet would have {params:,} parameters at {cfg.image_size[0]}x"
        f"{cfg.image_size[1]} input; training it needs about {human_bytes(need)} of memory (float32 weights, "
        f"gradients and Adam's two moments), {human_bytes(mem)} available; {what}")


# ------------------------------------------------------------------ pose heads

def pose_to_matrix(pose: torch.Tensor, rotation: str) -> torch.Tensor:
    """Regressed pose output (B, 3|6) -> rotation matrices (B, 3, 3). For ``bins`` use
    :meth:`HBEONet.pose_matrix`, which knows the grid."""
    if rotation == "bins":
        raise ValueError("rotation 'bins' needs the network's grid: use HBEONet.pose_matrix")
    return axis_angle_to_matrix(pose) if rotation == "axis_angle" else sixd_to_matrix(pose)


def bin_cosines(R: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """cos of the geodesic angle between rotations R (B, 3, 3) and grid (N, 3, 3) -> (B, N):
    (trace(R^T G) - 1) / 2, clamped to [-1, 1]."""
    return ((R.flatten(1) @ grid.flatten(1).T - 1) / 2).clamp(-1.0, 1.0)


def bins_to_matrix(logits: torch.Tensor, grid: torch.Tensor, radius_deg: float) -> torch.Tensor:
    """Rotation-bin logits (B, N) over ``grid`` (N, 3, 3) -> rotations (B, 3, 3): the most probable
    bin, refined by the probability-weighted mean (projected back onto SO(3)) of the bins within
    ``radius_deg`` of it (the network uses 4 sigma of its target: wide enough to cover the grid's
    spacing, narrow enough to leave a second mode out)."""
    p = torch.softmax(logits, dim=1)
    best = grid[p.argmax(1)]
    near = bin_cosines(best, grid) >= math.cos(math.radians(radius_deg))
    w = torch.where(near, p, torch.zeros_like(p))
    M = (w @ grid.flatten(1)).view(-1, 3, 3)
    return project_to_so3(M)


def bin_targets(R: torch.Tensor, grid: torch.Tensor, sigma_deg: float) -> torch.Tensor:
    """Smoothed one-hot targets (B, N) for true rotations R (B, 3, 3): proportional to
    exp(-angle^2 / (2 sigma^2)) over the grid's geodesic angles to R, summing to 1."""
    ang = torch.acos(bin_cosines(R, grid))
    return torch.softmax(-0.5 * (ang / math.radians(sigma_deg)) ** 2, dim=1)


# ------------------------------------------------------------------ loss

@dataclass(frozen=True)
class LossWeights:
    """gamma_c * CE + gamma_o * ||pose error||_2 + gamma_p * ||coefficient error||_2 (the paper's loss)."""

    classification: float = 1.0
    pose: float = 1.0
    coeffs: float = 1.0


def hbeo_loss(out: dict, batch: dict, cfg: NetConfig, w: LossWeights | None = None,
              coeff_scale: torch.Tensor | float = 1.0, grid: torch.Tensor | None = None,
              class_weights: torch.Tensor | None = None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """Total loss and its parts for one batch; the parts are 0-d tensors, detached, left on the device
    (reading one, ``float(part)``, waits for the device: the training loop never does).

    The pose term is the L2 norm of the difference between predicted and true pose encodings
    (axis-angle vectors, or 6-D vectors for the 6-D option), or for ``bins`` the cross-entropy
    against :func:`bin_targets` on ``grid`` (N, 3, 3); the coefficient term the L2 norm
    of the coefficient difference divided by ``coeff_scale`` (per-dimension scale, so that no
    dimension dominates); both averaged over the batch. ``class_weights`` (C,): the cross-entropy
    weighted by class (torch's weighted mean: sum_i w[y_i] CE_i / sum_i w[y_i]); None: the paper's.
    """
    w = w or LossWeights()
    if class_weights is not None:
        class_weights = class_weights.to(out["logits"].device, out["logits"].dtype)
    ce = F.cross_entropy(out["logits"], batch["label"], weight=class_weights)
    if cfg.rotation == "bins":
        if grid is None:
            raise ValueError("rotation 'bins' needs the network's grid (HBEONet.bin_rotations)")
        target = bin_targets(batch["rotation"].to(grid.dtype), grid, cfg.bin_sigma_deg)
        pose = F.cross_entropy(out["pose"].float(), target)
    else:
        target = batch["axis_angle"] if cfg.rotation == "axis_angle" else matrix_to_sixd(batch["rotation"])
        pose = (out["pose"] - target).norm(dim=-1).mean()
    coeff = ((out["coeffs"] - batch["coeffs"]) / coeff_scale).norm(dim=-1).mean()
    total = w.classification * ce + w.pose * pose + w.coeffs * coeff
    return total, {"ce": ce.detach(), "pose": pose.detach(), "coeff": coeff.detach()}
