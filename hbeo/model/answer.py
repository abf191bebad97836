"""HBEO's answer for one depth image: predict, then (optionally) verify, and the answer as JSON.

:class:`Predictor` is the one "predict then verify" set-up: the network's answer
(:meth:`hbeo.model.inference.HBEO.predict`, ``rolls`` camera rolls averaged) checked against the depth by
:class:`hbeo.model.verify.Verifier` (its per-model set-up done once) when a :class:`VerifyConfig` is given;
the CLI's ``predict`` and notebook 08 (:mod:`hbeo.lessons.yourdepth`) use it; the evaluation's
:class:`hbeo.evaluation.method.HBEOMethod` drives the same :class:`~hbeo.model.verify.Verifier` per view, sharing
one network answer between the verify settings of a sweep. :func:`predict_file` reads a depth file (and mask) as
``python -m hbeo predict`` does and returns an :class:`Answer`, whose :meth:`Answer.to_json` is ``predict
--out``'s JSON.

May import: foundation, data, subspace, render, and the other hbeo.model modules.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hbeo.errors import DataError


class Predictor:
    """``Predictor(model, rolls=1, verify=None)(depth, K, mask=None)`` -> (answer, network): HBEO's
    :class:`~hbeo.model.inference.Prediction` of one depth image (H, W) metres with intrinsics ``K``, verified
    against the (masked) depth when ``verify`` (a :class:`hbeo.model.verify.VerifyConfig`) is given, and
    the network's own answer (the same object without ``verify``). ``source``: a path named by a DataError
    when the model cannot see the input."""

    def __init__(self, model, rolls: int = 1, verify=None):
        self.model, self.rolls, self.verify = model, rolls, verify
        self.verifier = None
        if verify is not None:
            from hbeo.model.verify import Verifier
            self.verifier = Verifier(model, verify)

    def __call__(self, depth: np.ndarray, K, mask: np.ndarray | None = None, source=None):
        try:
            net = self.model.predict(depth, K, mask, rolls=self.rolls)
        except DataError as err:              # an input the model cannot see: name the depth file
            if source is None:
                raise
            raise DataError(source, err.problem) from None
        if self.verifier is None:
            return net, net
        return self.verifier.apply(depth * mask if mask is not None else depth, K, net), net


def verify_config(verify: bool, settings: str | None = None):
    """The :class:`hbeo.model.verify.VerifyConfig` that ``--verify`` and ``--verify-set KEY=VALUE,...`` ask
    for, or None; HBEOError for settings without ``verify`` or settings the config refuses."""
    from hbeo.errors import HBEOError
    if settings and not verify:
        raise HBEOError("--verify-set needs --verify")
    if not verify:
        return None
    from hbeo.model.verify import VerifyConfig       # (imports torch: only when asked for)
    try:
        return VerifyConfig.parse(settings)
    except ValueError as err:
        raise HBEOError(f"--verify-set: {err}") from None


def predict(model, depth, K, mask=None, rolls: int = 1, verify=None, source=None):
    """One image through :class:`Predictor`: returns (answer, network)."""
    return Predictor(model, rolls, verify)(depth, K, mask, source)


@dataclass
class Answer:
    """HBEO's answer for one depth file: ``prediction`` (a one-image
    :class:`~hbeo.model.inference.Prediction`; ``network`` the network's own before verification), which
    model and input produced it and how (precision, rolls, verify settings). Class, pose, shape and warnings
    are the prediction's (:attr:`cls`, :attr:`rotation`, :attr:`grid`, :attr:`warnings`)."""

    prediction: object
    network: object
    model: str
    depth: str
    precision: str
    rolls: int = 1
    verify: dict | None = None
    extra: dict = field(default_factory=dict)
    prior_tau: float = 0.0

    @property
    def cls(self) -> str:
        return self.prediction.class_names[0]

    @property
    def rotation(self) -> np.ndarray:
        return self.prediction.rotation[0]

    @property
    def grid(self) -> np.ndarray:
        return self.prediction.grids[0]

    @property
    def warnings(self) -> list[str]:
        return list(self.prediction.warnings[0]) if self.prediction.warnings else []

    def to_json(self) -> dict:
        """``predict --out``'s keys: model, depth, precision, rolls, verify, prior_tau, then the prediction's
        (:meth:`~hbeo.model.inference.Prediction.to_dict`: class, probabilities, rotation, axis_angle,
        translation_m, scale, coeffs, ..., warnings, timing_ms), then any ``extra``."""
        return {"model": self.model, "depth": self.depth, "precision": self.precision, "rolls": self.rolls,
                "verify": self.verify, "prior_tau": self.prior_tau, **self.prediction.to_dict(0), **self.extra}


#: file types ``predict --mesh`` writes (trimesh's exporters)
MESH_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb")


def predict_file(model_path, depth_path, intrinsics: str, mask_path=None, depth_scale: float | None = None,
                 rolls: int = 1, verify=None, precision: str = "float32", out=None, mesh_path=None,
                 prior_tau: float = 0.0, members=(), mirror: bool = False, completion: str | None = None,
                 face_object: bool = False) -> Answer:
    """``python -m hbeo predict``: read ``depth_path`` (16-bit PNG in mm or float ``.npy``/``.tiff`` in m,
    times ``depth_scale``), its ``intrinsics`` ``"fx,fy,cx,cy"`` and optional mask file
    (:mod:`hbeo.model.depthfile`), and answer with the model file ``model_path`` (network arithmetic
    ``precision``, prior correction ``prior_tau`` with the file's training class counts:
    :meth:`hbeo.model.inference.HBEO.set_prior_tau`; a file without them is refused) through :class:`Predictor`. With ``out``, the answer's JSON (:meth:`Answer.to_json`) is
    written there; with ``mesh_path``, the completed shape placed in the camera frame
    (:meth:`hbeo.model.inference.HBEO.to_mesh`); both files are complete before either is renamed into
    place, and a bad output path (or one naming an input) fails before any work. DataError names the file
    at fault. ``members``: model files averaged with ``model_path``'s (:meth:`hbeo.model.inference.HBEO.add_members`;
    the answer's ``ensemble`` names them). ``mirror``: the class answer averaged with the mirrored image's
    (:meth:`hbeo.model.inference.HBEO.set_mirror`; the answer's ``mirror`` says so). ``completion``: the completion
    rule (:meth:`hbeo.model.inference.HBEO.set_completion`; None: its default, never empty; another than ``paper`` is
    named in the answer's ``completion``). ``face_object``: the view is turned toward the object's estimated centre
    as far as the model needs (:meth:`hbeo.model.inference.HBEO.set_face_object`; the answer's ``face_object`` says
    so)."""
    from hbeo.model.depthfile import parse_intrinsics, read_depth, read_mask
    from hbeo.limits import check_rolls
    from hbeo.storage import atomic_files, check_outputs, json_text
    if out is not None or mesh_path is not None:
        check_outputs({"--out": out, "--mesh": mesh_path}, {"--depth": depth_path, "--mask": mask_path,
                                                            "--model": model_path,
                                                            **{f"--ensemble {f}": f for f in members}})
    check_rolls(rolls)                                  # before the model is read
    if mesh_path and Path(mesh_path).suffix.lower() not in MESH_SUFFIXES:
        raise DataError(mesh_path, f"--mesh: unsupported mesh format; expected {', '.join(MESH_SUFFIXES)}")
    depth = read_depth(depth_path, depth_scale)
    K = parse_intrinsics(intrinsics, depth.shape[1], depth.shape[0])
    mask = read_mask(mask_path, depth.shape) if mask_path else None
    if mask is not None and not (mask & (depth > 0)).any():
        raise DataError(mask_path, f"the mask covers no measured pixel of the depth image {depth_path}")
    from hbeo.model.inference import HBEO           # torch: once the inputs are known good
    model = HBEO.load(model_path, precision=precision, prior_tau=prior_tau, members=members).set_mirror(mirror)
    model.set_completion(completion).set_face_object(face_object)
    pred, net = Predictor(model, rolls, verify)(depth, K, mask, source=depth_path)
    answer = Answer(pred, net, str(model_path), str(depth_path), model.precision, rolls,
                    verify.to_dict() if verify is not None else None, prior_tau=model.prior_tau)
    answer.extra.update(model.answer_settings())      # classes, face_object, mirror, completion, ensemble
    data = None
    if mesh_path:
        mesh = model.to_mesh(pred)                    # fails before anything is written
        answer.extra["mesh"] = str(mesh_path)
        data = mesh.export(file_type=Path(mesh_path).suffix.lstrip(".").lower())
        data = data.encode() if isinstance(data, str) else data
    writes = [(out, "w", json_text(answer.to_json(), indent=2))] if out is not None else []
    writes += [(mesh_path, "wb", data)] if data is not None else []
    with atomic_files([(path, mode) for path, mode, _ in writes]) as files:   # all complete before any is renamed
        for f, (_, _, content) in zip(files, writes):
            f.write(content)
    return answer
