"""`HBEO`: one file holding a trained model, and the inference API.

The bundle holds HBEONet (configuration and weights), the object subspace, the model's camera (intrinsics of the
images it was trained on), class names and preprocessing settings. ``predict(depth, intrinsics, mask=None)`` takes
a user's depth image (metres, 0 = none) with its own intrinsics, brings it into the model's camera
(:mod:`hbeo.model.preprocess`), runs the network and back-projects the coefficients to a 30^3 grid. Poses come
back in the user's camera frame (R: object -> camera, see :mod:`hbeo.conventions`).

An input the model cannot have understood is never answered confidently (:mod:`hbeo.model.viewcheck`): it raises
:class:`~hbeo.errors.DataError`, or, usable but suspicious, gets ``warnings`` and ``low_confidence`` in its
:class:`Prediction`. The file format (``.hbeo``, never unpickled) is
:mod:`hbeo.model.modelfile`'s.
"""
from __future__ import annotations

import copy
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from hbeo.model.augment import mirror_depth, roll_depth
from hbeo.conventions import Intrinsics
from hbeo.rotations import matrix_to_axis_angle, z_angle_to_matrix
from hbeo.errors import DataError
from hbeo.limits import MAX_ROLLS, ROLL_BATCH, check_rolls, one_blas_thread
from hbeo.model.modelfile import ModelSettings, read_model, write_model
from hbeo.model.network import HBEONet, NetConfig, bin_cosines
from hbeo.model.preprocess import View, to_model_view
from hbeo.model.facing import MEDIAN, PLAIN, aims
from hbeo.model.viewcheck import check_view
from hbeo.subspace.basis import ObjectSubspace

#: inference precisions: float32 (default, exact) or bfloat16 (network weights and activations;
#: ~2.5x faster convolutions on CPUs with AVX512-BF16; class agreement with float32 ~99 %, see
#: benchmarks/README.md). The back-projection stays float32.
PRECISIONS = {"float32": torch.float32, "bfloat16": torch.bfloat16}

def _finite(x) -> bool:
    return isinstance(x, (int, float, np.integer, np.floating)) and not isinstance(x, bool) and math.isfinite(x)


def _batch(depth, mask) -> tuple:
    """(B, H, W) depth and a list of B masks (None each without ``mask``) from one image or a batch."""
    depth = np.asarray(depth)
    batch = depth[None] if depth.ndim == 2 else depth
    return batch, [None] * len(batch) if mask is None else (np.asarray(mask)[None] if np.ndim(mask) == 2 else mask)


def _build_net(cfg: dict) -> HBEONet:
    """The HBEONet a model file's ``net_cfg`` describes (JSON lists back to tuples)."""
    return HBEONet(NetConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in cfg.items()}))


@dataclass
class Prediction:
    """Outputs for a batch of B images (arrays lead with B)."""

    probabilities: np.ndarray     #: (B, C) class probabilities
    labels: np.ndarray            #: (B,) class indices
    class_names: list[str]        #: (B,)
    rotation: np.ndarray          #: (B, 3, 3) object -> user camera
    axis_angle: np.ndarray        #: (B, 3) radians
    translation: np.ndarray       #: (B, 3) estimated object centre, user camera frame, metres
    scale: np.ndarray             #: (B,) metres per training object_size unit (1 without distance normalization)
    coeffs: np.ndarray            #: (B, k) subspace coefficients
    grids: np.ndarray             #: (B, 30, 30, 30) bool completed shapes (canonical frame)
    timing_ms: dict = field(default_factory=dict)   #: per stage, whole batch
    warnings: list = field(default_factory=list)    #: (B,) lists of str: why an image's answer is doubtful
    low_confidence: np.ndarray | None = None        #: (B,) bool: the image has warnings (None: no checks run)
    #: rotation-bins models: (B, N) the network's distribution over its rotation grid (model's virtual
    #: camera, averaged over rolls); None for regression heads
    pose_probs: np.ndarray | None = None
    view_rotation: np.ndarray | None = None         #: (B, 3, 3) Q: virtual camera -> user camera
    #: (B,) dicts of verify's ``agreement``, ``kept_network``, ``n_hypotheses``, ``stride`` (None: not verified;
    #: :meth:`hbeo.model.verify.Verifier.apply`)
    verified: list | None = None

    def to_dict(self, i: int = 0) -> dict:
        """JSON-ready summary of image ``i``."""
        return {"class": self.class_names[i], "label": int(self.labels[i]),
                "probabilities": self.probabilities[i].round(6).tolist(),
                "rotation": self.rotation[i].round(6).tolist(), "axis_angle": self.axis_angle[i].round(6).tolist(),
                "translation_m": self.translation[i].round(6).tolist(), "scale": float(self.scale[i]),
                "coeffs": self.coeffs[i].round(6).tolist(), "occupied_voxels": int(self.grids[i].sum()),
                "low_confidence": bool(self.low_confidence[i]) if self.low_confidence is not None else False,
                "warnings": list(self.warnings[i]) if self.warnings else [],
                **({"verified": dict(self.verified[i])} if self.verified is not None else {}),
                "timing_ms": {k: round(v, 3) for k, v in self.timing_ms.items()}}


class HBEO:
    """A trained model: network + subspace + camera + classes + preprocessing settings.

    settings: a :class:`~hbeo.model.modelmeta.ModelSettings` (or a dict of its fields, the rest
    default): ``object_size`` (m, training objects' longest side), ``recenter`` (turn the view
    to the object), ``ref_distance`` (m or None: distance normalization), ``coeff_mean`` /
    ``coeff_std`` (k,) with which the network's coefficient output is de-standardized, and
    what the model was trained on (``render``, ``profile``, ...). ``self.settings`` is the
    frozen dataclass; read its attributes.
    """

    def __init__(self, net: HBEONet, subspace: ObjectSubspace, intrinsics: Intrinsics, classes,
                 settings: ModelSettings | dict | None = None, precision: str = "float32", prior_tau: float = 0.0):
        # channels_last: oneDNN's fast convolution layout on CPU (convolutions ~1.7x faster at 320x240)
        self.net = net.eval().to(memory_format=torch.channels_last)
        self.subspace = subspace
        self.intrinsics = intrinsics
        self.classes = tuple(classes)
        self.settings = ModelSettings.from_dict(settings or {})
        if net.cfg.n_coeffs != subspace.dim_:
            raise ValueError(f"network predicts {net.cfg.n_coeffs} coefficients, the subspace has {subspace.dim_}")
        if net.cfg.n_classes != len(self.classes):
            raise ValueError(f"network has {net.cfg.n_classes} classes, {len(self.classes)} names given")
        if tuple(net.cfg.image_size) != (intrinsics.width, intrinsics.height):
            raise ValueError(f"network input {net.cfg.image_size} does not match the camera "
                             f"{intrinsics.width}x{intrinsics.height}")
        if self.settings.class_counts is not None and len(self.settings.class_counts) != len(self.classes):
            raise ValueError(f"settings: class_counts has {len(self.settings.class_counts)} entries for "
                             f"{len(self.classes)} classes")
        self._roll_perms: dict = {}
        self.device = torch.device("cpu")
        #: other models whose answers :meth:`predict` averages with this one's (:meth:`add_members`), and their
        #: files' names and sha256 (what a metrics file records)
        self.members: list["HBEO"] = []
        self.member_files: list[dict] = []
        self.set_precision(precision)
        self.set_prior_tau(prior_tau)
        self.set_mirror(False)
        self.set_face_object(False)
        self.set_completion()

    def set_completion(self, rule=None, threshold: float | None = None) -> "HBEO":
        """How :meth:`predict` completes the back-projection (:mod:`hbeo.model.completion_rule`): ``"nonempty"``
        (the default, :data:`~hbeo.model.completion_rule.DEFAULT`: the threshold chosen on validation, and never an
        empty grid), ``"paper"`` (>= 0.5) or a :class:`~hbeo.model.completion_rule.CompletionRule`; ``threshold``
        overrides the rule's. Returns self."""
        from hbeo.model.completion_rule import DEFAULT, class_occupancy, rule as completion_rule
        self.completion = completion_rule(DEFAULT if rule is None else rule, threshold)
        self._occupancy = class_occupancy(self.subspace, self.classes) if self.completion.fallback else None
        return self

    def complete(self, coeffs, labels) -> np.ndarray:
        """Coefficients (B, k) of answers of class indices ``labels`` (B,) -> bool grids (B, 30, 30, 30) under the
        model's completion rule (:meth:`set_completion`; the class sets the never-empty rule's voxel count)."""
        fields = np.asarray(coeffs, np.float32)
        if self.completion.fallback:               # a never-empty rule (not the paper's)
            return self.completion.complete(self.subspace.reconstruct(fields),
                                            self._occupancy[np.asarray(labels, np.int64)])
        return self.subspace.reconstruct(fields, threshold=self.completion.threshold)

    def paper_grids(self, coeffs) -> np.ndarray:
        """Coefficients (B, k) -> bool grids (B, 30, 30, 30) under the paper's rule (back-projection >= 0.5),
        whatever the model's own: the grid scored beside, and the shape verify searches with."""
        return self.subspace.reconstruct(np.asarray(coeffs, np.float32), threshold=0.5)

    def set_mirror(self, mirror: bool) -> "HBEO":
        """Test-time mirror averaging of the class answer; returns self. With ``mirror``, :meth:`predict`
        also runs the network on each (rolled) input mirrored left-right about the principal point
        (:func:`hbeo.model.augment.mirror_depth`: exactly a view of the mirrored object) and averages the class
        probabilities over both; the rotation distribution, coefficients and completion stay the unmirrored
        passes' (the mirror plane that would turn them back is the class's own). Twice the network's cost."""
        if not isinstance(mirror, (bool, np.bool_)):
            raise ValueError(f"mirror must be True or False, got {mirror!r}")
        self.mirror = bool(mirror)
        return self

    def set_face_object(self, face: bool) -> "HBEO":
        """Turn each view toward the object's estimated centre before the network answers it, as far as the model
        needs (:mod:`hbeo.model.facing`: two passes), for a model trained without ``recenter`` and an object off the
        optical axis; returns self. The model's ``settings`` keep what it was trained with (``predict
        --face-object``)."""
        if not isinstance(face, (bool, np.bool_)):
            raise ValueError(f"face_object must be True or False, got {face!r}")
        self.face_object = bool(face)
        return self

    def view(self, depth, intrinsics: Intrinsics, mask=None, aim=None) -> View:
        """One depth image (H, W) metres with its ``intrinsics`` (and mask) in the model's camera, as :meth:`predict`
        gives it to the network (:func:`hbeo.model.preprocess.to_model_view`). ``aim``: None (the model's own
        setting), ``"plain"``, ``"median"`` or a direction (3,) (:mod:`hbeo.model.facing`; a prediction's Q: Q[:, 2])."""
        aim = (MEDIAN if self.settings.recenter else PLAIN) if aim is None else aim
        turned = not (isinstance(aim, str) and aim == PLAIN)
        return to_model_view(depth, intrinsics, self.intrinsics, mask, recenter=turned,
                             ref_distance=self.settings.ref_distance,
                             toward=None if isinstance(aim, str) else np.asarray(aim, np.float64))

    def answer_settings(self) -> dict:
        """What an answer's JSON records of how this model answered beside its class, pose and shape: the
        ``classes`` (the order of its probabilities), and ``face_object``, ``mirror``, ``completion`` (a rule other
        than the paper's) and ``ensemble`` (members' files) where they apply."""
        out = {"classes": list(self.classes)}
        if self.face_object:
            out["face_object"] = True
        if self.mirror:
            out["mirror"] = True
        if self.completion.name != "paper":
            out["completion"] = self.completion.to_dict()
        if self.members:
            out["ensemble"] = list(self.member_files)
        return out

    def set_prior_tau(self, tau: float, class_counts=None, source: str | None = None) -> "HBEO":
        """Prior correction (logit adjustment) of the class answer; returns self.

        The class probabilities become ``softmax(logits - tau * log(prior))``, ``prior`` the training
        class frequencies (Menon et al., "Long-tail learning via logit adjustment", ICLR 2021): ``tau``
        0 is the network's own answer (the paper's, the default), 1 divides its probabilities by the
        training prior (the answer a class-balanced training set would call Bayes-optimal). With
        ``rolls`` > 1 the roll-averaged probabilities are adjusted the same way. ModelNet10's training
        split is 9:1 between its largest and smallest class, its test split nearly balanced, and the
        paper's headline is the class-mean accuracy.

        ``class_counts`` (C,): the training images (or objects) per class; None: the model file's
        (:attr:`ModelSettings.class_counts`). ValueError when ``tau`` is not in [0, 1], or ``tau`` > 0 and
        no counts are known or a class has none, or the file's counts are asked for a class-balanced model
        (:attr:`ModelSettings.class_balance`). ``source`` says where given counts come from (recorded as
        :attr:`prior_source`; the file's are ``"model file"``)."""
        if not _finite(tau) or not 0 <= tau <= 1:
            raise ValueError(f"prior_tau must be a number in [0, 1], got {tau!r}")
        counts, where = class_counts, source or "given"
        if counts is None:
            counts, where = self.settings.class_counts, "model file"
            if tau > 0 and self.settings.class_balance != "none":
                raise ValueError(f"prior correction: this model was trained with class balance "
                                 f"{self.settings.class_balance!r}, so it saw its classes about equally often and "
                                 f"its file's class counts are not its prior (correcting by them would count the "
                                 f"imbalance twice); in Python, pass class_counts to correct by a prior of your own")
        log_prior = None
        if counts is not None:
            counts = np.asarray(counts, np.float64)
            if counts.shape != (len(self.classes),):
                raise ValueError(f"class_counts must have one entry per class ({len(self.classes)}), got shape "
                                 f"{counts.shape}")
            if tau > 0 and (counts <= 0).any():
                empty = [c for c, n in zip(self.classes, counts) if n <= 0]
                raise ValueError(f"prior correction: no training images of class {', '.join(empty)}")
            log_prior = np.log(np.maximum(counts, 1e-300) / counts.sum())
        elif tau > 0:
            raise ValueError("prior correction needs the training class counts, which this model file does not "
                             "hold (written before they were recorded); pass class_counts (e.g. "
                             "hbeo.data.datasets.training_class_counts of its dataset)")
        self.prior_tau = float(tau)
        self.prior_source = where if counts is not None else None
        self.class_counts = None if counts is None else tuple(int(c) for c in counts)
        self._log_prior = log_prior
        return self

    def adjust_probabilities(self, probs: np.ndarray) -> np.ndarray:
        """(B, C) class probabilities -> the same with the prior correction of :meth:`set_prior_tau`
        applied (renormalized; unchanged at ``prior_tau`` 0)."""
        if not self.prior_tau:
            return probs
        z = np.log(np.maximum(np.asarray(probs, np.float64), 1e-300)) - self.prior_tau * self._log_prior
        z = np.exp(z - z.max(1, keepdims=True))
        return (z / z.sum(1, keepdims=True)).astype(np.asarray(probs).dtype)

    def set_precision(self, precision: str) -> "HBEO":
        """Run the network in ``float32`` or ``bfloat16`` (:data:`PRECISIONS`); returns self.

        ``self.net`` keeps its float32 weights (they are what :meth:`save` writes); predictions use a
        copy whose layers hold ``precision`` weights (made now: change the weights first). The
        rotation-bin grid and all outputs stay float32 or better."""
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {tuple(PRECISIONS)}, got {precision!r}")
        self.precision = precision
        self._net = self.net
        if precision != "float32":
            self._net = copy.deepcopy(self.net)
            for m in self._net.modules():
                if isinstance(m, (torch.nn.Conv2d, torch.nn.Linear, torch.nn.BatchNorm2d)):
                    m.to(PRECISIONS[precision])
        for member in getattr(self, "members", ()):
            member.set_precision(precision)
        return self

    def add_members(self, models, files=None) -> "HBEO":
        """Average ``models`` (HBEO models trained like this one: other training seeds) with this one; returns self.

        :meth:`predict` then runs every network on each input (and each roll) and averages their class
        probabilities, their rotation distributions (before decoding, as rolls are) and their coefficients
        (each de-standardized with its own statistics); the time is the sum. The members must share this
        model's classes, camera, subspace, input preprocessing and rotation-bin grid (ValueError naming the
        difference); regression heads cannot be averaged. ``files``: the members' model files, recorded
        (name and sha256) in :attr:`member_files`. The precision and device are this model's. Not saved:
        :meth:`save` refuses an ensemble (save each member)."""
        models = list(models)
        files = [None] * len(models) if files is None else list(files)
        if len(files) != len(models):
            raise ValueError(f"{len(files)} file names for {len(models)} members")
        for i, (m, f) in enumerate(zip(models, files)):
            who = f"member {i}" + (f" ({Path(f).name})" if f else "")
            if m is self or m in self.members:
                raise ValueError(f"{who}: already in the ensemble")
            if m.members:
                raise ValueError(f"{who}: is itself an ensemble")
            diff = self._member_difference(m)
            if diff:
                raise ValueError(f"{who} cannot be averaged with this model: {diff}")
        from hbeo.storage import sha256_file
        for m, f in zip(models, files):
            m.set_precision(self.precision).to(self.device)
            self.members.append(m)
            self.member_files.append({"file": Path(f).name, "sha256": sha256_file(f)} if f else {"file": None})
        return self

    def _member_difference(self, m: "HBEO") -> str | None:
        """What keeps model ``m`` from being averaged with this one, or None."""
        if self.net.cfg.rotation != "bins" or m.net.cfg.rotation != "bins":
            return "an ensemble averages rotation distributions: both must be rotation-bins models"
        if tuple(m.classes) != tuple(self.classes):
            return f"classes {m.classes} differ from {self.classes}"
        if m.intrinsics != self.intrinsics:
            return "another camera (intrinsics)"
        for k in ("image_size", "n_classes", "n_coeffs", "rotation_bins"):
            if getattr(m.net.cfg, k) != getattr(self.net.cfg, k):
                return f"network {k} {getattr(m.net.cfg, k)} differs from {getattr(self.net.cfg, k)}"
        if not torch.equal(m.net.bin_rotations.cpu(), self.net.bin_rotations.cpu()):
            return "another rotation-bin grid"
        if not np.array_equal(m.subspace.basis_, self.subspace.basis_):
            return "another subspace (basis)"
        for k in ("object_size", "recenter", "ref_distance"):
            if getattr(m.settings, k) != getattr(self.settings, k):
                return f"settings {k} {getattr(m.settings, k)!r} differs from {getattr(self.settings, k)!r}"
        return None

    def to(self, device) -> "HBEO":
        """Run the network on ``device`` (``"cpu"``, ``"cuda"``, a torch.device); returns self. Inputs are
        prepared and outputs decoded as before (numpy on the CPU); only the network and the pose decoding
        run there. A file is always read onto the CPU (:meth:`load`)."""
        self.device = torch.device(device)
        self.net.to(self.device)
        if self._net is not self.net:
            self._net.to(self.device)
        self._roll_perms.clear()
        for m in self.members:
            m.to(device)
        return self

    # ------------------------------------------------------------ persistence
    def save(self, path) -> Path:
        """Write the model to one file, atomically (:mod:`hbeo.model.modelfile`; float32 weights
        whatever the precision). An ensemble (:meth:`add_members`) is refused: save each member."""
        if self.members:
            raise ValueError("an ensemble is not one model file: save each member (they are read together with "
                             "--ensemble)")
        meta = {"net_cfg": self.net.cfg.to_dict(), "classes": list(self.classes),
                "intrinsics": asdict(self.intrinsics), "settings": self.settings.to_dict()}
        return write_model(path, "hbeo", meta, self.net.state_dict(), self.subspace)

    @classmethod
    def load(cls, path, precision: str = "float32", prior_tau: float = 0.0, class_counts=None,
             counts_source: str | None = None, members=()) -> "HBEO":
        """Read a model file (:func:`hbeo.model.modelfile.read_model`: nothing is unpickled) onto the
        CPU; DataError naming the file on a missing, corrupt, old-format or inconsistent one.
        ``precision``: see :meth:`set_precision`; ``prior_tau``, ``class_counts``, ``counts_source``: see
        :meth:`set_prior_tau`; ``members``: other model files averaged with this one (:meth:`add_members`;
        DataError naming the member that cannot be)."""
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {tuple(PRECISIONS)}, got {precision!r}")
        if members:
            from hbeo.storage import sha256_file
            model = cls.load(path, precision, prior_tau, class_counts, counts_source)
            seen = {sha256_file(path): str(path)}
            for f in members:
                member = cls.load(f, precision)             # a bad file: its own DataError
                try:
                    model.add_members([member], [f])
                except ValueError as err:
                    raise DataError(f, f"not an ensemble member of {Path(path).name}: {err}") from None
                digest = model.member_files[-1]["sha256"]   # hashed once, by add_members
                if digest in seen:
                    raise DataError(f, f"the same model as {seen[digest]}: an ensemble averages different models "
                                       f"(other training seeds)")
                seen[digest] = str(f)
            return model
        mf = read_model(path, "hbeo", _build_net)
        m = mf.meta
        try:
            settings = ModelSettings.from_dict(m["settings"], path)
            model = cls(mf.net, mf.subspace, Intrinsics(**m["intrinsics"]), m["classes"], settings, precision)
        except DataError:
            raise
        except (TypeError, ValueError) as err:
            raise DataError(path, f"inconsistent model file ({err})") from None
        try:
            return model.set_prior_tau(prior_tau, class_counts, counts_source)
        except ValueError as err:
            raise DataError(path, str(err)) from None

    # ------------------------------------------------------------ inference
    @torch.inference_mode()
    def predict(self, depth, intrinsics: Intrinsics, mask=None, rolls: int = 1) -> Prediction:
        """Depth (H, W) or (B, H, W), metres, 0 = none, seen by ``intrinsics`` -> :class:`Prediction`.

        ``mask`` (same shape, bool) selects the object's pixels (default: all pixels > 0).
        ``rolls`` > 1 (rotation-bins models only): test-time augmentation over that many camera rolls
        about the optical axis (exact, :mod:`hbeo.model.augment`), ``rolls`` times the network's cost: the
        class probabilities and coefficients (roll-invariant) are averaged, and each roll's rotation
        distribution is turned back and averaged before decoding. The rolled images go through the
        network :data:`hbeo.limits.ROLL_BATCH` at a time (memory does not grow with ``rolls``);
        ``rolls`` above :data:`hbeo.limits.MAX_ROLLS` is refused (:class:`hbeo.limits.ResourceError`).
        numpy's BLAS runs on one thread meanwhile (:func:`hbeo.limits.one_blas_thread`: its spinning threads
        would slow the network down).
        """
        t0 = time.perf_counter()                   # the timing includes setting the limit (~25 us)
        with one_blas_thread():
            if not self.face_object or self.settings.recenter:
                return self._predict(depth, intrinsics, mask, rolls, t0)
            first = self._predict(depth, intrinsics, mask, rolls, t0, MEDIAN)      # two passes (facing)
            return self._predict(depth, intrinsics, mask, rolls, t0, aims(self, *_batch(depth, mask), intrinsics, first))

    def _predict(self, depth, intrinsics: Intrinsics, mask, rolls: int, t0: float, aim=None) -> Prediction:
        rolls = check_rolls(rolls, "rolls")      # a positive integer, at most MAX_ROLLS
        if rolls > 1 and self.net.cfg.rotation != "bins":
            raise ValueError(f"rolls > 1 needs a rotation-bins model; this one regresses {self.net.cfg.rotation}")
        if not isinstance(intrinsics, Intrinsics):
            raise TypeError(f"intrinsics must be an hbeo.conventions.Intrinsics, got {type(intrinsics).__name__}")
        depth = np.asarray(depth)
        if depth.ndim not in (2, 3) or depth.size == 0:
            raise ValueError(f"depth must be one image (H, W) or a batch (B, H, W) with pixels, got shape {depth.shape}")
        batch, masks = _batch(depth, mask)
        if len(masks) != len(batch):
            raise ValueError(f"{len(masks)} masks for {len(batch)} depth images")
        aim = [aim] * len(batch) if aim is None or isinstance(aim, str) else aim      # one per image
        views = [self.view(d, intrinsics, m, a) for d, m, a in zip(batch, masks, aim)]
        turned = self.settings.recenter or self.face_object
        warns = [check_view(v, self.intrinsics, self.settings, turned, i if len(views) > 1 else None)
                 for i, v in enumerate(views)]
        x0 = np.stack([v.depth for v in views])
        angles = [2 * math.pi * k / rolls for k in range(rolls)]
        nets = [(self._net, self.settings)] + [(m._net, m.settings) for m in self.members]
        one = rolls == 1 and len(nets) == 1             # one pass of one network: its own pose decoding
        net_s, prob_sum, coeff_sums, P, pose0 = 0.0, 0.0, [0.0] * len(nets), 0.0, None
        step = max(1, ROLL_BATCH // len(views))        # rolls per network pass: memory bounded whatever rolls is
        for r0 in range(0, rolls, step):
            part = angles[r0:r0 + step]
            x = np.concatenate([x0 if r0 + k == 0 else np.stack([roll_depth(d, self.intrinsics, a) for d in x0])
                                for k, a in enumerate(part)])
            xm = self._input(mirror_depth(x, self.intrinsics)) if self.mirror else None   # class answer only
            x = self._input(x)
            for j, (net, _) in enumerate(nets):
                tn = time.perf_counter()
                out = {k: v.float().view(len(part), len(views), -1) for k, v in net(x).items()}
                if xm is not None:
                    logits_m = net(xm)["logits"].float().view(len(part), len(views), -1)
                    prob_sum = prob_sum + torch.softmax(logits_m, dim=2).sum(0)
                if self.device.type == "cuda":
                    torch.cuda.synchronize(self.device)
                net_s += time.perf_counter() - tn
                prob_sum = prob_sum + torch.softmax(out["logits"], dim=2).sum(0)
                coeff_sums[j] = coeff_sums[j] + out["coeffs"].sum(0)
                if one:
                    pose0 = out["pose"][0]
                else:
                    p = torch.softmax(out["pose"].double(), dim=2)
                    P = P + sum(p[k][:, self._roll_permutation(a)] for k, a in enumerate(part))
        t2 = time.perf_counter()
        probs = self.adjust_probabilities((prob_sum / ((2 if self.mirror else 1) * rolls * len(nets))).cpu().numpy())
        pose_probs = None
        if one:
            R_virtual = self.net.pose_matrix(pose0.double()).cpu().numpy()
            if self.net.cfg.rotation == "bins":
                pose_probs = torch.softmax(pose0.double(), dim=1).cpu().numpy()
        else:
            P = P / (rolls * len(nets))
            R_virtual = self.net.pose_matrix(torch.log(P.clamp_min(1e-300))).cpu().numpy()
            pose_probs = P.cpu().numpy()
        Q = np.stack([v.Q for v in views])
        R = Q @ R_virtual
        coeffs = 0.0
        for (_, ms), c in zip(nets, coeff_sums):      # each network's output in its own standardization
            c = (c / rolls).cpu().numpy().astype(np.float64)
            if ms.coeff_std is not None:
                c = c * np.asarray(ms.coeff_std) + np.asarray(ms.coeff_mean)
            coeffs = coeffs + c
        coeffs = coeffs / len(nets)
        grids = self.complete(coeffs, probs.argmax(1))
        t3 = time.perf_counter()
        ref = self.settings.ref_distance
        scale = np.array([v.distance / ref if ref else 1.0 for v in views])
        trans = np.stack([v.center / np.linalg.norm(v.center) * v.distance for v in views])
        labels = probs.argmax(1)
        return Prediction(probs, labels, [self.classes[i] for i in labels], R, matrix_to_axis_angle(R), trans,
                          scale, coeffs, grids, {"preprocess": (t2 - t0 - net_s) * 1e3, "network": net_s * 1e3,
                                                 "reconstruct": (t3 - t2) * 1e3, "total": (t3 - t0) * 1e3},
                          warns, np.array([bool(w) for w in warns]), pose_probs, Q)

    def _input(self, x: np.ndarray) -> torch.Tensor:
        """Model views (N, H, W) as the network's input: (N, 1, H, W) on its device, in its precision."""
        return torch.from_numpy(x[:, None]).to(self.device, PRECISIONS[self.precision]).contiguous(
            memory_format=torch.channels_last)

    def _roll_permutation(self, angle: float) -> torch.Tensor:
        """(N,) index of the grid rotation nearest Rz(angle) G_j for each bin j (cached): a view rolled by
        ``angle`` sees the object at Rz(angle) R, so its probability for R = G_j sits at that bin."""
        cache = self._roll_perms
        key = round(angle, 12)
        if key not in cache:
            if len(cache) >= 4 * MAX_ROLLS:             # bounded: rolls of many different counts
                cache.clear()
            G = self.net.bin_rotations.float()
            RG = torch.from_numpy(z_angle_to_matrix(angle)).float().to(G.device) @ G
            cache[key] = torch.cat([bin_cosines(RG[i:i + 512], G).argmax(1) for i in range(0, len(G), 512)])
        return cache[key]

    def to_mesh(self, pred: Prediction, i: int = 0):
        """The completed shape of image ``i`` as a trimesh mesh placed in the user's camera frame
        (metres): grid surface, scaled, rotated by the predicted pose, moved to the estimated centre."""
        from hbeo.render.renderer import grid_mesh
        if not pred.grids[i].any():
            raise ValueError(f"the completed grid is empty (no back-projected voxel reaches {self.completion.threshold:g})")
        mesh = grid_mesh(pred.grids[i], object_size=self.settings.object_size * float(pred.scale[i]))
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = pred.rotation[i], pred.translation[i]
        mesh.apply_transform(T)
        return mesh
