"""Depth images of meshes: mesh preparation and two rendering backends.

Owns :class:`Renderer`, :func:`prepare_mesh` / :func:`grid_field` / :func:`grid_mesh` / :func:`record_mesh` and the
choice of backend and OpenGL platform; the sensor-noise model is :mod:`hbeo.render.noise`.
Imports the foundation and :mod:`hbeo.data.meshio` only.

Units and frames (see :mod:`hbeo.conventions`)
    Meshes handed to :class:`Renderer` are *prepared* (:func:`prepare_mesh`, :func:`grid_mesh`):
    metres, centred on the centre of their bounding box (the 30^3 grid's centre), longest side
    ``object_size``. A pose (R, t) puts object point x at ``R @ x + t`` in the camera frame
    (OpenCV axes: x right, y down, z forward). A depth image is float32 (H, W): the camera-frame
    z of the surface seen through each pixel *centre* (integer pixel coordinates), metres;
    0 where the ray misses the object.

Backends
    ``embree``   ray casting (embreex): one ray per pixel centre, first hit. Fast on CPUs.
    ``pyrender`` OpenGL rasterization, headless (EGL where an EGL device works, else OSMesa).
    Both sample the same pixel centres: masks agree except where a pixel centre lies within
    floating-point tolerance of a silhouette edge, and depths agree to ~1e-6 relative.
    ``backend="auto"`` picks embree when importable, else pyrender (optional:
    :func:`pyrender_available`); the environment variable
    ``HBEO_RENDER_BACKEND`` overrides "auto", ``HBEO_GL_PLATFORM`` (``egl`` / ``osmesa``) the
    OpenGL platform.
"""
from __future__ import annotations

import contextlib
import functools
import importlib.util
import os
import subprocess
import sys

import numpy as np
import trimesh

from hbeo import conventions as C
from hbeo.errors import DataError
from hbeo.data.meshio import check_mesh
from hbeo.rotations import check_rotation_matrices

BACKENDS = ("embree", "pyrender")
GL_PLATFORMS = ("egl", "osmesa")

# ----------------------------------------------------------------------------- meshes


def _mesh_name(mesh):
    meta = getattr(mesh, "metadata", None) or {}
    return meta.get("file") or meta.get("name") or meta.get("id")


def _check_size(object_size) -> float:
    s = float(object_size)
    if not np.isfinite(s) or s <= 0:
        raise ValueError(f"object_size must be a positive number of metres, got {object_size!r}")
    return s


def prepare_mesh(mesh: trimesh.Trimesh, object_size: float = 1.0) -> trimesh.Trimesh:
    """Copy of ``mesh`` in the rendering frame: centred on the centre of the bounding box of
    *all* its vertices (as :func:`hbeo.conventions.grid_transform`), scaled uniformly so the
    longest side is ``object_size`` metres. Vertices (V, 3) float64, faces (F, 3) as given.

    Raises :class:`DataError` (naming the mesh's file) for empty, degenerate or non-finite meshes.
    """
    size = _check_size(object_size)
    name = _mesh_name(mesh)
    v, f = check_mesh(getattr(mesh, "vertices", np.zeros((0, 3))), getattr(mesh, "faces", np.zeros((0, 3))), name)
    center, scale = C.grid_transform(v)
    k = scale * size / C.OBJECT_VOXELS          # metres per file unit
    meta = dict(getattr(mesh, "metadata", {}) or {})
    meta.update(object_size=size)
    return trimesh.Trimesh((v - center) * k, f.copy(), process=False, validate=False, metadata=meta)


def _constrained_smooth(occ: np.ndarray, sigma: float, iterations: int = 12, margin: float = 0.05):
    """Gaussian smoothing of a 0/1 field that keeps every occupied voxel centre above 0.5 and
    every empty one below it, so thin walls and rods survive and the 0.5 level set lies
    between the same voxel centres as the blocky surface."""
    from scipy import ndimage
    f = occ.astype(np.float32)
    if sigma <= 0:
        return f
    lo = np.where(occ, 0.5 + margin, 0.0).astype(np.float32)
    hi = np.where(occ, 1.0, 0.5 - margin).astype(np.float32)
    for _ in range(iterations):
        f = ndimage.gaussian_filter(f, sigma, mode="constant")
        np.clip(f, lo, hi, out=f)
    return f


def grid_field(grid: np.ndarray, smooth: float = 1.0) -> np.ndarray:
    """The occupancy field whose 0.5 level set is a grid's surface (:func:`grid_mesh` triangulates it,
    :mod:`hbeo.render.gridcast` ray-marches it): float32 (R+2, R+2, R+2), the grid (R, R, R) padded by
    one empty voxel on each side and smoothed by :func:`_constrained_smooth` with ``sigma = smooth``
    voxels. Padded index p lies at grid coordinate ``u = p - 0.5`` (:mod:`hbeo.conventions`).
    ValueError for a grid that is not cubic, DataError (a ValueError) for an empty one."""
    g = np.asarray(grid)
    if g.ndim != 3 or len(set(g.shape)) != 1 or g.shape[0] < 2:
        raise ValueError(f"grid must be a cubic (R, R, R) array, got shape {g.shape}")
    occ = g.astype(bool)
    if not occ.any():
        raise DataError(None, "empty occupancy grid (no occupied voxel); nothing to mesh")
    return _constrained_smooth(np.pad(occ, 1), float(smooth))


def grid_mesh(grid: np.ndarray, object_size: float = 1.0, smooth: float = 1.0) -> trimesh.Trimesh:
    """Surface mesh (metres, rendering frame of :func:`prepare_mesh`) of an occupancy grid
    (R, R, R), normally 30^3 in the :mod:`hbeo.conventions` layout.

    Marching cubes at level 0.5 on the grid padded by one voxel and Gaussian-smoothed with
    ``sigma = smooth`` voxels. The smoothing is *constrained*: after each pass, occupied voxel
    centres are held at >= 0.55 and empty ones at <= 0.45, so walls and legs one voxel thick
    do not vanish and the surface stays within half a voxel of the blocky one (plain
    smoothing at sigma 1 drops a one-voxel wall to 0.38). ``smooth=0``: blocky surface.
    Grid coordinate u (voxel centre i + 0.5) maps to ``(u - R/2) / (0.8 R) * object_size``.
    """
    from skimage import measure
    size = _check_size(object_size)
    f = grid_field(grid, smooth)
    res = f.shape[0] - 2
    verts, faces, _, _ = measure.marching_cubes(f, level=0.5, allow_degenerate=False)
    u = verts.astype(np.float64) - 1.0 + 0.5             # padded index -> grid coordinate
    span = res * C.OBJECT_VOXELS / C.RESOLUTION          # voxels spanned by object_size
    x = (u - res / 2.0) / span * size
    # marching_cubes winds its triangles inward for a field that is high inside: flip them
    return trimesh.Trimesh(x, faces[:, ::-1].astype(np.int64), process=False, validate=False,
                           metadata={"name": "grid_mesh", "object_size": size})


def record_mesh(record, object_size: float = 1.0) -> trimesh.Trimesh:
    """Prepared mesh of a dataset record (:class:`hbeo.data.datasets.ObjectRecord`): its mesh when it
    has one, else a surface of its grid."""
    if record.has_mesh:
        mesh = record.mesh()
        if mesh is not None and not (getattr(mesh, "metadata", {}) or {}).get("file"):
            mesh.metadata.setdefault("name", getattr(record, "id", None))
        return prepare_mesh(mesh, object_size)
    if record.has_grid:
        try:
            m = grid_mesh(record.grid(), object_size)
        except DataError as err:
            raise DataError(getattr(record, "path", None) or record.id, err.problem) from None
        m.metadata["name"] = record.id
        return m
    raise DataError(getattr(record, "path", None) or record.id, "record has neither a mesh nor a grid")


# ----------------------------------------------------------------------------- backends

def embree_available() -> bool:
    try:
        import embreex  # noqa: F401
        from embreex import rtcore_scene  # noqa: F401
        return True
    except (ImportError, OSError):
        return False


@functools.lru_cache(maxsize=None)
def pyrender_available() -> bool:
    """Whether pyrender is installed and imports here. Asked of a child process, once: importing
    pyrender here would load OpenGL before :func:`gl_platform` has chosen its platform."""
    if importlib.util.find_spec("pyrender") is None:
        return False
    try:
        res = subprocess.run([sys.executable, "-c", "import pyrender"], capture_output=True, timeout=120, check=False)
    except (OSError, subprocess.SubprocessError):
        return False
    return res.returncode == 0


def _load_triton_first() -> None:
    """Import Triton, where it is installed, before pyrender loads OpenGL. Mesa's software OpenGL (llvmpipe)
    and Triton each bring an LLVM; loaded after Mesa's, Triton's segfaults on import, and torch imports it
    with its first optimizer (``torch._dynamo``): rendering with pyrender, then training in one process,
    crashed. Loaded first, both work."""
    if importlib.util.find_spec("triton") is None:
        return
    try:
        import triton  # noqa: F401
    except Exception:                                   # a Triton that cannot load here: torch will not use it
        pass


def _import_pyrender():
    """pyrender, or a RuntimeError that says why it cannot be used here (Triton loaded first:
    :func:`_load_triton_first`)."""
    _load_triton_first()
    try:
        import pyrender
    except (ImportError, AttributeError) as err:     # AttributeError: a numpy name a pyrender release lacks
        raise RuntimeError(f"render backend 'pyrender' cannot import pyrender here ({type(err).__name__}: {err}); "
                           f"install it (pip install --no-deps -r requirements-nodeps.txt) or use the embree "
                           f"backend (pip install embreex)") from err
    return pyrender


def _egl_works() -> bool:
    """Whether pyrender can open its EGL context here (EGL device ``EGL_DEVICE_ID``, default 0).

    A probe because no library answers this: pyrender only reads ``PYOPENGL_PLATFORM`` and
    PyOpenGL fixes its platform when OpenGL is first imported, so a failed EGL attempt cannot
    fall back to OSMesa in the same process. The child process does exactly what
    :class:`Renderer` will do (a crash of a broken driver cannot take this process down).
    """
    code = "import pyrender; pyrender.OffscreenRenderer(8, 8).delete()"
    env = {**os.environ, "PYOPENGL_PLATFORM": "egl"}
    try:
        res = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, timeout=120, check=False)
    except (OSError, subprocess.SubprocessError):
        return False
    return res.returncode == 0


def gl_platform() -> str:
    """The headless OpenGL platform pyrender uses in this process ("egl" or "osmesa"), chosen
    once: ``HBEO_GL_PLATFORM`` if set, else an already set ``PYOPENGL_PLATFORM``, else egl when
    an EGL device works, else osmesa. Exported to ``PYOPENGL_PLATFORM`` (child processes inherit it)."""
    want = os.environ.get("HBEO_GL_PLATFORM", "").strip().lower()
    if want and want not in GL_PLATFORMS:
        raise ValueError(f"HBEO_GL_PLATFORM={want!r}; expected one of {', '.join(GL_PLATFORMS)}")
    current = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
    if want:
        if current and current != want and "OpenGL.GL" in sys.modules:
            raise RuntimeError(f"OpenGL was already loaded with PYOPENGL_PLATFORM={current}; "
                               f"HBEO_GL_PLATFORM={want} must be set before anything imports OpenGL")
        plat = want
    elif current in GL_PLATFORMS:
        plat = current
    else:
        plat = "egl" if _egl_works() else "osmesa"
    os.environ["PYOPENGL_PLATFORM"] = plat
    return plat


def resolve_backend(backend: str = "auto") -> str:
    """"auto" -> ``HBEO_RENDER_BACKEND`` if set, else "embree" when importable, else "pyrender"."""
    b = (backend or "auto").strip().lower()
    if b == "auto":
        b = os.environ.get("HBEO_RENDER_BACKEND", "").strip().lower() or (
            "embree" if embree_available() else "pyrender")
    if b not in BACKENDS:
        raise ValueError(f"unknown render backend {b!r}; expected one of auto, {', '.join(BACKENDS)}")
    if b == "embree" and not embree_available():
        raise RuntimeError("render backend 'embree' needs the embreex package (pip install embreex)")
    return b


class _MeshInfo:
    """What a renderer keeps per mesh: bounding sphere, projection hull, backend handle."""

    def __init__(self, mesh):
        v, f = check_mesh(mesh.vertices, mesh.faces, _mesh_name(mesh))
        mask = np.zeros(len(v), dtype=bool)
        mask[f.ravel()] = True
        used = v[mask]
        lo, hi = used.min(axis=0), used.max(axis=0)
        self.center = (lo + hi) / 2.0
        self.radius = float(np.sqrt(((used - self.center) ** 2).sum(axis=1).max()))
        # points whose projection bounds the object's image: the bbox corners, then (once the
        # mesh has been rendered often enough to pay for it) the convex hull's vertices
        self.used = used
        self.corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                 for z in (lo[2], hi[2])])
        self.hull = None
        self.views = 0
        # zero-area faces show nothing, but a rasterizer snapping one onto a pixel centre writes
        # a depth extrapolated from its (undefined) plane: leave them out
        a = v[f[:, 0]]
        b, c = v[f[:, 1]] - a, v[f[:, 2]] - a
        area2 = ((b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1]) ** 2 + (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2]) ** 2
                 + (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]) ** 2)        # (2 * area)^2, no np.cross (slow)
        keep = area2 > 1e-24 * max(self.radius, 1e-300) ** 4
        self.vertices, self.faces = v, (f[keep] if keep.any() else f)
        self.handle = None


def _check_poses(Rs, ts):
    Rs = np.asarray(Rs, dtype=np.float64)
    ts = np.asarray(ts, dtype=np.float64)
    if Rs.ndim != 3 or Rs.shape[1:] != (3, 3):
        raise ValueError(f"rotations must have shape (N, 3, 3), got {Rs.shape}")
    if ts.ndim != 2 or ts.shape[1:] != (3,):
        raise ValueError(f"translations must have shape (N, 3), got {ts.shape}")
    if len(Rs) != len(ts):
        raise ValueError(f"{len(Rs)} rotations but {len(ts)} translations")
    if not (np.isfinite(Rs).all() and np.isfinite(ts).all()):
        raise ValueError("pose contains NaN or infinity")
    return check_rotation_matrices(Rs), ts


def _delete_offscreen(offscreen):
    """Free a pyrender OffscreenRenderer. With EGL, pyrender's own ``delete`` calls eglTerminate
    on the device's display, which every context in the process shares: it would break the
    other renderers. Destroy only this context and leave the display initialized."""
    plat = getattr(offscreen, "_platform", None)
    if plat is None or not hasattr(plat, "_egl_context"):
        offscreen.delete()
        return
    try:
        plat.make_current()
        offscreen._renderer.delete()
    finally:
        from OpenGL.EGL import (
            EGL_NO_CONTEXT,
            EGL_NO_SURFACE,
            eglDestroyContext,
            eglMakeCurrent,
        )
        if plat._egl_display is not None and plat._egl_context is not None:
            eglMakeCurrent(plat._egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
            eglDestroyContext(plat._egl_display, plat._egl_context)
        plat._egl_context = plat._egl_display = None


class Renderer:
    """Depth renderer for one camera. ``Renderer(intrinsics, backend="auto")``.

    Keeps per-mesh state (embree BVH / OpenGL buffers) for the last mesh rendered, so call
    :meth:`render_many` (or :meth:`render` repeatedly) with one mesh at a time. Picklable:
    a copy in another process rebuilds its state lazily. Use ``with Renderer(K) as r:`` or
    :meth:`close` to free OpenGL resources.
    """

    #: objects must lie entirely beyond this depth (metres)
    znear = 0.01
    _HULL_AFTER = 32   # views of one mesh after which a convex hull tightens the ray box

    def __init__(self, intrinsics: C.Intrinsics, backend: str = "auto"):
        if not isinstance(intrinsics, C.Intrinsics):
            raise TypeError(f"intrinsics must be hbeo.conventions.Intrinsics, got {type(intrinsics).__name__}")
        self.intrinsics = intrinsics
        self.backend = resolve_backend(backend)
        self._reset()

    def _reset(self):
        self._mesh = None          # the mesh object the cached state belongs to
        self._mesh_key = None
        self._info = None
        self._dirs = None          # embree: per-column x and per-row y of camera rays (z = 1)
        self._gl = None            # pyrender: (OffscreenRenderer, Scene, camera, mesh node)

    # -- pickling / lifetime
    def __getstate__(self):
        return {"intrinsics": self.intrinsics, "backend": self.backend}

    def __setstate__(self, state):
        self.intrinsics, self.backend = state["intrinsics"], state["backend"]
        self._reset()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        with contextlib.suppress(Exception):     # interpreter shutdown: OpenGL may be gone
            self.close()

    def close(self):
        """Free backend resources (the OpenGL context); the renderer can still be used after."""
        gl = getattr(self, "_gl", None)
        if gl is not None:
            self._gl = None
            _delete_offscreen(gl[0])
        if getattr(self, "_info", None) is not None:
            self._info.handle = None
        self._mesh = self._mesh_key = self._info = None

    def __repr__(self):
        K = self.intrinsics
        return f"<Renderer {self.backend} {K.width}x{K.height} f=({K.fx:g}, {K.fy:g})>"

    # -- public
    def render(self, mesh: trimesh.Trimesh, R: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Depth (H, W) float32, metres, 0 = no object, of a prepared mesh at pose R (3, 3), t (3,)."""
        R, t = np.asarray(R, dtype=np.float64), np.asarray(t, dtype=np.float64)
        if R.shape != (3, 3):
            raise ValueError(f"R must have shape (3, 3), got {R.shape}")
        if t.shape != (3,):
            raise ValueError(f"t must have shape (3,), got {t.shape}")
        return self.render_many(mesh, R[None], t[None])[0]

    def render_many(self, mesh: trimesh.Trimesh, Rs: np.ndarray, ts: np.ndarray) -> np.ndarray:
        """Depths (N, H, W) float32 of one prepared mesh at poses Rs (N, 3, 3), ts (N, 3)."""
        Rs, ts = _check_poses(Rs, ts)
        info = self._prepare(mesh)
        zc = (Rs @ info.center + ts)[:, 2]
        bad = np.nonzero(zc - info.radius <= self.znear)[0]
        if len(bad):
            i = int(bad[0])
            where = "behind the camera" if zc[i] + info.radius <= 0 else "intersecting the near plane"
            raise ValueError(f"pose {i}: object {where} (bounding sphere centre at z = {zc[i]:.3g} m, "
                             f"radius {info.radius:.3g} m; it must lie beyond z = {self.znear} m)")
        K = self.intrinsics
        out = np.zeros((len(Rs), K.height, K.width), dtype=np.float32)
        if len(Rs):
            (self._render_embree if self.backend == "embree" else self._render_gl)(info, Rs, ts, zc, out)
        return out

    # -- per-mesh state
    def _prepare(self, mesh) -> _MeshInfo:
        if not isinstance(mesh, trimesh.Trimesh):
            raise TypeError(f"mesh must be a trimesh.Trimesh, got {type(mesh).__name__}")
        key = hash(mesh)   # trimesh hashes its data (cached until modified)
        if mesh is self._mesh and key == self._mesh_key:
            return self._info
        info = _MeshInfo(mesh)
        if self._info is not None:
            self._info.handle = None
        self._mesh, self._mesh_key, self._info = mesh, key, info
        return info

    def _pixel_box(self, info, R, t):
        """Rows/columns (v0, v1, u0, u1) of the image rectangle that can contain the object."""
        K = self.intrinsics
        info.views += 1
        if info.hull is None and info.views > self._HULL_AFTER:
            from scipy.spatial import ConvexHull, QhullError
            try:
                info.hull = info.used[ConvexHull(info.used).vertices]
            except (QhullError, ValueError):            # flat or tiny meshes: keep the corners
                info.hull = info.corners
        uvz = C.project((info.corners if info.hull is None else info.hull) @ R.T + t, K)
        u0 = max(0, int(np.floor(uvz[:, 0].min())))
        u1 = min(K.width, int(np.ceil(uvz[:, 0].max())) + 1)
        v0 = max(0, int(np.floor(uvz[:, 1].min())))
        v1 = min(K.height, int(np.ceil(uvz[:, 1].max())) + 1)
        return v0, v1, u0, u1

    # -- embree
    def _render_embree(self, info, Rs, ts, zc, out):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh
        K = self.intrinsics
        if self._dirs is None:     # camera-frame ray direction through pixel (u, v): (xs[u], ys[v], 1)
            self._dirs = ((np.arange(K.width) - K.cx) / K.fx).astype(np.float32), \
                         ((np.arange(K.height) - K.cy) / K.fy).astype(np.float32)
        xs_all, ys_all = self._dirs
        if info.handle is None:
            scene = rtcore_scene.EmbreeScene()
            # vertices relative to the bounding-box centre: float32 keeps ~1e-7 relative precision
            TriangleMesh(scene=scene, vertices=(info.vertices - info.center).astype(np.float32),
                         indices=info.faces.astype(np.int32))
            info.handle = scene
        scene = info.handle
        for i in range(len(Rs)):
            R, t = Rs[i], ts[i]
            v0, v1, u0, u1 = self._pixel_box(info, R, t)
            if v0 >= v1 or u0 >= u1:
                continue
            # camera-frame ray (origin 0, direction d with d_z = 1) in the object frame relative to
            # the bbox centre c: origin R^T (0 - t) - c, direction R^T d, so the hit parameter is
            # the camera-frame z of the hit. R^T d = x R[0] + y R[1] + R[2], written out (no BLAS:
            # OpenBLAS threads spin and slow down parallel workers).
            Rf = R.astype(np.float32)
            xs, ys = xs_all[u0:u1], ys_all[v0:v1]
            dirs = np.empty((v1 - v0, u1 - u0, 3), dtype=np.float32)
            for j in range(3):
                np.add(ys[:, None] * Rf[1, j], xs * Rf[0, j] + Rf[2, j], out=dirs[..., j])
            dirs = dirs.reshape(-1, 3)
            o = (-(R.T @ t) - info.center).astype(np.float32)
            try:
                tfar = scene.run(np.broadcast_to(o, dirs.shape), dirs, query="DISTANCE")
            except (ValueError, BufferError, TypeError):      # an embreex that wants writable rows
                tfar = scene.run(np.repeat(o[None], len(dirs), axis=0), dirs, query="DISTANCE")
            tfar[tfar > 1e30] = 0.0
            out[i, v0:v1, u0:u1] = tfar.reshape(v1 - v0, u1 - u0)

    # -- pyrender
    def _render_gl(self, info, Rs, ts, zc, out):
        K = self.intrinsics
        if self._gl is None:
            gl_platform()
            pyrender = _import_pyrender()
            renderer = pyrender.OffscreenRenderer(K.width, K.height)
            scene = pyrender.Scene(bg_color=np.zeros(4), ambient_light=np.zeros(3))
            # pyrender's window coordinate of pixel i's centre is i + 0.5; OpenCV's is i
            cam = pyrender.IntrinsicsCamera(K.fx, K.fy, K.cx + 0.5, K.cy + 0.5, znear=0.05, zfar=100.0)
            scene.add(cam, pose=np.eye(4))             # GL camera at the origin: world = GL camera frame
            self._gl = [renderer, scene, cam, None]
        renderer, scene, cam, node = self._gl
        if info.handle is None:
            pyrender = _import_pyrender()
            if node is not None:
                scene.remove_node(node)
            # DEPTH_ONLY rendering culls back faces: add every triangle in both windings,
            # since real meshes (ModelNet) are not consistently oriented.
            faces = np.vstack([info.faces, info.faces[:, ::-1]]).astype(np.uint32)
            prim = pyrender.Primitive(positions=(info.vertices - info.center).astype(np.float32),
                                      indices=faces, mode=pyrender.constants.GLTF.TRIANGLES)
            node = scene.add(pyrender.Mesh([prim]))
            self._gl[3] = info.handle = node
        flip = np.diag([1.0, -1.0, -1.0])               # OpenCV camera axes -> OpenGL camera axes
        pyrender = _import_pyrender()
        # DEPTH_ONLY; SEG in addition only because it makes pyrender disable GL_MULTISAMPLE:
        # its framebuffer (EGL) is 4x multisampled, and a multisampled depth buffer resolves to
        # one sample's depth, off the pixel centre. With SEG every sample is the pixel centre's.
        flags = pyrender.RenderFlags.DEPTH_ONLY | pyrender.RenderFlags.SEG
        seg = {node: 255}
        pose = np.eye(4)
        for i in range(len(Rs)):
            pose[:3, :3] = flip @ Rs[i]
            pose[:3, 3] = flip @ (Rs[i] @ info.center + ts[i])
            scene.set_pose(node, pose)
            cam.znear = max(self.znear, 0.9 * (zc[i] - info.radius))
            cam.zfar = zc[i] + 1.1 * info.radius + 0.01
            out[i] = renderer.render(scene, flags=flags, seg_node_map=seg)
