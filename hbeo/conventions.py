"""The project's conventions, in one place.

Everything that fixes a frame, a grid layout or a name lives here and is imported
from here; ``docs/method.md`` ("Conventions") documents the same facts.

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

Camera
    Pinhole, OpenCV axes: x right, y down, z forward (out of the lens). Pixel (u, v) =
    (column, row); integer coordinates are pixel centres. Intrinsics (fx, fy, cx, cy) in
    pixels; default Kinect-like: f = 525 px at 640x480, scaled with the image size.
    Depth images hold the z coordinate (along the optical axis) of the surface seen at
    each pixel, in metres; 0 means "no object".

Pose
    The rotation R (3x3) takes the canonical object frame to the camera frame; with the
    translation t (metres, camera frame), a point x of the object (metres, origin at the
    centre of its bounding box) is seen at ``R @ x + t``. Encoded as the paper's 3-element
    axis-angle vector (rotation vector: axis * angle, radians). Pose errors are geodesic
    angles in degrees. Every rotation is built and converted by :mod:`hbeo.rotations`.

Rendering scale
    Before rendering, a mesh is centred on its bounding-box centre (the grid's centre) and
    scaled so its longest side is ``object_size`` metres, so grid, mesh and depth share
    one frame up to that scale.

Grid coordinates
    Continuous grid coordinates ``u`` in [0, 30)^3: voxel (i, j, k) covers
    [i, i+1) x [j, j+1) x [k, k+1); its centre is (i+0.5, j+0.5, k+0.5).
    ``u = (x - center) * scale + RESOLUTION / 2`` with ``scale = OBJECT_VOXELS /
    longest_side`` (voxels per object unit) and ``RESOLUTION / 2`` = 15.

Imports numpy only; nothing from hbeo.
"""
from __future__ import annotations

from dataclasses import dataclass

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
UP_AXIS = 2              #: +z is up in the canonical frame


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


# --------------------------------------------------------------------------- camera

#: Kinect-like reference camera: f = 525 px at 640 x 480.
KINECT_F, KINECT_SIZE = 525.0, (640, 480)


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels, OpenCV convention (integer pixel coordinates are centres)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    def __post_init__(self):
        if int(self.width) < 1 or int(self.height) < 1:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(np.isfinite(v) for v in vals) or self.fx <= 0 or self.fy <= 0:
            raise ValueError(f"intrinsics need finite fx, fy > 0 and finite cx, cy; got {vals}")

    @classmethod
    def kinect(cls, width: int = 320, height: int = 240) -> "Intrinsics":
        """The default camera: Kinect-like, square pixels with f = 525 px per 640 px of image
        width (the Kinect's horizontal field of view, 62.7 degrees), principal point at the centre."""
        f = KINECT_F * width / KINECT_SIZE[0]
        return cls(f, f, (width - 1) / 2.0, (height - 1) / 2.0, int(width), int(height))

    @property
    def K(self) -> np.ndarray:
        """The 3x3 camera matrix."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def as_tuple(self) -> tuple:
        return (self.fx, self.fy, self.cx, self.cy, self.width, self.height)


def project(points: np.ndarray, K: Intrinsics) -> np.ndarray:
    """Camera-frame points (N, 3), metres -> pixel coordinates and depth (N, 3): (u, v, z)."""
    p = np.asarray(points, dtype=np.float64)
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = K.fx * p[:, 0] / z + K.cx
        v = K.fy * p[:, 1] / z + K.cy
    return np.stack([u, v, z], axis=1)


def backproject(depth: np.ndarray, K: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """Depth image (H, W), metres, 0 = none -> (camera-frame points (N, 3), their (row, col) (N, 2)).

    Inverse of :func:`project` at the pixel centres of all pixels with depth > 0.
    """
    depth = np.asarray(depth)
    if depth.shape != (K.height, K.width):
        raise ValueError(f"depth image is {depth.shape[1]}x{depth.shape[0]}, intrinsics are for "
                         f"{K.width}x{K.height}")
    rows, cols = np.nonzero(depth > 0)
    z = depth[rows, cols].astype(np.float64)
    x = (cols - K.cx) * z / K.fx
    y = (rows - K.cy) * z / K.fy
    return np.stack([x, y, z], axis=1), np.stack([rows, cols], axis=1)


def subsample_points(points: np.ndarray, n: int, rng, keep_order: bool = False) -> np.ndarray:
    """At most ``n`` of ``points`` (N, ...): all of them when N <= n, else ``n`` drawn without
    replacement by ``rng`` (a numpy Generator, or an int seed), in drawn order or, with
    ``keep_order``, in their original order. The one way hbeo thins a point cloud."""
    points = np.asarray(points)
    if len(points) <= n:
        return points
    idx = np.random.default_rng(rng).choice(len(points), n, replace=False)
    return points[np.sort(idx) if keep_order else idx]


# --------------------------------------------------------------------------- pose

#: Near-symmetries of the classes: order n of turns by 360/n degrees about the object's up
#: axis (+z) that leave the class's typical shape nearly unchanged (tables: 90 degrees; desks,
#: dressers, night stands, bathtubs: 180). Used for the symmetry-aware pose error only; the
#: paper's metric is the raw geodesic error.
UP_SYMMETRY: dict[str, int] = {"bathtub": 2, "desk": 2, "dresser": 2, "night_stand": 2, "table": 4}
