"""HBEONet: one depth image -> class logits, pose and subspace coefficients, in one shot.

The paper's architecture: four shared stride-2 convolutions (no pooling), three shared
fully connected layers, then a separate linear head each for class, pose and subspace
projection. Input: a depth image (B, 1, H, W), metres, 0 = no object (see
:func:`normalize_depth`). Pose output: the paper's 3-element axis-angle vector (radians),
or, as an option, the continuous 6-D representation (Zhou et al. 2019: the first two
columns of the rotation matrix, Gram-Schmidt-orthonormalized), which has no
discontinuity at pi.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

ROTATIONS = ("axis_angle", "6d")
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
    rotation: str = "axis_angle"     #: "axis_angle" (paper) or "6d"
    normalization: str = "none"      #: "none" (paper: metres) or "center" (see normalize_depth)
    dropout: float = 0.0

    def __post_init__(self):
        if self.rotation not in ROTATIONS:
            raise ValueError(f"rotation must be one of {ROTATIONS}, got {self.rotation!r}")
        if self.normalization not in NORMALIZATIONS:
            raise ValueError(f"normalization must be one of {NORMALIZATIONS}, got {self.normalization!r}")
        if len(self.conv_channels) != 4 or len(self.fc) != 3:
            raise ValueError("HBEONet has four convolutions and three fully connected layers")

    @property
    def pose_dim(self) -> int:
        return 3 if self.rotation == "axis_angle" else 6

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

    def forward(self, depth: torch.Tensor) -> dict[str, torch.Tensor]:
        """depth (B, 1, H, W), metres -> {"logits": (B, C), "pose": (B, 3|6), "coeffs": (B, k)}."""
        x = normalize_depth(depth, self.cfg.normalization)
        x = self.shared(self.features(x).flatten(1))
        return {"logits": self.class_head(x), "pose": self.pose_head(x), "coeffs": self.coeff_head(x)}

    def n_params(self) -> int:
        return sum(p.numel() for p in self.parameters())


# ------------------------------------------------------------------ rotations (torch)

def axis_angle_to_matrix(v: torch.Tensor) -> torch.Tensor:
    """Axis-angle (B, 3), radians -> rotation matrices (B, 3, 3) (Rodrigues)."""
    theta = v.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    k = v / theta
    K = torch.zeros(v.shape[0], 3, 3, dtype=v.dtype, device=v.device)
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
    K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
    s, c = torch.sin(theta)[..., None], torch.cos(theta)[..., None]
    eye = torch.eye(3, dtype=v.dtype, device=v.device).expand_as(K)
    return eye + s * K + (1 - c) * (K @ K)


def sixd_to_matrix(x: torch.Tensor) -> torch.Tensor:
    """6-D representation (B, 6) -> rotation matrices (B, 3, 3) whose first two columns are the
    Gram-Schmidt-orthonormalized halves of x."""
    a, b = x[:, :3], x[:, 3:]
    c1 = F.normalize(a, dim=-1)
    c2 = F.normalize(b - (c1 * b).sum(-1, keepdim=True) * c1, dim=-1)
    return torch.stack([c1, c2, torch.cross(c1, c2, dim=-1)], dim=-1)


def matrix_to_sixd(R: torch.Tensor) -> torch.Tensor:
    """Rotation matrices (B, 3, 3) -> 6-D representation (B, 6): the first two columns."""
    return torch.cat([R[:, :, 0], R[:, :, 1]], dim=-1)


def pose_to_matrix(pose: torch.Tensor, rotation: str) -> torch.Tensor:
    """Network pose output (B, 3|6) -> rotation matrices (B, 3, 3)."""
    return axis_angle_to_matrix(pose) if rotation == "axis_angle" else sixd_to_matrix(pose)


# ------------------------------------------------------------------ loss

@dataclass(frozen=True)
class LossWeights:
    """gamma_c * CE + gamma_o * ||pose error||_2 + gamma_p * ||coefficient error||_2 (the paper's loss)."""

    classification: float = 1.0
    pose: float = 1.0
    coeffs: float = 1.0


def hbeo_loss(out: dict, batch: dict, cfg: NetConfig, w: LossWeights | None = None,
              coeff_scale: torch.Tensor | float = 1.0) -> tuple[torch.Tensor, dict[str, float]]:
    """Total loss and its parts for one batch.

    The pose term is the L2 norm of the difference between predicted and true pose encodings
    (axis-angle vectors, or 6-D vectors for the 6-D option); the coefficient term the L2 norm
    of the coefficient difference divided by ``coeff_scale`` (per-dimension scale, so that no
    dimension dominates); both averaged over the batch.
    """
    w = w or LossWeights()
    ce = F.cross_entropy(out["logits"], batch["label"])
    target = batch["axis_angle"] if cfg.rotation == "axis_angle" else matrix_to_sixd(batch["rotation"])
    pose = (out["pose"] - target).norm(dim=-1).mean()
    coeff = ((out["coeffs"] - batch["coeffs"]) / coeff_scale).norm(dim=-1).mean()
    total = w.classification * ce + w.pose * pose + w.coeffs * coeff
    return total, {"ce": ce.item(), "pose": pose.item(), "coeff": coeff.item()}
