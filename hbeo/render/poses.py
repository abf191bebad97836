"""Sampling viewpoints: rotations (uniform over SO(3) or upright) and object placement.

Frames and encodings are those of :mod:`hbeo.conventions`: R takes the canonical object
frame to the camera frame (OpenCV axes), t is the object centre in the camera frame, metres.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SAMPLERS = ("so3", "upright")


def quaternion_to_matrix(w, x, y, z) -> np.ndarray:
    """Unit quaternions (arrays of any matching shape S, scalar first) -> rotation matrices (S, 3, 3)."""
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def uniform_so3(n: int, rng: np.random.Generator) -> np.ndarray:
    """n rotation matrices (n, 3, 3) uniform (Haar) on SO(3): normalized Gaussian quaternions."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return quaternion_to_matrix(*q.T)


#: super-Fibonacci constants (Alexa, CVPR 2022): phi = sqrt(2), psi^4 = psi + 4
_SF_PHI, _SF_PSI = np.sqrt(2.0), 1.533751168755204288118041


def super_fibonacci(n: int) -> np.ndarray:
    """n rotation matrices (n, 3, 3) spread near-uniformly over SO(3), deterministic, any n: the
    super-Fibonacci spiral (Alexa, CVPR 2022). Sample i: s = i + 1/2, r = sqrt(s/n), R = sqrt(1 - s/n),
    quaternion (x, y, z, w) = (r sin(2 pi s / phi), r cos(..), R sin(2 pi s / psi), R cos(..))."""
    n = int(n)
    if n < 1:
        raise ValueError(f"need at least one rotation, got n={n}")
    s = np.arange(n) + 0.5
    r, R = np.sqrt(s / n), np.sqrt(1.0 - s / n)
    a, b = 2 * np.pi * s / _SF_PHI, 2 * np.pi * s / _SF_PSI
    return quaternion_to_matrix(R * np.cos(b), r * np.sin(a), r * np.cos(a), R * np.sin(b))


def upright(yaw: np.ndarray, elevation: np.ndarray) -> np.ndarray:
    """Rotations (n, 3, 3) for a camera without roll looking down at ``elevation`` (radians)
    on an object turned by ``yaw`` (radians) about its up axis (+z). At yaw 0 the camera sits
    on the object's -y side, facing its front."""
    yaw, elevation = np.atleast_1d(yaw), np.atleast_1d(elevation)
    ce, se = np.cos(elevation), np.sin(elevation)
    zeros, ones = np.zeros_like(ce), np.ones_like(ce)
    x = np.stack([ones, zeros, zeros], -1)             # camera right, world axes
    y = np.stack([zeros, -se, -ce], -1)                # camera down
    f = np.stack([zeros, ce, -se], -1)                 # camera forward
    R_cw = np.stack([x, y, f], axis=1)                 # world -> camera
    cy, sy = np.cos(yaw), np.sin(yaw)
    Rz = np.zeros((len(yaw), 3, 3))
    Rz[:, 0, 0], Rz[:, 0, 1], Rz[:, 1, 0], Rz[:, 1, 1], Rz[:, 2, 2] = cy, -sy, sy, cy, 1.0
    return R_cw @ Rz


@dataclass(frozen=True)
class ViewSampler:
    """Draws (R, t) for views of an object whose longest side is ``object_size`` metres.

    sampler: ``"so3"`` (uniform rotations, the paper's unknown 3-DOF setting) or ``"upright"``
    (yaw uniform, elevation uniform in ``elevation_deg``, no roll).
    distance: range of the object centre's depth, metres. shift: largest offset of the object
    centre from the optical axis, as a fraction of its depth (x and y uniform in +-shift).
    """

    sampler: str = "so3"
    elevation_deg: tuple[float, float] = (10.0, 50.0)
    distance: tuple[float, float] = (1.4, 2.0)
    shift: float = 0.05
    object_size: float = 1.0

    def __post_init__(self):
        if self.sampler not in SAMPLERS:
            raise ValueError(f"unknown sampler {self.sampler!r}; expected one of {', '.join(SAMPLERS)}")
        lo, hi = self.distance
        if not 0 < lo <= hi:
            raise ValueError(f"distance range must satisfy 0 < min <= max, got {self.distance}")
        if lo <= self.object_size * np.sqrt(3) / 2:
            raise ValueError(f"distance {lo} m puts the camera inside an object of size {self.object_size} m")

    def sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """n views -> rotations (n, 3, 3), translations (n, 3) in metres."""
        if self.sampler == "so3":
            R = uniform_so3(n, rng)
        else:
            e_lo, e_hi = np.radians(self.elevation_deg)
            R = upright(rng.uniform(0, 2 * np.pi, n), rng.uniform(e_lo, e_hi, n))
        z = rng.uniform(*self.distance, size=n)
        xy = rng.uniform(-self.shift, self.shift, size=(n, 2)) * z[:, None]
        return R, np.column_stack([xy, z])
