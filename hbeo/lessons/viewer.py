"""Rotatable 3-D views for the notebooks: a completed 30³ grid beside the true one, with the observed depth points.

A :class:`View3D` holds what one view shows, all in **grid coordinates of the canonical object frame**
(:mod:`hbeo.conventions`: voxel (i, j, k) covers ``[i, i+1) × [j, j+1) × [k, k+1)``, +z up): the completed
grid, optionally the true grid, and the object's depth pixels back-projected (:func:`hbeo.conventions.backproject`)
and moved into that frame by a pose (R, t) (:func:`depth_points`: ``x = Rᵀ (p − t)`` metres, then
``u = x · 24 / object_size + 15`` voxels), with a second pose's points optional (hidden at first).

- :func:`object_view` builds it for one test object of a run (notebook 06): query view ``view`` of the first
  test objects of a class, the same image the evaluations score (:mod:`hbeo.evaluation.protocol`), HBEO's
  completion, the true grid, the points moved with the true pose (and, hidden, with HBEO's predicted pose);
- :func:`frame_view` builds it for one depth frame and HBEO's answer (notebook 08): the points moved with the
  predicted pose; no true grid (a user's file has none), the true pose's points when the frame knows it.

:func:`figure` draws it with plotly: one 3-D scene, so one rotation turns every part together; the completion
and the true grid as their exposed voxel faces (:func:`voxel_faces`, one ``Mesh3d`` each, the true grid drawn
:data:`TRUTH_OFFSET` voxels beside the completion along +x), the points as markers over both. :func:`to_html`
gives it as an HTML fragment that works offline: plotly.js is embedded (``include_plotlyjs=True``, ~4.9 MB),
nothing is loaded from a CDN, and the one ``src="https://…"`` inside the bundle's map code is written with
``\\/\\/`` (the same JavaScript string) so that the run's book (:func:`hbeo.report.book.remote_references`)
accepts the page. :func:`static_figure` is the same view as a matplotlib figure (shaded grids by
:func:`hbeo.report.figures.render_voxels` and the points in 3-D) for papermill/nbval runs and viewers that
run no JavaScript; :func:`show` displays both in a notebook and saves the PNG into the run folder.

May import: foundation, data, render, model, :mod:`hbeo.report.figures` and
:mod:`hbeo.evaluation.protocol` (plotly, matplotlib and IPython lazily).
"""
from __future__ import annotations

import re
import textwrap
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hbeo import config
from hbeo import conventions as C
from hbeo.conventions import backproject
from hbeo.report import figures
from hbeo.rundir import RunDir

#: Voxels between the completion's and the true grid's origins along +x (a 30-voxel grid and a gap).
TRUTH_OFFSET = 36.0
#: At most this many observed points are drawn (a deterministic subsample; the HTML stays small).
MAX_POINTS = 2000
#: Colours: the completion in HBEO's colour (:data:`hbeo.report.figures.METHOD_COLORS`), the truth grey,
#: the points moved with the view's pose black, those moved with the other pose red.
COMPLETION_COLOR = figures.METHOD_COLORS[("hbeo", "3dof")]
TRUTH_COLOR, POINTS_COLOR, OTHER_POINTS_COLOR = "#a0a0a0", "#111111", "#d62728"
#: plotly's figure options: no plotly logo link, resizes with the page.
PLOTLY_CONFIG = {"displaylogo": False, "responsive": True}
_REMOTE_IN_JS = re.compile(r"""(\bsrc\s*=\s*["'])(https?:)//""")


@dataclass
class View3D:
    """What one 3-D view shows; grids (30, 30, 30) bool and points (N, 3) in grid coordinates of the
    canonical object frame (voxels, see the module docstring)."""

    completion: np.ndarray                  #: the completed grid
    points: np.ndarray                      #: observed points moved into the object frame with ``pose``
    pose: str                               #: which pose moved ``points``, in words ("true pose", ...)
    truth: np.ndarray | None = None         #: the true grid (None: unknown, e.g. your own frame)
    other_points: np.ndarray | None = None  #: the same points moved with ``other_pose`` (drawn hidden at first)
    other_pose: str | None = None
    title: str = ""
    completion_label: str = "HBEO completion"


def depth_points(depth: np.ndarray, intrinsics: C.Intrinsics, R: np.ndarray, t: np.ndarray,
                 object_size: float) -> np.ndarray:
    """The pixels of ``depth`` (H, W, metres, 0 = none) back-projected and moved into the object frame by the pose
    ``R`` (3, 3, object → camera) and ``t`` (3,) metres (the object's centre), as grid coordinates (N, 3) for an
    object whose longest side is ``object_size`` metres (24 voxels)."""
    pts, _ = backproject(np.asarray(depth, np.float64), intrinsics)
    x = (pts - np.asarray(t, np.float64)) @ np.asarray(R, np.float64)       # Rᵀ (p − t), row vectors
    return x * (C.OBJECT_VOXELS / float(object_size)) + C.RESOLUTION / 2.0


def subsample(points: np.ndarray, n: int = MAX_POINTS, seed: int = 0) -> np.ndarray:
    """At most ``n`` of ``points`` (N, 3), chosen with a fixed seed, in their original order."""
    points = np.asarray(points)
    if len(points) <= n:
        return points
    return points[np.sort(np.random.default_rng(seed).choice(len(points), n, replace=False))]


def surface_voxels(grid: np.ndarray) -> np.ndarray:
    """Indices (N, 3) of the occupied voxels of ``grid`` (R, R, R) with an empty 6-neighbour or on the border."""
    from scipy import ndimage
    g = np.asarray(grid, bool)
    return np.argwhere(g & ~ndimage.binary_erosion(g))


def voxel_faces(grid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The exposed faces of an occupancy grid (R, R, R) (an occupied voxel next to an empty one or the border) as a
    triangle mesh: vertices (V, 3) float on the voxel corners (grid coordinates) and triangles (F, 3) int, wound
    so that their normals point out of the object. Empty grid: (0, 3) and (0, 3)."""
    g = np.pad(np.asarray(grid, bool), 1)
    n = g.shape[0] - 1                                   # lattice corners per axis of the unpadded grid: R + 1
    quads = []
    for axis in range(3):
        b, c = (axis + 1) % 3, (axis + 2) % 3
        for sign in (1, -1):
            face = g & ~np.roll(g, -sign, axis=axis)
            idx = np.argwhere(face[1:-1, 1:-1, 1:-1])   # voxel indices of the unpadded grid
            if not len(idx):
                continue
            base = idx.copy()
            base[:, axis] += sign > 0                      # the face's plane along ``axis``
            corners = [(0, 0), (1, 0), (1, 1), (0, 1)] if sign > 0 else [(0, 0), (0, 1), (1, 1), (1, 0)]
            quad = np.repeat(base[:, None, :], 4, axis=1)
            for q, (db, dc) in enumerate(corners):
                quad[:, q, b] += db
                quad[:, q, c] += dc
            quads.append(quad)
    if not quads:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    quads = np.concatenate(quads)                          # (Q, 4, 3) integer corners
    keys = np.ravel_multi_index(quads.reshape(-1, 3).T, (n, n, n))
    uniq, inverse = np.unique(keys, return_inverse=True)
    q = inverse.reshape(-1, 4)
    tris = np.concatenate([q[:, [0, 1, 2]], q[:, [0, 2, 3]]])
    return np.stack(np.unravel_index(uniq, (n, n, n)), axis=1).astype(np.float64), tris.astype(np.int64)


def _mesh_trace(grid, color: str, name: str, offset: float):
    import plotly.graph_objects as go
    v, f = voxel_faces(grid)
    v, f = (v + [offset, 0.0, 0.0]).astype(np.float32), f.astype(np.int32)     # compact arrays in the HTML
    return go.Mesh3d(x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2], color=color,
                     flatshading=True, name=name, showlegend=True, hoverinfo="skip",
                     lighting=dict(ambient=0.55, diffuse=0.7, specular=0.05, roughness=0.9))


def figure(view: View3D, height: int = 560):
    """The rotatable plotly figure of ``view``: the completion at the origin, the true grid :data:`TRUTH_OFFSET`
    voxels beside it along +x, the observed points over both (one legend entry toggles both copies; the other
    pose's points start hidden). Axes in voxels of the object frame, +z up."""
    import plotly.graph_objects as go
    traces = [_mesh_trace(view.completion, COMPLETION_COLOR, view.completion_label, 0.0)]
    copies = [0.0]
    if view.truth is not None:
        traces.append(_mesh_trace(view.truth, TRUTH_COLOR, "true shape (drawn beside, +x)", TRUTH_OFFSET))
        copies.append(TRUTH_OFFSET)
    layers = [(view.points, f"observed points ({view.pose})", POINTS_COLOR, True)]
    if view.other_points is not None:
        layers.append((view.other_points, f"observed points ({view.other_pose})", OTHER_POINTS_COLOR, "legendonly"))
    for k, (pts, label, color, visible) in enumerate(layers):
        pts = subsample(pts, seed=k).astype(np.float32)
        for c, off in enumerate(copies):
            traces.append(go.Scatter3d(x=pts[:, 0] + np.float32(off), y=pts[:, 1], z=pts[:, 2], mode="markers",
                                       marker=dict(size=1.6, color=color), name=label, legendgroup=label,
                                       showlegend=c == 0, visible=visible, hoverinfo="skip"))
    top = C.RESOLUTION + 1.0
    notes = [dict(x=C.RESOLUTION / 2 + off, y=C.RESOLUTION / 2, z=top, text=text, showarrow=False,
                  font=dict(size=12)) for off, text in zip(copies, [view.completion_label, "true shape"])]
    fig = go.Figure(traces)
    fig.update_layout(
        title=dict(text=view.title, font=dict(size=13)), height=height, margin=dict(l=0, r=0, t=60, b=0),
        legend=dict(x=0.01, y=0.98, bgcolor="rgba(255,255,255,0.7)"),
        scene=dict(aspectmode="data", annotations=notes,
                   xaxis_title="x (voxels)" + (f"; true shape at x + {TRUTH_OFFSET:g}" if len(copies) > 1 else ""),
                   yaxis_title="y (voxels)", zaxis_title="z, up (voxels)",
                   camera=dict(up=dict(x=0, y=0, z=1), eye=dict(x=0.4, y=-1.9, z=0.9))))
    return fig


def to_html(fig, include_plotlyjs: bool = True) -> str:
    """The plotly figure ``fig`` as an HTML fragment that needs no network: plotly.js embedded when
    ``include_plotlyjs`` (False: the page must already hold it, e.g. from an earlier output of the same
    notebook); never a CDN. The bundle's ``src="https://…"`` strings become ``src="https:\\/\\/…"`` (the same
    JavaScript string), which the run's book does not mistake for a resource to load."""
    if not isinstance(include_plotlyjs, bool):
        raise ValueError(f"include_plotlyjs must be True or False (never a CDN), got {include_plotlyjs!r}")
    html = fig.to_html(full_html=False, include_plotlyjs=include_plotlyjs, include_mathjax=False,
                       config=PLOTLY_CONFIG, default_width="100%", default_height=f"{fig.layout.height or 560}px")
    if re.search(r"<script[^>]*\bsrc\s*=", html):
        raise RuntimeError("plotly's HTML would load a script from elsewhere; this view must embed it")
    return _REMOTE_IN_JS.sub(lambda m: m.group(1) + m.group(2) + r"\/\/", html)


def static_figure(view: View3D, azim: float = -60.0, elev: float = 25.0):
    """``view`` as a matplotlib figure: the completion and the true grid shaded (:func:`figures.render_voxels`,
    seen from azimuth ``azim`` and elevation ``elev`` degrees) and the observed points over the completion's
    surface voxels in 3-D from the same direction."""
    import matplotlib.pyplot as plt
    n = 3 if view.truth is not None else 2
    fig = plt.figure(figsize=(4.0 * n, 4.5))
    panels = [(view.completion, view.completion_label, COMPLETION_COLOR)]
    if view.truth is not None:
        panels.append((view.truth, "true shape", TRUTH_COLOR))
    for i, (grid, label, color) in enumerate(panels):
        ax = fig.add_subplot(1, n, i + 1)
        rgb = tuple(int(color[k:k + 2], 16) / 255 for k in (1, 3, 5))
        ax.imshow(figures.render_voxels(grid, azim=azim, elev=elev, size=220, color=rgb))
        ax.set_title(f"{label} ({int(np.sum(grid))} voxels)", fontsize=10)
        ax.axis("off")
    ax = fig.add_subplot(1, n, n, projection="3d")
    surf = subsample(surface_voxels(view.completion) + 0.5, 2500, seed=1)
    ax.scatter(surf[:, 0], surf[:, 1], surf[:, 2], s=2, c=COMPLETION_COLOR, alpha=0.25, depthshade=False,
               label=view.completion_label)
    pts = subsample(view.points, 2000)
    ax.scatter(pts[:, 0], pts[:, 1], pts[:, 2], s=1.5, c=POINTS_COLOR, depthshade=False,
               label=f"observed points ({view.pose})")
    ax.set(xlim=(0, C.RESOLUTION), ylim=(0, C.RESOLUTION), zlim=(0, C.RESOLUTION),
           xlabel="x (voxels)", ylabel="y (voxels)", zlabel="z, up (voxels)")
    ax.set_box_aspect((1, 1, 1))
    ax.view_init(elev=elev, azim=azim)
    ax.tick_params(labelsize=7)
    ax.legend(loc="upper left", fontsize=7, markerscale=4)
    ax.set_title("observed points on the completion", fontsize=10)
    fig.suptitle(textwrap.fill(view.title, 45 * n), fontsize=10)
    fig.tight_layout()
    return fig


def show(view: View3D, run=None, name: str | None = None, include_plotlyjs: bool = True):
    """Display ``view`` in a notebook: the rotatable figure (:func:`to_html`, works offline in the executed
    notebook and the run's book), then :func:`static_figure` below it (matplotlib's inline backend shows it),
    saved as the run's PNG ``name`` when ``run`` and ``name`` are given. Returns the matplotlib figure."""
    from IPython.display import HTML, display
    display(HTML(to_html(figure(view), include_plotlyjs)))
    fig = static_figure(view)
    if run is not None and name:
        figures.save(fig, run, name)
    return fig


def object_view(run, cls: str | None = None, index: int = 0, view: int = 0) -> View3D:
    """The 3-D view of one test object of ``run`` (a :class:`hbeo.run.Run`): object ``index`` (in id order) of class ``cls`` (None: a chair,
    or the dataset's first class when it has no chairs) in the test split, query view ``view`` (the image every method's evaluation scores: seed
    :data:`hbeo.evaluation.protocol.SEED`, :meth:`hbeo.render.views.ObjectViews.query_views`), HBEO's
    completion from that depth image alone, the true grid, the points moved with the true pose and (hidden at
    first) with HBEO's predicted pose. ValueError when the split has no such object."""
    from hbeo.data.gridset import record_grid
    from hbeo.model.inference import HBEO
    from hbeo.render.views import ObjectViews, RenderSettings
    from hbeo.evaluation.protocol import SEED
    from hbeo.rotations import geodesic_deg
    model = HBEO.load(run.dir.model)
    ds = run.dataset
    cls = cls or ("chair" if "chair" in ds.classes else ds.classes[0])
    records = ds.records(split="test", classes=[cls])
    if not 0 <= index < len(records):
        raise ValueError(f"index must be in 0..{len(records) - 1} for the {len(records)} test objects of {cls!r}, "
                         f"got {index}")
    rec = records[index]
    rs = RenderSettings.for_queries(model.settings.render, 1, SEED)
    views = ObjectViews(rs)
    try:
        v = views.query_views(rec, "test", view + 1)
    finally:
        views.close()
    depth = v["depth"][view].astype(np.float32)
    R, t = v["rotation"][view].astype(np.float64), v["translation"][view].astype(np.float64)
    pred = model.predict(depth, model.intrinsics)
    size = float(rs.object_size)
    err = float(geodesic_deg(pred.rotation[0], R))
    name = str(rec.id) if str(rec.id).startswith(rec.cls) else f"{rec.cls} {rec.id}"
    title = (f"test object {name}, view {view}: HBEO says {pred.class_names[0]} "
             f"(p = {pred.probabilities[0].max():.2f}), pose error {err:.0f}°")
    return View3D(completion=pred.grids[0], points=depth_points(depth, model.intrinsics, R, t, size),
                  pose="true pose", truth=record_grid(rec),
                  other_points=depth_points(depth, model.intrinsics, pred.rotation[0], pred.translation[0],
                                            size * float(pred.scale[0])),
                  other_pose="HBEO's predicted pose", title=title,
                  completion_label=f"HBEO completion ({pred.class_names[0]})")


def frame_view(model, frame, answer) -> View3D:
    """The 3-D view of one depth frame and HBEO's answer for it (notebook 08): ``frame`` a
    :class:`hbeo.lessons.yourdepth.Frame` (its ``object_depth``, ``intrinsics`` and, for the sample frame,
    ``truth`` with ``rotation`` and ``translation``), ``answer`` a :class:`hbeo.model.inference.Prediction` of
    that one image. The points are moved with the predicted pose; with the true pose too (hidden at first) when
    the frame knows it. No true grid."""
    size = float(model.settings.object_size) * float(answer.scale[0])
    depth = frame.object_depth
    pts = depth_points(depth, frame.intrinsics, answer.rotation[0], answer.translation[0], size)
    truth = getattr(frame, "truth", None) or {}
    other = None
    if "rotation" in truth and "translation" in truth:
        other = depth_points(depth, frame.intrinsics, truth["rotation"], truth["translation"],
                             float(model.settings.object_size))
    label = f"HBEO completion ({answer.class_names[0]})"
    return View3D(completion=answer.grids[0], points=pts, pose="HBEO's predicted pose", other_points=other,
                  other_pose="true pose" if other is not None else None, completion_label=label,
                  title=f"{_name(frame)}: HBEO says {answer.class_names[0]} (p = {answer.probabilities[0].max():.2f}); "
                        f"points moved into the object frame with the predicted pose")


def _name(frame) -> str:
    path = getattr(frame, "depth_path", None)
    return f"frame {Path(path).name}" if path is not None else "the frame"
