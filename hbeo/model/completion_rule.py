"""How HBEO turns its back-projected coefficients into a completed grid: the paper's rule and a never-empty one.

HBEO predicts subspace coefficients o' (k,) and back-projects them, o_hat = W o' (a float 30^3 field in the
canonical frame, :meth:`hbeo.subspace.basis.ObjectSubspace.reconstruct`); a rule (:class:`CompletionRule`) makes
the bool (30, 30, 30) completion of it:

``paper`` (:data:`PAPER`)
    voxels with o_hat >= 0.5, the paper's rule. A regressed shape whose thin parts (table and chair legs, a
    desk's top, a monitor's screen) stay below 0.5 everywhere completes to an empty grid: 114 of the ModelNet10
    reference model's 2,721 test completions.
``nonempty`` (:data:`NONEMPTY`, :data:`DEFAULT`: what HBEO answers unless asked otherwise)
    voxels with o_hat >= :data:`NONEMPTY_THRESHOLD`, a threshold chosen on validation queries (never test ones:
    :func:`hbeo.evaluation.decompose.choose_threshold`, the lowest mean e' of this rule over a fixed scan on the
    reference model's validation views); when no voxel reaches it, the k voxels of largest o_hat, k the occupancy
    of the predicted class's mean shape (the sum of its mean field clipped to [0, 1], rounded, at least 1:
    :func:`class_occupancy`). Every answer then has at least one filled voxel. A deviation from the paper;
    an HBEO evaluation under it also scores the paper's rule on the same queries (``completion_paper``).

How the metrics treat an empty grid (:mod:`hbeo.subspace.metrics`): its distance field is the grid's diagonal
R sqrt(3) (~52 voxels at R = 30) everywhere, so an empty completion of a non-empty target scores e' of
several thousand (~7,450 on ModelNet10's test objects, ten times HBEO's mean), IoU 0, and the naive score e
exactly 0 (1 - ||o|| / ||o||). A never-empty rule removes those worst cases; it is an option, not the paper's method.

Imports numpy only (a subspace is passed in).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: the never-empty rule's threshold: the lowest mean e' of the never-empty rule itself over 0.1, 0.15, ..., 0.5 on
#: the reference model's 1,191 validation queries (:func:`hbeo.evaluation.decompose.choose_threshold`, the rule's
#: second version; results/cpu-modelnet10-vox30/06_completion_decomposition.csv, section ``validation``: 276 at
#: 0.25 against 280 at 0.2 and 383 at 0.5). The first version (scored on the paper's rule, 0.2 to 0.5) chose 0.2.
NONEMPTY_THRESHOLD = 0.25
#: the rules :meth:`hbeo.model.inference.HBEO.set_completion` and ``--completion`` take
RULES = ("paper", "nonempty")


@dataclass(frozen=True)
class CompletionRule:
    """A completion rule (see the module docstring): filled where the back-projection reaches ``threshold``;
    with ``fallback``, an empty result becomes the k voxels of largest back-projection instead."""

    name: str
    threshold: float = 0.5
    fallback: bool = False

    def __post_init__(self):
        if not (isinstance(self.threshold, (int, float)) and 0 < float(self.threshold) < 1):
            raise ValueError(f"completion threshold must be in (0, 1), got {self.threshold!r}")

    def to_dict(self) -> dict:
        return {"name": self.name, "threshold": float(self.threshold), "fallback": bool(self.fallback)}

    def complete(self, fields: np.ndarray, k=None) -> np.ndarray:
        """Float fields (B, R, R, R) -> bool grids (B, R, R, R); ``k`` (B,) voxels to keep where a grid would be
        empty (needed with ``fallback``)."""
        fields = np.asarray(fields)
        grids = fields >= self.threshold
        if not self.fallback:
            return grids
        if k is None:
            raise ValueError(f"completion rule {self.name!r} needs k (voxels to keep when nothing passes)")
        k = np.broadcast_to(np.asarray(k, np.int64), (len(fields),))
        empty = ~grids.reshape(len(grids), -1).any(1)
        for i in np.flatnonzero(empty):
            grids[i] = top_k(fields[i], int(k[i]))
        return grids


PAPER = CompletionRule("paper", 0.5, False)
NONEMPTY = CompletionRule("nonempty", NONEMPTY_THRESHOLD, True)
#: the rule HBEO completes by unless asked otherwise (``--completion``; :meth:`hbeo.model.inference.HBEO.set_completion`)
DEFAULT = "nonempty"


def rule(name: str, threshold: float | None = None) -> CompletionRule:
    """The rule called ``name`` (:data:`RULES`), at ``threshold`` when given (the rule's own otherwise)."""
    if isinstance(name, CompletionRule):
        return name
    base = {"paper": PAPER, "nonempty": NONEMPTY}.get(name)
    if base is None:
        raise ValueError(f"completion rule must be one of {', '.join(RULES)}, got {name!r}")
    return base if threshold is None else CompletionRule(base.name, float(threshold), base.fallback)


def of_record(record) -> CompletionRule:
    """The rule a metrics file or answer recorded (its ``completion_rule`` dict; None or absent: files written
    before the key existed, or under the paper's rule, which leaves no key)."""
    if not record:
        return PAPER
    try:
        return CompletionRule(str(record["name"]), float(record["threshold"]), bool(record["fallback"]))
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"completion_rule {record!r} is not a rule ({err})") from None


def top_k(field: np.ndarray, k: int) -> np.ndarray:
    """Bool grid of ``field``'s shape: its ``k`` largest values (ties by position; 1 <= k <= size)."""
    field = np.asarray(field)
    k = int(min(max(k, 1), field.size))
    flat = np.zeros(field.size, bool)
    flat[np.argsort(-field.ravel(), kind="stable")[:k]] = True
    return flat.reshape(field.shape)


def class_occupancy(subspace, classes) -> np.ndarray:
    """(C,) int: for each of ``classes``, the occupancy of its mean shape, round(sum(clip(mean field, 0, 1))),
    at least 1: the voxel count the never-empty rule keeps for an answer of that class."""
    return np.array([max(1, int(round(float(np.clip(subspace.eigen_object(c), 0, 1).sum())))) for c in classes],
                    np.int64)
