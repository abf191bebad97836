"""Sampling viewpoints: which rotations (uniform over SO(3) or upright) and where the object sits.

Frames and encodings are those of :mod:`hbeo.conventions`: R takes the canonical object
frame to the camera frame (OpenCV axes), t is the object centre in the camera frame, metres.
The rotations themselves are built by :mod:`hbeo.rotations` (:func:`~hbeo.rotations.uniform_so3`,
:func:`~hbeo.rotations.yaw_elevation_to_matrix`). Imports numpy and the foundation layer only.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hbeo.rotations import uniform_so3, yaw_elevation_to_matrix

SAMPLERS = ("so3", "upright")


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
            R = yaw_elevation_to_matrix(rng.uniform(0, 2 * np.pi, n), rng.uniform(e_lo, e_hi, n))
        z = rng.uniform(*self.distance, size=n)
        xy = rng.uniform(-self.shift, self.shift, size=(n, 2)) * z[:, None]
        return R, np.column_stack([xy, z])
