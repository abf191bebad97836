"""Sampling viewpoints: which rotations (the readings of the view protocol) and where the object sits.

Frames and encodings are those of :mod:`hbeo.conventions`: R takes the canonical object
frame to the camera frame (OpenCV axes), t is the object centre in the camera frame, metres.
The rotations themselves are built by :mod:`hbeo.rotations` (:func:`~hbeo.rotations.quaternion_to_matrix`
of normalized Gaussian quaternions, as :func:`~hbeo.rotations.uniform_so3` draws them,
:func:`~hbeo.rotations.yaw_elevation_to_matrix`, :func:`~hbeo.rotations.yaw_elevation_roll_to_matrix`).
Imports numpy and the foundation layer only.

Readings of the view protocol (:data:`SAMPLERS`)
    The paper says only that its views are "multiple random viewpoints" of each object. Each
    sampler is one reading of that phrase; the angles are those of the 3-DOF order
    ``R = Rz(roll) @ E(elevation) @ Rz(yaw)`` (:mod:`hbeo.rotations`), elevation measured from
    the object's horizon (the horizontal plane through its centre; positive: camera above it).

    ``so3``
        R uniform (Haar) on SO(3) (normalized Gaussian quaternions): the object in any orientation,
        views from under the floor included. The project's main reading (``docs/method.md``, "Readings of the
        view protocol").
    ``upright``
        yaw uniform in [0, 2 pi), elevation uniform in ``elevation_deg`` (default 10..50 degrees),
        no roll: 2 DOF, the object standing on a floor seen by a level camera.
    ``sphere``
        the camera anywhere on the view sphere looking at the object with a random roll: yaw uniform
        in [0, 2 pi), sin(elevation) uniform in [-1, 1] (the viewing direction uniform in area on
        the sphere, Archimedes), roll uniform in [0, 2 pi); 3 DOF. *This is the same distribution
        as* ``so3``: the viewing direction ``R.T @ (0, 0, 1)`` of a Haar rotation is uniform on the
        sphere, and since the Haar measure is invariant under ``R -> Rz(a) @ R``, given the
        direction the remaining freedom (a turn about the optical axis) is uniform and independent;
        ``sphere`` draws exactly that (elevation +-90 degrees, a null set, is where the angles
        are singular). It is kept as a reading of its own, by its own formula and its own draws
        (uniform angles, not quaternions): evaluated on the same objects it gives a second,
        independent set of views from the main reading's distribution, so the difference between
        its figures and ``so3``'s measures the views' sampling noise and checks both samplers.
        ``tests/test_poses.py`` tests the two distributions equal.
    ``floor``
        a robot's camera above the floor plane: yaw uniform in [0, 2 pi), sin(elevation) uniform
        in (0, 1] (the viewing direction uniform in area on the upper hemisphere, elevation in
        (0, 90] degrees), roll uniform in [0, 2 pi); 3 DOF. Unlike ``so3`` no view looks from
        below the object's horizon: the object's up axis never points away from the camera
        (``R[2, 2] = -sin(elevation) < 0``). The elevation is that of the optical axis; the
        object's offset from the axis (``shift``) can put the camera's centre below the horizon
        of the object's centre by at most ``sqrt(2) * shift`` times the depth, and only when
        ``tan(elevation) < sqrt(2) * shift`` (elevation below 4 degrees at the default shift).

Draws
    Each sampler draws its rotations first, then the depths, then the offsets, from the one
    generator it is given (:meth:`ViewSampler.sample`): deterministic given the generator's state.
    The samplers use different numbers of draws (``so3`` 4 normals, ``upright`` 2 uniforms,
    ``sphere`` and ``floor`` 3 uniforms per view), so the same generator gives different depths
    and offsets under different samplers: views under two readings share their objects and
    streams (:func:`hbeo.render.views.query_rng`), not their images.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hbeo.rotations import quaternion_to_matrix, yaw_elevation_roll_to_matrix, yaw_elevation_to_matrix

#: the view samplers, one per reading of "multiple random viewpoints" (module docstring); ``so3`` the main one
SAMPLERS = ("so3", "upright", "sphere", "floor")
#: one line each, for help texts and reports
SAMPLER_HELP = {
    "so3": "uniform over SO(3) (the main reading: any orientation, views from below included)",
    "upright": "random yaw, elevation in elevation_deg, no roll (2 DOF)",
    "sphere": "camera uniform on the view sphere + uniform roll (3 DOF; the same distribution as so3)",
    "floor": "camera uniform on the upper hemisphere (above the floor) + uniform roll (3 DOF)",
}


def check_sampler(name) -> str:
    """``name`` if it is one of :data:`SAMPLERS`, else ValueError naming it and the choices."""
    if not isinstance(name, str) or name not in SAMPLERS:
        raise ValueError(f"unknown sampler {name!r}; expected one of {', '.join(SAMPLERS)}")
    return name


def draw_angles(sampler: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """The raw numbers of n rotations of reading ``sampler``, drawn from ``rng`` (module docstring,
    "Draws"): (n, 4) normals for ``so3``, (n, 2) uniforms [yaw, elevation u] for ``upright``, (n, 3)
    [yaw, u, roll] for ``sphere`` and ``floor``; :func:`rotations_from` turns them into matrices."""
    check_sampler(sampler)
    if sampler == "so3":
        return rng.normal(size=(n, 4))
    if sampler == "upright":
        return np.column_stack([rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 1, n)])
    return np.column_stack([rng.uniform(0, 2 * np.pi, n), rng.uniform(0, 1, n), rng.uniform(0, 2 * np.pi, n)])


def rotations_from(sampler: str, raw: np.ndarray, elevation_deg: tuple[float, float] = (10.0, 50.0)) -> np.ndarray:
    """Rotations (n, 3, 3) from :func:`draw_angles`' numbers ``raw``, row by row (so rows drawn from
    several generators give each generator's rotations)."""
    check_sampler(sampler)
    if sampler == "so3":
        q = raw / np.linalg.norm(raw, axis=1, keepdims=True)
        return quaternion_to_matrix(q)
    if sampler == "upright":
        e_lo, e_hi = np.radians(elevation_deg)
        return yaw_elevation_to_matrix(raw[:, 0], e_lo + (e_hi - e_lo) * raw[:, 1])
    u = raw[:, 1]                                               # [0, 1)
    sin_e = 2 * u - 1 if sampler == "sphere" else 1 - u       # [-1, 1) or (0, 1]
    return yaw_elevation_roll_to_matrix(raw[:, 0], np.arcsin(sin_e), raw[:, 2])


def sample_rotations(sampler: str, n: int, rng: np.random.Generator,
                     elevation_deg: tuple[float, float] = (10.0, 50.0)) -> np.ndarray:
    """n rotations (n, 3, 3) of reading ``sampler`` (module docstring), drawn from ``rng``;
    ``elevation_deg``: the ``upright`` sampler's elevation range, degrees."""
    return rotations_from(sampler, draw_angles(sampler, n, rng), elevation_deg)


@dataclass(frozen=True)
class ViewSampler:
    """Draws (R, t) for views of an object whose longest side is ``object_size`` metres.

    sampler: one of :data:`SAMPLERS` (module docstring): ``"so3"`` (uniform rotations, the paper's
    unknown 3-DOF setting, the main reading), ``"upright"`` (yaw uniform, elevation uniform in
    ``elevation_deg``, no roll), ``"sphere"`` (view sphere + roll: the same distribution as so3)
    or ``"floor"`` (upper hemisphere + roll).
    distance: range of the object centre's depth, metres. shift: largest offset of the object
    centre from the optical axis, as a fraction of its depth (x and y uniform in +-shift).
    """

    sampler: str = "so3"
    elevation_deg: tuple[float, float] = (10.0, 50.0)
    distance: tuple[float, float] = (1.4, 2.0)
    shift: float = 0.05
    object_size: float = 1.0

    def __post_init__(self):
        check_sampler(self.sampler)
        lo, hi = self.distance
        if not 0 < lo <= hi:
            raise ValueError(f"distance range must satisfy 0 < min <= max, got {self.distance}")
        if lo <= self.object_size * np.sqrt(3) / 2:
            raise ValueError(f"distance {lo} m puts the camera inside an object of size {self.object_size} m")

    def sample(self, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """n views -> rotations (n, 3, 3), translations (n, 3) in metres."""
        return self._views(*self._draw(n, rng))

    def sample_each(self, rngs) -> tuple[np.ndarray, np.ndarray]:
        """One view from each generator of ``rngs``: the rows of ``sample(1, rng)`` for each, stacked, with
        the arithmetic done once for all (a batch of streamed training views draws one generator per image)."""
        return self._views(*(np.concatenate(d) for d in zip(*(self._draw(1, g) for g in rngs))))

    def _draw(self, n: int, rng: np.random.Generator):
        """The rotations' raw numbers, then the depths, then the offsets, in that order."""
        raw = draw_angles(self.sampler, n, rng)
        z = rng.uniform(*self.distance, size=n)
        return raw, z, rng.uniform(-self.shift, self.shift, size=(n, 2))

    def _views(self, raw, z, xy) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_draw`'s numbers (rows of one generator or of several) -> rotations, translations (metres)."""
        return rotations_from(self.sampler, raw, self.elevation_deg), np.column_stack([xy * z[:, None], z])
