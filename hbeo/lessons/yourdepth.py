"""Notebook 08: one depth image from your own camera through HBEO, and what to check when the answer is odd.

Owns the path from a depth file on disk to HBEO's answer and the pictures of it:

- :func:`sample_frame` renders the default input, a sensor-like frame: a ModelNet10 sample mesh
  (``shared/modelnet10_sample/bathtub/train/*.off``, :func:`hbeo.config.modelnet10_sample_dir`; a procedural
  bathtub when that folder is missing) at an upright pose in the middle of the model's training distances,
  seen by a 640x480 Kinect-like camera (:meth:`hbeo.conventions.Intrinsics.kinect`) with
  :class:`hbeo.render.noise.SensorNoise`, written as a 16-bit PNG in millimetres and a mask PNG into the run;
- :func:`read_frame` reads a depth image (and mask) as ``python -m hbeo predict`` does
  (:mod:`hbeo.model.depthfile`: 16-bit PNG in millimetres, float ``.npy``/``.tiff`` in metres, times ``depth_scale``);
- :func:`predict_frame` asks :class:`hbeo.model.answer.Predictor` (the network, then optionally the verify step,
  as ``predict`` and the evaluation do), :func:`class_hypotheses` / :func:`rotation_hypotheses` tabulate the
  network's top classes and rotation modes, :func:`checks` the things to look at when the answer is odd;
- :func:`input_figure`, :func:`points_figure`, :func:`overlay_figure` draw the frame, its back-projected points
  and the completion placed on them; :func:`write_answer` writes the completed mesh (:meth:`HBEO.to_mesh`, as
  ``predict --mesh`` does) and the answer's JSON (``predict --out``'s keys and more) into the run folder.

Shapes and units: depth (H, W) float32 metres, 0 = no measurement; mask (H, W) bool; points (N, 3) metres in the
camera frame of :mod:`hbeo.conventions` (OpenCV: x right, y down, z forward); R (3, 3) object -> camera, t (3,)
the object's centre in metres; grids (30, 30, 30) bool in the canonical object frame (+z up). Files are written
atomically (:mod:`hbeo.storage`); relative input paths are taken from the repository root.

May import: foundation, data, render, model, and the other reproduction modules (matplotlib lazily).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from hbeo import config
from hbeo.conventions import Intrinsics, backproject
from hbeo.errors import DataError
from hbeo.report import figures
from hbeo.rundir import RunDir
from hbeo.storage import atomic_file, atomic_text, json_text

#: The files notebook 08 writes into the run folder (stems; PNGs through :meth:`RunDir.figure`).
DEPTH_PNG, MASK_PNG = "08_depth_mm", "08_mask"
ANSWER_JSON, MESH_FILE = "08_answer.json", "08_completion.ply"
#: The sample frame: a Kinect's full image, the ModelNet10 sample's class, its view (yaw about the object's up
#: axis and camera elevation, degrees: an upright view of the object's front-left) and its noise seed.
SAMPLE_SIZE = (640, 480)
SAMPLE_CLASS = "bathtub"
SAMPLE_VIEW_DEG = (35.0, 30.0)
SAMPLE_SEED = 0
#: Distances (m) the model was trained at when its file does not say (:class:`hbeo.render.poses.ViewSampler`'s).
DEFAULT_DISTANCE = (1.4, 2.0)
#: :func:`checks` flags an object whose points span more than this factor from the training objects' size.
SIZE_FACTOR = 2.0


@dataclass
class Frame:
    """One depth image and how to read it."""

    depth: np.ndarray              #: (H, W) float32 metres, 0 = no measurement
    intrinsics: Intrinsics         #: the camera that took it (pixels)
    mask: np.ndarray | None        #: (H, W) bool object pixels, None: every pixel with depth
    depth_path: Path
    mask_path: Path | None = None
    depth_scale: float | None = None
    source: str = ""               #: where the frame came from, in words
    truth: dict = field(default_factory=dict)   #: the sample frame's class, R (3, 3), t (3,); {} for yours

    @property
    def object_depth(self) -> np.ndarray:
        """The depth with the mask applied (H, W)."""
        return self.depth * self.mask if self.mask is not None else self.depth


def _path(p) -> Path:
    p = Path(p).expanduser()
    return p if p.is_absolute() else config.REPO_ROOT / p


def training_distances(model) -> tuple[float, float]:
    """The range (m) of object-centre distances the model's training images had."""
    d = model.settings.render.get("distance") or DEFAULT_DISTANCE
    return float(min(d)), float(max(d))


def sample_mesh():
    """(mesh, words): the first ModelNet10 sample mesh of :data:`SAMPLE_CLASS`, else a procedural one."""
    from hbeo.data import procedural
    from hbeo.data.meshio import read_mesh
    root = config.modelnet10_sample_dir()
    files = sorted((root / SAMPLE_CLASS / "train").glob("*.off")) if root is not None else []
    if files:
        return read_mesh(files[0]), f"ModelNet10 mesh {files[0].name}"
    return procedural.generate(SAMPLE_CLASS, "test", 0), f"procedural {SAMPLE_CLASS} (ModelNet10 sample not found)"


def _write_png(path: Path, array: np.ndarray) -> Path:
    from PIL import Image
    with atomic_file(path) as f:
        Image.fromarray(array).save(f, format="PNG")
    return path


def sample_frame(run, model) -> Frame:
    """Render the default input (see the module docstring) into ``run``'s :data:`DEPTH_PNG` (uint16, mm) and
    :data:`MASK_PNG` (uint8, 255 = object) and read them back as a user's files would be."""
    from hbeo.render.noise import SensorNoise
    from hbeo.render.renderer import Renderer, prepare_mesh
    from hbeo.rotations import yaw_elevation_to_matrix
    run = RunDir.of(run)
    mesh, words = sample_mesh()
    K = Intrinsics.kinect(*SAMPLE_SIZE)
    R = yaw_elevation_to_matrix(math.radians(SAMPLE_VIEW_DEG[0]), math.radians(SAMPLE_VIEW_DEG[1]))
    t = np.array([0.0, 0.0, float(np.mean(training_distances(model)))])
    size = float(model.settings.object_size)
    with Renderer(K) as r:
        clean = r.render(prepare_mesh(mesh, size), R, t)
    noisy = SensorNoise().apply(clean, K, np.random.default_rng(SAMPLE_SEED))
    depth_path = _write_png(run.figure(DEPTH_PNG), np.round(noisy * 1000).astype(np.uint16))
    mask_path = _write_png(run.figure(MASK_PNG), np.where(noisy > 0, 255, 0).astype(np.uint8))
    frame = read_frame(depth_path, f"{K.fx},{K.fy},{K.cx},{K.cy}", 0.001, mask_path)
    frame.source = (f"{words}, {size:g} m long, {t[2]:.2f} m away (yaw {SAMPLE_VIEW_DEG[0]:g}°, elevation "
                    f"{SAMPLE_VIEW_DEG[1]:g}°), {K.width}x{K.height} Kinect-like camera, sensor noise")
    frame.truth = {"class": SAMPLE_CLASS, "rotation": R, "translation": t}
    return frame


def read_frame(depth_path, intrinsics: str | None = None, depth_scale: float | None = 0.001, mask_path=None) -> Frame:
    """A depth file (16-bit PNG in mm, or float ``.npy``/``.tiff`` in m) times ``depth_scale`` (metres per stored
    unit; None: 0.001 for integers, 1 for floats), ``intrinsics`` ``"fx,fy,cx,cy"`` in pixels of this image
    (None: Kinect-like for its size, with a printed warning) and an optional mask file. DataError / ValueError
    name the problem, as ``python -m hbeo predict`` does."""
    from hbeo.model.depthfile import parse_intrinsics, read_depth, read_mask
    depth_path = _path(depth_path)
    depth = read_depth(depth_path, depth_scale)
    H, W = depth.shape
    if intrinsics is None:
        K = Intrinsics.kinect(W, H)
        print(f"warning: no intrinsics given: assuming a Kinect-like camera for {W}x{H} "
              f"(fx = fy = {K.fx:g}, cx = {K.cx:g}, cy = {K.cy:g}); give yours as 'fx,fy,cx,cy'")
    else:
        K = parse_intrinsics(str(intrinsics), W, H)
    mask_path = _path(mask_path) if mask_path is not None else None
    mask = read_mask(mask_path, depth.shape) if mask_path is not None else None
    if mask is not None and not (mask & (depth > 0)).any():
        raise DataError(mask_path, "the mask covers no pixel with depth")
    return Frame(depth, K, mask, depth_path, mask_path, depth_scale, source=f"your file {depth_path.name}")


def load_model(run, model_path=None, face_object: bool = False):
    """The model to ask: ``model_path`` if given, else the model of ``run`` (a :class:`hbeo.run.Run`; trained
    with the profile's recipe when missing, :meth:`hbeo.run.Run.model`); ``face_object``: its views turned to the
    object first, as ``predict --face-object`` (:meth:`hbeo.model.inference.HBEO.set_face_object`). Returns
    (model, its path)."""
    from hbeo.model.inference import HBEO
    model, path = (HBEO.load(_path(model_path)), _path(model_path)) if model_path is not None else \
        (run.model(), run.dir.model)
    return model.set_face_object(face_object), path


def predict_frame(model, frame: Frame, verify: bool = True, rolls: int = 1):
    """HBEO's answer for the frame (a :class:`~hbeo.model.inference.Prediction` of one image), verified against
    the depth when ``verify`` (:class:`hbeo.model.verify.Verifier`, default settings), as ``predict --verify``;
    also returns the network's own answer: (answer, network). DataError names the depth file. The same
    "predict then verify" as ``predict`` and the evaluation (:class:`hbeo.model.answer.Predictor`)."""
    from hbeo.model.answer import Predictor
    from hbeo.model.verify import VerifyConfig
    return Predictor(model, rolls, VerifyConfig() if verify else None)(frame.depth, frame.intrinsics, frame.mask,
                                                                       source=frame.depth_path)


def class_hypotheses(model, pred, n: int = 3) -> pd.DataFrame:
    """The network's ``n`` most probable classes with their probabilities (``pred``: the network's answer)."""
    p = np.asarray(pred.probabilities[0])
    order = np.argsort(-p)[:n]
    return pd.DataFrame({"rank": np.arange(1, len(order) + 1), "class": [model.classes[i] for i in order],
                         "probability": p[order]})


def rotation_hypotheses(model, pred, frame: Frame | None = None, n: int | None = None) -> pd.DataFrame:
    """The network's ``n`` rotation modes (None: as many as verify tries, :attr:`VerifyConfig.rotations
    <hbeo.model.verify.VerifyConfig>`; :meth:`hbeo.model.verify.Verifier.hypotheses_rotations`: a rotation-bins
    model's most probable separated modes with their probability mass; a regression head's answer turned about
    the up axis by 360°/n steps, equally weighted): the axis-angle vector (radians), the angle from the answer
    and, for the sample frame, from the true rotation (degrees)."""
    from dataclasses import replace
    from hbeo.model.verify import Verifier, VerifyConfig
    from hbeo.rotations import geodesic_deg, matrix_to_axis_angle
    cfg = VerifyConfig()
    v = Verifier(model, replace(cfg, rotations=cfg.rotations if n is None else n))
    Rs, logw = v.hypotheses_rotations(pred, 0)
    w = np.exp(logw)
    rows = {"mode": np.arange(1, len(Rs) + 1),
            "weight": w if pred.pose_probs is not None else np.full(len(Rs), np.nan),
            "axis-angle (rad)": [np.round(a, 3).tolist() for a in matrix_to_axis_angle(Rs)],
            "angle from the answer (°)": geodesic_deg(Rs, pred.rotation[0][None])}
    if frame is not None and frame.truth:
        rows["angle from the truth (°)"] = geodesic_deg(Rs, frame.truth["rotation"][None])
    return pd.DataFrame(rows)


def answer_summary(model, pred, frame: Frame) -> str:
    """One line: class and probability, pose (axis-angle), centre and distance, and for the sample frame its
    errors (raw pose error, and modulo the class's turns about the up axis)."""
    t = pred.translation[0]
    s = (f"{pred.class_names[0]} (p = {pred.probabilities[0].max():.2f}); axis-angle "
         f"{np.round(pred.axis_angle[0], 3).tolist()} rad; centre {np.round(t, 3).tolist()} m "
         f"({np.linalg.norm(t):.2f} m away)")
    if frame.truth:
        from hbeo.conventions import UP_SYMMETRY
        from hbeo.rotations import symmetric_pose_error_deg as symmetric_pose_error
        from hbeo.rotations import geodesic_deg
        R_true = frame.truth["rotation"]
        err = float(geodesic_deg(pred.rotation[0], R_true))
        sym = float(symmetric_pose_error(pred.rotation[0], R_true, UP_SYMMETRY.get(frame.truth["class"], 1)))
        s += (f"\ntruth: {frame.truth['class']}; pose error {err:.0f}° ({sym:.0f}° modulo the class's symmetry); "
              f"centre off by {np.linalg.norm(t - frame.truth['translation']) * 100:.0f} cm")
    return s


def checks(model, frame: Frame, pred) -> pd.DataFrame:
    """What to look at when the answer is odd, measured on this frame: units (median depth), intrinsics (field
    of view), the mask, the object's distance and size against the training images', sensor noise, how much of
    the object the network sees, and predict's warnings. ``ok`` is False where this frame is outside what the
    model was trained on."""
    from hbeo.model.viewcheck import DISTANCE_FACTOR, MIN_COVERAGE, min_input_pixels
    from hbeo.model.depthfile import DEPTH_RANGE_M
    K, Km = frame.intrinsics, model.intrinsics
    min_filled = min_input_pixels(Km)
    d = frame.object_depth
    med = float(np.median(d[d > 0]))
    fov = math.degrees(2 * math.atan(K.width / (2 * K.fx)))
    fov_m = math.degrees(2 * math.atan(Km.width / (2 * Km.fx)))
    view = model.view(frame.depth, K, frame.mask, aim=network_aim(model, pred))
    lo, hi = training_distances(model)
    n_obj = int((d > 0).sum())
    pts, _ = backproject(d, K)
    extent = float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0
    size = float(model.settings.object_size)
    noise = model.settings.render.get("noise", False)
    warns = list(pred.warnings[0]) if pred.warnings else []
    d_lo, d_hi = DEPTH_RANGE_M
    rows = [("depth units", f"median object depth {med:.3f} m",
             f"the distance a tape measures ({d_lo:g}..{d_hi:g} m accepted)", d_lo <= med <= d_hi),
            ("intrinsics", f"fx {K.fx:g}, fy {K.fy:g}, cx {K.cx:g}, cy {K.cy:g} px; horizontal FOV {fov:.0f}°",
             f"this image's camera (the model's: {Km.width}x{Km.height}, FOV {fov_m:.0f}°); the object in its view",
             view.coverage >= MIN_COVERAGE),
            ("mask", f"{n_obj} object pixels ({n_obj / d.size:.1%} of the image)"
             + ("" if frame.mask is not None else ", no mask: every pixel with depth"),
             "the object only (floor, wall, other objects removed)", 0 < n_obj),
            ("distance", f"object centre {view.distance:.2f} m away",
             f"trained at {lo:g}..{hi:g} m (within a factor {DISTANCE_FACTOR:g})",
             lo / DISTANCE_FACTOR <= view.distance <= hi * DISTANCE_FACTOR),
            ("object size", f"the points span {extent:.2f} m (the visible part: a lower bound)",
             f"trained on objects {size:g} m long, scaled to it (within a factor {SIZE_FACTOR:g})",
             size / SIZE_FACTOR <= extent <= size * SIZE_FACTOR),
            ("sensor noise", "a real camera's depth: noise, holes at edges and grazing surfaces",
             f"trained {'with' if noise else 'without'} sensor noise", bool(noise)),
            ("network input", f"{view.filled} of {Km.width * Km.height} input pixels filled, "
             f"{view.coverage:.0%} of the object inside", f"at least {min_filled} pixels, {MIN_COVERAGE:.0%} inside",
             view.filled >= min_filled and view.coverage >= MIN_COVERAGE),
            ("predict's warnings", "; ".join(warns) or "none", "none (low_confidence false)", not warns)]
    return pd.DataFrame(rows, columns=["check", "this frame", "expected", "ok"])


# ----------------------------------------------------------------------------- figures

def network_aim(model, pred=None):
    """The ``aim`` of :meth:`HBEO.view` that gives the view the network answered for ``pred`` (its
    ``view_rotation``), or the model's own setting without ``pred``: with ``face_object`` the turn depends on a first
    answer (:mod:`hbeo.model.facing`)."""
    if pred is None or pred.view_rotation is None:
        return None
    Q = np.asarray(pred.view_rotation[0])
    return "plain" if np.allclose(Q, np.eye(3)) and not model.settings.recenter else Q[:, 2]


def input_figure(model, frame: Frame, pred=None):
    """The depth image (metres, colour bar), its mask, and the network's input (the frame resampled into the
    model's camera as :meth:`HBEO.predict` gives it to the network, :meth:`HBEO.view`; with ``face_object``, the
    view of ``pred``, or without it the frame unturned)."""
    import matplotlib.pyplot as plt
    view = model.view(frame.depth, frame.intrinsics, frame.mask, aim=network_aim(model, pred))
    fig, ax = plt.subplots(1, 3, figsize=(12, 3.4), gridspec_kw={"width_ratios": [1.25, 1, 1]})
    d = np.ma.masked_less_equal(frame.depth, 0)
    im = ax[0].imshow(d, cmap="viridis_r")
    fig.colorbar(im, ax=ax[0], label="depth z (m)", shrink=0.85)
    ax[0].set(title=f"depth image ({frame.depth.shape[1]}x{frame.depth.shape[0]})", xlabel="column u (px)",
              ylabel="row v (px)")
    mask = frame.mask if frame.mask is not None else frame.depth > 0
    ax[1].imshow(mask, cmap="gray")
    ax[1].set(title="mask" if frame.mask is not None else "mask (none given: depth > 0)", xlabel="column u (px)",
              ylabel="row v (px)")
    figures.show_depth(ax[2], view.depth)
    ax[2].set_axis_on()
    ax[2].set(title=f"network input ({model.intrinsics.width}x{model.intrinsics.height}, model camera)",
              xlabel="column (px)", ylabel="row (px)")
    fig.tight_layout()
    return fig


def _completion_points(model, pred) -> np.ndarray:
    """The completed shape's surface points (N, 3), camera frame, metres, placed at the predicted pose."""
    from hbeo.model.verify import surface_points
    size = float(model.settings.object_size) * float(pred.scale[0])
    pts = surface_points(pred.grids[0], size)
    return pts @ pred.rotation[0].T + pred.translation[0]


def _subsample(pts: np.ndarray, n: int = 4000, seed: int = 0) -> np.ndarray:
    if len(pts) <= n:
        return pts
    return pts[np.random.default_rng(seed).choice(len(pts), n, replace=False)]


def _scatter_views(ax_row, layers, title_suffix=""):
    """Top (x-z) and side (z-y) views of point layers [(points (N, 3), label, colour), ...], camera frame."""
    for ax, (i, j, name) in zip(ax_row, ((0, 2, "top view"), (2, 1, "side view"))):
        for pts, label, colour in layers:
            if len(pts):
                ax.scatter(pts[:, i], pts[:, j], s=1.5, c=colour, label=label, alpha=0.6, linewidths=0)
        ax.set_xlabel(("x, right (m)", "y, down (m)", "z, forward (m)")[i])
        ax.set_ylabel(("x, right (m)", "y, down (m)", "z, forward (m)")[j])
        ax.set_aspect("equal", adjustable="datalim")
        if j == 1:
            ax.invert_yaxis()                   # y points down: up is up in the picture
        ax.set_title(name + title_suffix, fontsize=10)


def points_figure(frame: Frame):
    """The frame's object pixels back-projected (:func:`hbeo.conventions.backproject`) to camera-frame points:
    seen from above (x-z) and from the side (z-y)."""
    import matplotlib.pyplot as plt
    pts, _ = backproject(frame.object_depth, frame.intrinsics)
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    _scatter_views(ax, [(_subsample(pts), f"observed ({len(pts)} points)", "tab:blue")],
                   " of the back-projected points")
    ax[0].legend(loc="upper right", fontsize=8, markerscale=5)
    fig.tight_layout()
    return fig


def overlay_figure(model, frame: Frame, pred):
    """HBEO's completion placed at its predicted pose on the observed points: in the image (the completion's
    silhouette, :func:`hbeo.model.verify.shape_depth`, outlined on the depth), from above and from the side, and
    the completed grid in the canonical frame."""
    import matplotlib.pyplot as plt
    from hbeo.model.verify import shape_depth, surface_points
    obs, _ = backproject(frame.object_depth, frame.intrinsics)
    comp = _completion_points(model, pred)
    size = float(model.settings.object_size) * float(pred.scale[0])
    syn = shape_depth(surface_points(pred.grids[0], size), pred.rotation[0], pred.translation[0], frame.intrinsics)
    fig, ax = plt.subplots(1, 4, figsize=(16, 3.9), gridspec_kw={"width_ratios": [1.3, 1, 1, 0.9]})
    ax[0].imshow(np.ma.masked_less_equal(frame.object_depth, 0), cmap="Greys")
    if (syn > 0).any():                   # the z-buffered points leave gaps: close them into a silhouette
        from scipy import ndimage
        sil = ndimage.binary_fill_holes(ndimage.binary_closing(syn > 0, np.ones((5, 5), bool), iterations=2))
        ax[0].contour(sil, levels=[0.5], colors="tab:orange", linewidths=1.5)
    ax[0].set(title="image: depth (grey), completion's outline (orange)", xlabel="column u (px)", ylabel="row v (px)")
    _scatter_views(ax[1:3], [(_subsample(obs), "observed", "tab:blue"),
                             (_subsample(comp, seed=1), "completion", "tab:orange")])
    ax[1].legend(loc="upper right", fontsize=8, markerscale=5)
    ax[3].imshow(figures.render_voxels(pred.grids[0], size=160))
    ax[3].set_title(f"completed grid: {pred.class_names[0]} (canonical frame)", fontsize=10)
    ax[3].axis("off")
    fig.suptitle(f"HBEO's answer: {pred.class_names[0]} (p = {pred.probabilities[0].max():.2f}), "
                 f"completion at the predicted pose", fontsize=11)
    fig.tight_layout()
    return fig


# ----------------------------------------------------------------------------- files

def write_answer(run, model, model_path, frame: Frame, pred, verify: bool, rolls: int = 1) -> dict:
    """Write the completed mesh (:data:`MESH_FILE`, metres, camera frame: :meth:`HBEO.to_mesh`, as
    ``predict --mesh``) and the answer (:data:`ANSWER_JSON`: ``predict --out``'s keys (:meth:`hbeo.model.answer.Answer.to_json`), plus the intrinsics, the
    depth scale, the mask, the checks and, for the sample frame, the truth) into ``run``; returns the answer."""
    from hbeo.model.answer import Answer
    from hbeo.model.verify import VerifyConfig
    run = RunDir.of(run)
    K = frame.intrinsics
    extra = {"intrinsics": {"fx": K.fx, "fy": K.fy, "cx": K.cx, "cy": K.cy, "width": K.width, "height": K.height},
             "depth_scale": frame.depth_scale, "mask": str(frame.mask_path) if frame.mask_path else None,
             "source": frame.source, **model.answer_settings()}
    result = Answer(pred, pred, str(model_path), str(frame.depth_path), model.precision, rolls,
                    VerifyConfig().to_dict() if verify else None, extra).to_json()
    if frame.truth:
        result["truth"] = {"class": frame.truth["class"], "rotation": np.round(frame.truth["rotation"], 6).tolist(),
                           "translation_m": np.round(frame.truth["translation"], 6).tolist()}
    result["checks"] = checks(model, frame, pred).to_dict(orient="records")
    try:
        mesh = model.to_mesh(pred)
    except (ValueError, DataError) as err:        # an empty completion: no mesh, said in the answer
        result["mesh"], result["mesh_error"] = None, str(err)
    else:
        data = mesh.export(file_type=Path(MESH_FILE).suffix.lstrip("."))
        with atomic_file(run.path / MESH_FILE) as f:
            f.write(data.encode() if isinstance(data, str) else data)
        result["mesh"] = str(run.path / MESH_FILE)
    atomic_text(run.path / ANSWER_JSON, json_text(result, indent=2, default=_json_default))
    return result


def _json_default(o):
    if isinstance(o, (np.bool_,)):
        return bool(o)
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return float(o)
    raise TypeError(f"not JSON serializable: {type(o).__name__}")
