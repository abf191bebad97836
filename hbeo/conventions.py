"""The project's conventions, in one place.

Everything that fixes a frame, a grid layout or a name lives here and is imported
from here; the README's "Conventions" section documents the same facts.

Canonical object frame
    ModelNet's own per-class alignment: right-handed, +z up. ModelNet aligns objects
    within a class, not across classes: chairs, beds and toilets have their back
    toward +y, sofas toward +x. Units are whatever the mesh file uses (ModelNet is
    not normalized); the grid removes scale.

Grid layout (3D ShapeNets, Wu et al. 2015)
    A solid occupancy grid of shape (30, 30, 30), indexed ``grid[i, j, k]`` with
    i, j, k along the object's x, y, z axes. The object is scaled uniformly so that
    the longest side of its bounding box (over all vertices in the file) spans
    ``OBJECT_VOXELS`` = 24 voxels, and centred, leaving ``MARGIN`` = 3 empty voxels
    on each side of the longest axis: occupied indices along that axis run 3..26.
    Surfaces are voxelized and then every cavity closed to the outside is filled;
    open basins (a bathtub's tub, a cup) stay empty, as in the original data.

Grid coordinates
    Continuous grid coordinates ``u`` in [0, 30)^3: voxel (i, j, k) covers
    [i, i+1) x [j, j+1) x [k, k+1); its centre is (i+0.5, j+0.5, k+0.5).
    ``u = (x - center) * scale + GRID_CENTER`` with ``scale = OBJECT_VOXELS /
    longest_side`` (voxels per object unit) and ``GRID_CENTER`` = 15.
"""
from __future__ import annotations

import numpy as np

#: ModelNet10 class names, in the index order of the 3D ShapeNets / VoxNet grids.
CLASSES: tuple[str, ...] = (
    "bathtub", "bed", "chair", "desk", "dresser",
    "monitor", "night_stand", "sofa", "table", "toilet",
)
SPLITS: tuple[str, ...] = ("train", "test")

RESOLUTION = 30          #: voxels per side of the grid
OBJECT_VOXELS = 24       #: voxels spanned by the longest side of the object
MARGIN = (RESOLUTION - OBJECT_VOXELS) // 2   #: empty voxels each side of the longest axis (3)
GRID_CENTER = RESOLUTION / 2.0               #: grid coordinate of the object's bbox centre (15.0)
UP_AXIS = 2              #: +z is up in the canonical frame
GRID_DTYPE = np.bool_    #: occupancy grids are boolean in memory, uint8 on disk


def class_index(name: str) -> int:
    """Index of a ModelNet10 class name in :data:`CLASSES` (ValueError if unknown)."""
    try:
        return CLASSES.index(name)
    except ValueError:
        raise ValueError(f"unknown class {name!r}; expected one of {', '.join(CLASSES)}") from None


def grid_transform(vertices: np.ndarray, resolution: int = RESOLUTION):
    """Centre and scale taking object coordinates to continuous grid coordinates.

    vertices: (N, 3) float, object frame, any unit; the bounding box over *all*
    of them is used (as 3D ShapeNets did, unused vertices in the file included).
    Returns ``(center (3,), scale)`` with ``u = (x - center) * scale + resolution / 2``;
    scale is in voxels per object unit. The longest side spans
    ``resolution * OBJECT_VOXELS / RESOLUTION`` voxels.
    """
    v = np.asarray(vertices, dtype=np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    longest = float((hi - lo).max())
    if not np.isfinite(longest) or longest <= 0:
        raise ValueError("degenerate bounding box (all vertices coincide or are not finite)")
    span = resolution * OBJECT_VOXELS / RESOLUTION
    return (lo + hi) / 2.0, span / longest


def object_to_grid(points: np.ndarray, center: np.ndarray, scale: float,
                   resolution: int = RESOLUTION) -> np.ndarray:
    """Object-frame points (N, 3) -> continuous grid coordinates (N, 3), in voxels."""
    return (np.asarray(points, dtype=np.float64) - center) * scale + resolution / 2.0


def grid_to_object(u: np.ndarray, center: np.ndarray, scale: float,
                   resolution: int = RESOLUTION) -> np.ndarray:
    """Continuous grid coordinates (N, 3) -> object-frame points (N, 3); inverse of :func:`object_to_grid`.

    Voxel centres are ``index + 0.5``.
    """
    return (np.asarray(u, dtype=np.float64) - resolution / 2.0) / scale + center


def voxel_centers(resolution: int = RESOLUTION) -> np.ndarray:
    """Grid coordinates of all voxel centres, shape (R, R, R, 3), same index order as grids."""
    c = np.arange(resolution) + 0.5
    return np.stack(np.meshgrid(c, c, c, indexing="ij"), axis=-1)
