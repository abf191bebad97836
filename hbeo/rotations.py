"""Rotations: the one module that builds or converts a rotation (layout after pytorch3d's
``rotation_conversions.py``).

Convention (the pose facts are :mod:`hbeo.conventions`'; this module fixes the encodings)
    * Column vectors: a rotation matrix ``R`` (..., 3, 3) moves a point as ``R @ p``.
    * ``R`` takes the canonical object frame (ModelNet's, +z up) to the camera frame (OpenCV
      axes: x right, y down, z forward). The one exception is :func:`view_deg_to_matrix`, whose
      target is a picture frame (x right, y *up*, z toward the viewer); its docstring says so.
    * Angles in radians unless a name says ``_deg``.
    * Axis-angle (rotation vector) (..., 3): unit axis times angle, components (x, y, z); the
      paper's 3-DOF pose vector. Produced with the angle in [0, pi].
    * Quaternions (..., 4): unit, real part first, ``(w, x, y, z)``; q and -q are one rotation.
    * 6-D (..., 6): the first two columns of ``R``, ``(R[:, 0], R[:, 1])``, the continuous
      representation of Zhou et al., "On the Continuity of Rotation Representations in Neural
      Networks", CVPR 2019.
    * The 3-DOF order of an upright view: ``R = Rz(roll) @ E(elevation) @ Rz(yaw)``: the object
      turns by ``yaw`` about its own +z first, the camera then looks down at it from
      ``elevation`` above its horizon (:func:`yaw_elevation_to_matrix`), and last rolls about
      its optical axis (``Rz`` in the camera frame, :func:`z_angle_to_matrix`);
      :func:`yaw_elevation_roll_to_matrix` builds it, for the view samplers of
      :mod:`hbeo.render.poses` (the upright one has roll 0).
    * Batched over leading ``...`` dimensions; an argument whose trailing shape is wrong raises
      ``ValueError`` naming the function and the shape that arrived.

Conversions are named ``a_to_b``. numpy in, numpy out (float64); the functions documented
"numpy or torch" also take torch tensors and return tensors of the input's dtype and device,
with the same formula. This module does not load torch: its torch branches run only for a
tensor argument, when torch is already loaded, so the data layer and worker processes can use
it without paying for torch.

Numerics: each function keeps the formula and evaluation order of the code it replaced, so
the callers' results round as they did before; that is why :func:`direction_to_matrix` evaluates
Rodrigues' formula in its own order and :func:`axis_and_angle_to_matrix` normalizes a single
axis differently from a batch of them.

Imports: numpy and scipy only; nothing from hbeo.
"""
from __future__ import annotations

import sys

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "ROTATION_TOL", "axis_and_angle_to_matrix", "axis_angle_to_matrix", "check_rotation_matrices",
    "direction_to_matrix", "geodesic", "geodesic_deg", "matrix_to_axis_angle", "matrix_to_quaternion",
    "matrix_to_sixd", "project_to_so3", "quaternion_to_matrix", "sixd_to_matrix", "super_fibonacci",
    "symmetric_pose_error_deg", "uniform_so3", "view_deg_to_matrix", "x_angle_to_matrix",
    "yaw_elevation_roll_to_matrix", "yaw_elevation_to_matrix", "z_angle_to_matrix",
]

#: how far a matrix may be from orthonormal (max |R^T R - I|) and its determinant from +1 and still
#: count as a rotation (:func:`check_rotation_matrices`)
ROTATION_TOL = 1e-4


# --------------------------------------------------------------------------- helpers

def _is_torch(x) -> bool:
    """True for a torch tensor (without importing torch)."""
    torch = sys.modules.get("torch")
    return torch is not None and isinstance(x, torch.Tensor)


def _check(x, tail: tuple[int, ...], fn: str, what: str, torch_ok: bool = False):
    """``x`` as float64 numpy (a tensor passes through if ``torch_ok``); ValueError unless its
    shape ends in ``tail``."""
    if not (torch_ok and _is_torch(x)):
        x = np.asarray(x, dtype=np.float64)
    shape = tuple(x.shape)
    if len(shape) < len(tail) or shape[len(shape) - len(tail):] != tail:
        want = "(..., " + ", ".join(map(str, tail)) + ")"
        raise ValueError(f"{fn}: {what} must have shape {want}, got {shape}")
    return x


# --------------------------------------------------------------------------- samplers

def uniform_so3(n: int, rng: np.random.Generator) -> np.ndarray:
    """n rotation matrices (n, 3, 3) uniform (Haar) on SO(3): normalized Gaussian quaternions."""
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return quaternion_to_matrix(q)


#: super-Fibonacci constants (Alexa, CVPR 2022): phi = sqrt(2), psi^4 = psi + 4
_SF_PHI, _SF_PSI = np.sqrt(2.0), 1.533751168755204288118041


def super_fibonacci(n: int) -> np.ndarray:
    """n rotation matrices (n, 3, 3) spread near-uniformly over SO(3), deterministic, any n: the
    super-Fibonacci spiral (Alexa, CVPR 2022). Sample i: s = i + 1/2, r = sqrt(s/n), R = sqrt(1 - s/n),
    quaternion (x, y, z, w) = (r sin(2 pi s / phi), r cos(..), R sin(2 pi s / psi), R cos(..))."""
    n = int(n)
    if n < 1:
        raise ValueError(f"super_fibonacci: need at least one rotation, got n={n}")
    s = np.arange(n) + 0.5
    r, R = np.sqrt(s / n), np.sqrt(1.0 - s / n)
    a, b = 2 * np.pi * s / _SF_PHI, 2 * np.pi * s / _SF_PSI
    return quaternion_to_matrix(np.stack([R * np.cos(b), r * np.sin(a), r * np.cos(a), R * np.sin(b)], -1))


# --------------------------------------------------------------------------- quaternions

def quaternion_to_matrix(q) -> np.ndarray:
    """Unit quaternions (..., 4), real part first -> rotation matrices (..., 3, 3)."""
    q = _check(q, (4,), "quaternion_to_matrix", "quaternions")
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], axis=-2)


def matrix_to_quaternion(R) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> unit quaternions (..., 4), real part first, w >= 0 (scipy)."""
    R = _check(R, (3, 3), "matrix_to_quaternion", "rotation matrices")
    xyzw = Rotation.from_matrix(R.reshape(-1, 3, 3)).as_quat()
    q = xyzw[:, [3, 0, 1, 2]]
    q[q[:, 0] < 0] *= -1
    return q.reshape(R.shape[:-2] + (4,))


# --------------------------------------------------------------------------- axis-angle

def matrix_to_axis_angle(R) -> np.ndarray:
    """Rotation matrices (..., 3, 3) -> axis-angle vectors (..., 3), radians, angle in [0, pi] (scipy)."""
    R = _check(R, (3, 3), "matrix_to_axis_angle", "rotation matrices")
    return Rotation.from_matrix(R.reshape(-1, 3, 3)).as_rotvec().reshape(R.shape[:-2] + (3,))


def axis_angle_to_matrix(v):
    """Axis-angle vectors (..., 3), radians -> rotation matrices (..., 3, 3), numpy or torch.

    Rodrigues: ``I + sin(theta) K + (1 - cos(theta)) K @ K`` with K the cross-product matrix of
    the unit axis; theta is clamped to >= 1e-12 (a zero vector gives the identity).
    """
    v = _check(v, (3,), "axis_angle_to_matrix", "axis-angle vectors", torch_ok=True)
    lead = tuple(v.shape[:-1])
    if _is_torch(v):
        import torch
        v = v.reshape(-1, 3)
        theta = v.norm(dim=-1, keepdim=True).clamp_min(1e-12)
        k = v / theta
        K = torch.zeros(v.shape[0], 3, 3, dtype=v.dtype, device=v.device)
        K[:, 0, 1], K[:, 0, 2], K[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
        K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
        s, c = torch.sin(theta)[..., None], torch.cos(theta)[..., None]
        eye = torch.eye(3, dtype=v.dtype, device=v.device).expand_as(K)
        return (eye + s * K + (1 - c) * (K @ K)).reshape(lead + (3, 3))
    v = v.reshape(-1, 3)
    theta = np.maximum(np.linalg.norm(v, axis=1), 1e-12)
    return _rodrigues(v / theta[:, None], np.sin(theta), np.cos(theta)).reshape(lead + (3, 3))


def axis_and_angle_to_matrix(axis, angle) -> np.ndarray:
    """Rotations by ``angle`` (...) radians about ``axis`` (..., 3) (normalized here; any nonzero
    length), broadcast against each other -> (..., 3, 3). Same Rodrigues formula as
    :func:`axis_angle_to_matrix`; for many angles about one axis, without forming axis * angle."""
    axis = _check(axis, (3,), "axis_and_angle_to_matrix", "axis")
    angle = np.asarray(angle, dtype=np.float64)
    # a single axis is normalized as np.linalg.norm does for a vector (a dot product), which can
    # differ from the batched sum in the last bit; kept so that ICP's results stay what they were
    norm = np.linalg.norm(axis) if axis.ndim == 1 else np.linalg.norm(axis, axis=-1, keepdims=True)
    k = axis / norm
    lead = np.broadcast_shapes(k.shape[:-1], angle.shape)
    k = np.broadcast_to(k, lead + (3,)).reshape(-1, 3)
    angle = np.broadcast_to(angle, lead).reshape(-1)
    return _rodrigues(k, np.sin(angle), np.cos(angle)).reshape(lead + (3, 3))


def _rodrigues(k: np.ndarray, s: np.ndarray, c: np.ndarray) -> np.ndarray:
    """I + s K + (1 - c) K @ K for unit axes k (N, 3), sines s (N,), cosines c (N,) -> (N, 3, 3)."""
    K = np.zeros((len(k), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0] = -k[:, 2], k[:, 1], k[:, 2]
    K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -k[:, 0], -k[:, 1], k[:, 0]
    return np.eye(3) + s[:, None, None] * K + (1 - c)[:, None, None] * (K @ K)


# --------------------------------------------------------------------------- 6-D (Zhou et al. 2019)

def sixd_to_matrix(x):
    """6-D representation (..., 6) -> rotation matrices (..., 3, 3), numpy or torch: the first two
    columns are the Gram-Schmidt-orthonormalized halves of x (norms clamped to >= 1e-12), the
    third their cross product (Zhou et al. 2019)."""
    x = _check(x, (6,), "sixd_to_matrix", "6-D vectors", torch_ok=True)
    a, b = x[..., :3], x[..., 3:]
    if _is_torch(x):
        import torch
        import torch.nn.functional as F
        c1 = F.normalize(a, dim=-1)
        c2 = F.normalize(b - (c1 * b).sum(-1, keepdim=True) * c1, dim=-1)
        return torch.stack([c1, c2, torch.cross(c1, c2, dim=-1)], dim=-1)

    def normalize(u):
        return u / np.maximum(np.linalg.norm(u, axis=-1, keepdims=True), 1e-12)
    c1 = normalize(a)
    c2 = normalize(b - (c1 * b).sum(-1, keepdims=True) * c1)
    return np.stack([c1, c2, np.cross(c1, c2)], axis=-1)


def matrix_to_sixd(R):
    """Rotation matrices (..., 3, 3) -> 6-D representation (..., 6): the first two columns,
    numpy or torch (Zhou et al. 2019)."""
    R = _check(R, (3, 3), "matrix_to_sixd", "rotation matrices", torch_ok=True)
    if _is_torch(R):
        import torch
        return torch.cat([R[..., :, 0], R[..., :, 1]], dim=-1)
    return np.concatenate([R[..., :, 0], R[..., :, 1]], axis=-1)


# --------------------------------------------------------------------------- matrices

def project_to_so3(M):
    """Nearest rotations (..., 3, 3) to matrices M (..., 3, 3) in the Frobenius norm (SVD,
    ``U diag(1, 1, sign det(U Vh)) Vh``), numpy or torch."""
    M = _check(M, (3, 3), "project_to_so3", "matrices", torch_ok=True)
    if _is_torch(M):
        import torch
        U, _, Vh = torch.linalg.svd(M)
        d = torch.sign(torch.det(U @ Vh))
        D = torch.diag_embed(torch.stack([torch.ones_like(d), torch.ones_like(d), d], dim=-1))
        return U @ D @ Vh
    U, _, Vh = np.linalg.svd(M)
    d = np.sign(np.linalg.det(U @ Vh))
    D = np.zeros(d.shape + (3, 3))
    D[..., 0, 0] = D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    return U @ D @ Vh


def geodesic(R1, R2) -> np.ndarray:
    """Angle (radians, in [0, pi]) of the rotation taking R1 to R2, for broadcastable batches (..., 3, 3):
    arccos((trace(R1^T R2) - 1) / 2), the cosine clipped to [-1, 1]."""
    R1 = _check(R1, (3, 3), "geodesic", "R1")
    R2 = _check(R2, (3, 3), "geodesic", "R2")
    tr = np.einsum("...ji,...ji->...", R1, R2)          # trace(R1^T R2)
    return np.arccos(np.clip((tr - 1.0) / 2.0, -1.0, 1.0))


def geodesic_deg(R1, R2) -> np.ndarray:
    """Angle (degrees, in [0, 180]) of the rotation taking R1 to R2 (see :func:`geodesic`)."""
    return np.degrees(geodesic(R1, R2))


def symmetric_pose_error_deg(R_pred, R_true, order: int) -> np.ndarray:
    """Geodesic error (degrees) modulo ``order``-fold turns of the object about its up axis (+z):
    min over k of angle(R_pred, R_true @ Rz(2 pi k / order)); ``order`` <= 1: the plain geodesic
    error. The evaluation's symmetric pose metric (orders: :data:`hbeo.conventions.UP_SYMMETRY`)."""
    errs = []
    for k in range(max(1, order)):
        Rz = z_angle_to_matrix(2 * np.pi * k / max(1, order))
        errs.append(geodesic_deg(R_pred, R_true @ Rz))
    return np.min(errs, axis=0)


def check_rotation_matrices(R, name: str = "R") -> np.ndarray:
    """``R`` as float64 (same shape), checked to hold rotation matrices: orthonormal (max
    |R^T R - I|) with determinant +1, both within :data:`ROTATION_TOL`. One matrix (3, 3) or a
    batch (..., 3, 3); ValueError naming the first bad one (``name`` or ``name[i]``, flat index)
    with its error and determinant. Shape and finiteness are the caller's to check first (their
    messages name the caller's arguments)."""
    R = _check(R, (3, 3), "check_rotation_matrices", name)
    flat = R.reshape(-1, 3, 3)
    if not len(flat):
        return R
    err = np.abs(np.einsum("nji,njk->nik", flat, flat) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(flat)
    bad = np.nonzero((err > ROTATION_TOL) | (np.abs(det - 1.0) > ROTATION_TOL))[0]
    if len(bad):
        i = int(bad[0])
        who = name if R.ndim == 2 else f"{name}[{i}]"
        raise ValueError(f"{who} is not a rotation matrix (|R^T R - I| = {err[i]:.2g}, det = {det[i]:.6g}; "
                         f"need orthonormal with det +1 within {ROTATION_TOL:g})")
    return R


# --------------------------------------------------------------------------- elementary rotations

def z_angle_to_matrix(angle) -> np.ndarray:
    """Rotations (..., 3, 3) by ``angle`` (...) radians about +z (positive: +x turns toward +y).

    About the object's up axis this is a yaw; about the camera's optical axis, a roll."""
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


def x_angle_to_matrix(angle) -> np.ndarray:
    """Rotations (..., 3, 3) by ``angle`` (...) radians about +x (positive: +y turns toward +z)."""
    a = np.asarray(angle, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    R[..., 0, 0], R[..., 1, 1], R[..., 1, 2], R[..., 2, 1], R[..., 2, 2] = 1.0, c, -s, s, c
    return R


def yaw_elevation_to_matrix(yaw, elevation) -> np.ndarray:
    """Rotations (..., 3, 3) for a camera without roll looking down at ``elevation`` (radians) on
    an object turned by ``yaw`` (radians) about its up axis (+z); yaw and elevation broadcast.
    At yaw 0 the camera sits on the object's -y side, facing its front:
    ``R = E(elevation) @ Rz(yaw)``, E with rows camera right (1, 0, 0), camera down
    (0, -sin e, -cos e), camera forward (0, cos e, -sin e) in object axes."""
    yaw, elevation = np.broadcast_arrays(np.asarray(yaw, np.float64), np.asarray(elevation, np.float64))
    lead = yaw.shape
    yaw, elevation = yaw.reshape(-1), elevation.reshape(-1)
    ce, se = np.cos(elevation), np.sin(elevation)
    zeros, ones = np.zeros_like(ce), np.ones_like(ce)
    x = np.stack([ones, zeros, zeros], -1)             # camera right, object axes
    y = np.stack([zeros, -se, -ce], -1)                # camera down
    f = np.stack([zeros, ce, -se], -1)                 # camera forward
    R_cw = np.stack([x, y, f], axis=1)                 # object -> camera, before the yaw
    return (R_cw @ z_angle_to_matrix(yaw)).reshape(lead + (3, 3))


def yaw_elevation_roll_to_matrix(yaw, elevation, roll) -> np.ndarray:
    """Rotations (..., 3, 3) of the 3-DOF order of a view (module docstring):
    ``R = Rz(roll) @ E(elevation) @ Rz(yaw)``, radians, broadcast against each other: the object
    turns by ``yaw`` about its up axis (+z), a camera without roll looks down at it from
    ``elevation`` above its horizon (:func:`yaw_elevation_to_matrix`; negative: from below), and
    the camera last rolls by ``roll`` about its optical axis (:func:`z_angle_to_matrix` in the
    camera frame). The camera looks along ``R.T @ (0, 0, 1)`` = (sin(yaw) cos(e), cos(yaw) cos(e),
    -sin(e)) in object axes, whatever the roll."""
    yaw, elevation, roll = np.broadcast_arrays(np.asarray(yaw, np.float64), np.asarray(elevation, np.float64),
                                               np.asarray(roll, np.float64))
    return z_angle_to_matrix(roll) @ yaw_elevation_to_matrix(yaw, elevation)


def direction_to_matrix(direction) -> np.ndarray:
    """The smallest rotations Q (..., 3, 3) taking +z to ``direction`` (..., 3) (any nonzero
    length; no twist about it). For +z itself the identity, for -z a half turn about +x."""
    d = _check(direction, (3,), "direction_to_matrix", "direction")
    out = np.empty(d.shape[:-1] + (3, 3))
    for i in np.ndindex(d.shape[:-1]):      # one vector at a time: np.linalg.norm of a vector
        out[i] = _direction_to_matrix(d[i])  # rounds differently from the batched form
    return out


def _direction_to_matrix(z: np.ndarray) -> np.ndarray:
    z = z / np.linalg.norm(z)
    axis = np.cross([0.0, 0.0, 1.0], z)
    s, c = np.linalg.norm(axis), z[2]
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / s
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + s * Kx + (1 - c) * Kx @ Kx


def view_deg_to_matrix(azim_deg, elev_deg) -> np.ndarray:
    """Rotations (..., 3, 3) from object axes to a *picture* frame (x right, y up, z toward the
    viewer; not the OpenCV camera) for a viewer at azimuth ``azim_deg`` (degrees about +z, from +x
    toward +y) and elevation ``elev_deg`` (degrees above the xy plane), matplotlib-style; the
    object's +z points up in the picture. Rows: picture right, up, toward the viewer."""
    a, e = np.broadcast_arrays(np.radians(azim_deg), np.radians(elev_deg))
    toward = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1)
    right = np.stack([-np.sin(a), np.cos(a), np.zeros_like(a)], -1)
    up = np.cross(toward, right)
    return np.stack([right, up, toward], axis=-2)
