"""What the evaluation needs from a method: the :class:`Method` protocol, HBEO's adapter to it, and
the display label of each (method, pose setting).

A method is anything that answers one rendered view (scikit-learn's estimator contract in
small; :func:`hbeo.evaluation.evaluate.evaluate_methods` is its one loop, ``tests/test_methods.py``
the conformance suite every registered method passes):

``name``
    the registry name (:data:`hbeo.baselines.methods.METHODS`: ``hbeo``, ``beo``, ``icp``,
    ``voxcnn``), which the metrics dict records as ``method``.
``poses``
    the pose settings it takes (``known``, ``1dof``, ``3dof``), its default first.
``predict_view(depth, intrinsics, R_true, t_true, object_size, pose, label_true, rng) -> dict``
    one depth image (H, W), metres, 0 = none, seen by ``intrinsics``, ->
    ``{"probabilities": (C,), "rotation": (3, 3) object -> camera, "grid": (30, 30, 30) bool}``,
    optionally ``"label"`` (the class index, when it is not the probabilities' argmax) and
    ``"ms"`` (the method's own timing of the answer; otherwise the loop times the call). What
    of the truth it may use is the paper's protocol (:mod:`hbeo.baselines.methods`).
``describe() -> dict``
    what the metrics dict records of the method's own settings beyond name and pose (HBEO:
    ``precision``, ``rolls``, ``mirror``, ``verify``, ``prior_tau``, ``class_prior`` and ``ensemble``: the files of the
    models averaged with it, or None; ``completion`` only when not the paper's rule; a baseline: ``{}``).

Preparation is not the loop's: a method arrives ready to answer (a baseline fitted or loaded by
:func:`hbeo.baselines.methods.load_method`, HBEO loaded and wrapped in :class:`HBEOMethod`).
The evaluation's camera, views and classes come from an
:class:`hbeo.evaluation.evaluate.EvaluationSetup`, not from the method.

The metrics dicts carry ``method`` and ``pose``; tables, figures, the paired statistics and the
report all name a method by :func:`label`, from one table (:data:`LABELS`).

May import: the foundation modules (and :mod:`hbeo.model.verify`, lazily, for HBEO's verify step).
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

#: Display label of each (method, pose) pair; :func:`label` falls back to ``"method (pose)"``.
LABELS = {("hbeo", "3dof"): "HBEO (3-DOF)", ("hbeo-verify", "3dof"): "HBEO + rolls + verify (3-DOF, ours)",
          ("beo", "known"): "BEO (known pose)", ("beo", "1dof"): "BEO (1-DOF)",
          ("beo", "3dof"): "BEO (3-DOF, true class)", ("icp", "3dof"): "ICP (3-DOF, true class)",
          ("icp", "1dof"): "ICP (1-DOF, true class)", ("voxcnn", "known"): "3-D CNN on partial grid (known pose)",
          ("class_mean", "-"): "class mean shape (HBEO's class)"}


def label(metrics: dict) -> str:
    """The display label of a metrics dict (``+ verify`` added when HBEO's answers were verified;
    ``rolls`` dropped from the verified setting's label when its metrics record one roll, as a model
    without rotation bins answers)."""
    key = (metrics["method"], metrics["pose"])
    name = LABELS.get(key, f"{key[0]} ({key[1]})")
    if metrics.get("rolls") == 1:
        name = name.replace("+ rolls + verify", "+ verify")
    return name + (" + verify" if metrics.get("verify") and "verify" not in name else "")


@runtime_checkable
class Method(Protocol):
    """The contract every evaluated method implements (see the module docstring)."""

    name: str
    poses: tuple[str, ...]

    def predict_view(self, depth, intrinsics, R_true, t_true, object_size: float = 1.0, pose: str = "3dof",
                     label_true=None, rng=None) -> dict: ...

    def describe(self) -> dict: ...


class _SharedPrediction:
    """HBEO's prediction of the last depth image asked (by identity), shared by the adapters of one
    model so that several verify settings of one sweep run the network once per view."""

    def __init__(self):
        self.depth, self.pred, self.verified = None, None, {}

    def get(self, model, depth, intrinsics, rolls: int):
        if depth is not self.depth:
            self.depth, self.pred, self.verified = depth, model.predict(depth, intrinsics, rolls=rolls), {}
        return self.pred


class HBEOMethod:
    """:class:`Method` adapter of an :class:`hbeo.model.inference.HBEO` model: HBEONet's one-shot
    answer (``rolls``: test-time roll averaging), optionally verified against the view
    (``verify``: a :class:`hbeo.model.verify.VerifyConfig`). The truth arguments are ignored;
    ``ms`` is the model's own timing (preprocessing + network + back-projection, + verify).

    ``share``: another HBEOMethod of the same model whose prediction of the same depth image
    (the same array object) this one reuses instead of running the network again
    (:func:`hbeo.evaluation.sweep.verify_sweep`); ``min_agreement``: answer with this method's
    verified result only where verify's agreement reaches it, else with HBEO's own answer (the
    time stays the verified one's): a threshold derived from the same verification."""

    name = "hbeo"
    poses = ("3dof",)

    def __init__(self, model, rolls: int = 1, verify=None, share: "HBEOMethod | None" = None,
                 min_agreement: float | None = None):
        self.model, self.rolls, self.verify, self.min_agreement = model, int(rolls), verify, min_agreement
        self._shared = None
        if share is not None:
            if share.model is not model or share.rolls != self.rolls:
                raise ValueError("share: an HBEOMethod of the same model and rolls")
            share._shared = share._shared or _SharedPrediction()
            self._shared = share._shared
        self._base = share if min_agreement is not None else None
        if min_agreement is not None and (share is None or share.verify is None):
            raise ValueError("min_agreement derives from a verified HBEOMethod: pass it as share")
        self._verifier = None
        if verify is not None and min_agreement is None:
            from hbeo.model.verify import Verifier
            self._verifier = Verifier(model, verify)

    def describe(self) -> dict:
        verify = self.verify if self.min_agreement is None else _with_agreement(self.verify, self.min_agreement)
        tau = getattr(self.model, "prior_tau", 0.0)
        prior = None if not tau else {"tau": tau, "source": self.model.prior_source,
                                      "counts": list(self.model.class_counts)}
        members = getattr(self.model, "member_files", None)
        return {"precision": getattr(self.model, "precision", "float32"), "rolls": self.rolls,
                "mirror": bool(getattr(self.model, "mirror", False)),
                "verify": verify.to_dict() if verify is not None else None, "prior_tau": tau, "class_prior": prior,
                "ensemble": list(members) if members else None, **_completion(self.model)}

    def _prediction(self, depth, intrinsics):
        if self._shared is None:
            return self.model.predict(depth, intrinsics, rolls=self.rolls)
        return self._shared.get(self.model, depth, intrinsics, self.rolls)

    def _verified(self, depth, intrinsics, p) -> dict:
        if self._shared is None:
            return self._verifier.verify(depth, intrinsics, p)
        key = id(self)
        if key not in self._shared.verified:
            self._shared.verified[key] = self._verifier.verify(depth, intrinsics, p)
        return self._shared.verified[key]

    @property
    def batchable(self) -> bool:
        """Whether :meth:`predict_views` answers as :meth:`predict_view` does: the one network pass (rolls
        allowed), not verify, not an agreement threshold or a shared prediction."""
        return self._verifier is None and self._base is None and self._shared is None

    def predict_views(self, depths, intrinsics) -> list[dict]:
        """Depth images (B, H, W) -> the answers :meth:`predict_view` gives each (pose ``3dof``), from one call of
        the network on the batch; each ``ms`` is the batch's time over B."""
        if not self.batchable:
            raise ValueError("predict_views is HBEO's one network pass: not with verify or a shared prediction")
        p = self.model.predict(np.asarray(depths, np.float32), intrinsics, rolls=self.rolls)
        ms = p.timing_ms["total"] / len(p.labels)
        paper = self.model.paper_grids(p.coeffs) if self.model.completion.name != "paper" else None
        return [{"label": int(p.labels[i]), "probabilities": p.probabilities[i], "rotation": p.rotation[i],
                 "grid": p.grids[i], "ms": ms, **({"grid_paper": paper[i]} if paper is not None else {})}
                for i in range(len(p.labels))]

    def predict_view(self, depth, intrinsics, R_true=None, t_true=None, object_size: float = 1.0,
                     pose: str = "3dof", label_true=None, rng=None) -> dict:
        if pose != "3dof":
            raise ValueError(f"HBEO estimates all three degrees of freedom (pose '3dof'), got {pose!r}")
        p = self._prediction(depth, intrinsics)
        own = {"label": int(p.labels[0]), "probabilities": p.probabilities[0], "rotation": p.rotation[0],
               "grid": p.grids[0], "ms": p.timing_ms["total"]}
        if self.model.completion.name != "paper":      # the paper's rule on the same coefficients, scored beside
            own["grid_paper"] = self.model.paper_grids(p.coeffs[:1])[0]
        if self._base is not None:
            base = self._base.predict_view(depth, intrinsics, pose=pose)
            return base if base["agreement"] >= self.min_agreement else {**own, "ms": base["ms"]}
        if self._verifier is None:
            return own
        x = self._verified(depth, intrinsics, p)
        out = {"label": int(x["label"]), "probabilities": x["probabilities"], "rotation": x["rotation"],
               "grid": x["grid"], "ms": p.timing_ms["total"] + x["ms"], "agreement": x["agreement"]}
        if "grid_paper" in own:
            out["grid_paper"] = x["grid_paper"]
        return out


def _completion(model) -> dict:
    """``{"completion": rule dict}`` when the model completes by another rule than the paper's
    (:meth:`hbeo.model.inference.HBEO.set_completion`), else ``{}`` (the paper's leaves no key)."""
    rule = getattr(model, "completion", None)
    return {} if rule is None or rule.name == "paper" else {"completion": rule.to_dict()}


def _with_agreement(cfg, x: float):
    from dataclasses import replace
    return replace(cfg, min_agreement=float(x))


def answer_label(out: dict) -> int:
    """The class index of a :meth:`Method.predict_view` answer: its ``label``, else the argmax of
    its probabilities."""
    return int(out["label"]) if "label" in out else int(np.argmax(out["probabilities"]))
