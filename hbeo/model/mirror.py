"""Mirror augmentation in training: a view mirrored left-right together with its labels.

A depth image mirrored about the principal point (:func:`hbeo.model.augment.mirror_depth`) is exactly the view
of the object mirrored by any reflection F_obj of its frame, at the rotation F R F_obj (F = diag(-1, 1, 1), the
camera's x). For the labels to stay those of a normal member of the class, F_obj must be the class's own
left-right reflection: ModelNet aligns each class alone (chairs' backs toward +y, sofas' toward +x, :mod:`hbeo.conventions`),
so :func:`mirror_axes` picks, per class, the horizontal object axis whose flip leaves the class's mean training
grid most like itself (a mirrored chair still faces the way every chair faces). :class:`MirrorAugment` mirrors
each item with probability 1/2: depth, rotation (:func:`mirror_rotation`), axis-angle, and the coefficients
replaced by those of the object's grid flipped across that axis (:func:`mirror_targets`, from the run's grids).

Shapes: grids (N, 30, 30, 30) bool, i, j, k along the object's x, y, z; rotations (..., 3, 3) object -> camera;
depth (1, H, W) metres in the model's view.

May import: foundation, data, subspace and hbeo.model.augment.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch.utils.data import Dataset
from hbeo.progress import tqdm

from hbeo.conventions import Intrinsics
from hbeo.data.gridset import GridSet
from hbeo.errors import DataError
from hbeo.model.augment import mirror_depth
from hbeo.rotations import matrix_to_axis_angle
from hbeo.subspace.basis import ObjectSubspace


#: object axes a class's mirror plane may be normal to: the horizontal ones (x, y); +z is up
MIRROR_AXES = (0, 1)


def mirror_axes(grids: np.ndarray, labels, n_classes: int) -> tuple[int, ...]:
    """For each class, the horizontal object axis (0: x, 1: y) across which the class mirrors: the one whose
    flip leaves the class's mean training grid most like itself (the IoU of the soft grids, sum of minima over
    sum of maxima). grids (N, 30, 30, 30) with i, j, k along x, y, z (:mod:`hbeo.conventions`); labels (N,).
    ModelNet aligns each class alone (chairs' backs toward +y, sofas' toward +x), so the axis is per class.
    ValueError for a class with no grid."""
    labels = np.asarray(labels)
    out = []
    for c in range(n_classes):
        sel = np.flatnonzero(labels == c)
        if not len(sel):
            raise ValueError(f"mirror_axes: class {c} has no training grid")
        mean = np.zeros(grids.shape[1:], np.float64)
        for i in range(0, len(sel), 256):                     # bounded memory however many grids
            mean += grids[sel[i:i + 256]].sum(0, dtype=np.float64)
        mean /= len(sel)
        score = [np.minimum(mean, np.flip(mean, a)).sum() / max(np.maximum(mean, np.flip(mean, a)).sum(), 1e-12)
                 for a in MIRROR_AXES]
        out.append(MIRROR_AXES[int(np.argmax(score))])
    return tuple(out)


def mirror_rotation(R: np.ndarray, axis: int) -> np.ndarray:
    """(..., 3, 3) object -> camera rotation of an object -> that of the object mirrored across the plane normal
    to its ``axis``, seen in the left-right mirrored image: ``F R F_obj`` with F = diag(-1, 1, 1) (the camera's
    x) and F_obj the object's reflection; a proper rotation again."""
    R = np.asarray(R, np.float64)
    out = R.copy()                                            # F R F_obj: signs of row 0 and column `axis`
    out[..., 0, :] *= -1
    out[..., :, axis] *= -1
    return out


class MirrorAugment(Dataset):
    """Items of a view dataset (``depth`` (1, H, W) in the model's view, ``label``, ``rotation``, ``axis_angle``,
    ``coeffs`` (k,) standardized, ``object_index``) mirrored with probability 1/2 each time they are read:
    the depth by :func:`mirror_depth`, the rotation by :func:`mirror_rotation` across the item's class's axis
    (``axes``, from :func:`mirror_axes`), the coefficients replaced by ``mirrored_coeffs[object_index]`` (the
    standardized coefficients of the object's grid flipped across that axis). The draw comes from torch's
    global generator, so a seeded run (and its exact resume) repeats. Wrap it in :class:`RollAugment` to roll
    the mirrored views too."""

    def __init__(self, base: Dataset, K: Intrinsics, axes, mirrored_coeffs: np.ndarray):
        if not math.isclose(K.cx, (K.width - 1) / 2) or not math.isclose(K.cy, (K.height - 1) / 2):
            raise ValueError(f"mirror augmentation needs the principal point at the image centre, got cx={K.cx}, "
                             f"cy={K.cy} for {K.width}x{K.height}")
        self.base, self.K, self.axes = base, K, tuple(int(a) for a in axes)
        if any(a not in MIRROR_AXES for a in self.axes):
            raise ValueError(f"mirror axes must be among {MIRROR_AXES}, got {self.axes}")
        self.mirrored_coeffs = np.asarray(mirrored_coeffs, np.float32)

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        item = self.base[i]
        if float(torch.rand(()).item()) >= 0.5:
            return item
        return mirror_item(item, self.K, self.axes[int(item["label"])],
                           self.mirrored_coeffs[int(item["object_index"])])


def mirror_item(item: dict, K: Intrinsics, axis: int, coeffs: np.ndarray) -> dict:
    """A copy of view item ``item`` mirrored left-right, its object mirrored across ``axis`` (coefficients
    ``coeffs``: those of the mirrored object, standardized as the item's)."""
    item = dict(item)
    R = mirror_rotation(item["rotation"].double().numpy(), axis)
    item["depth"] = torch.from_numpy(mirror_depth(item["depth"].numpy(), K))
    item["rotation"] = torch.from_numpy(R.astype(np.float32))
    item["axis_angle"] = torch.from_numpy(matrix_to_axis_angle(R).astype(np.float32))
    item["coeffs"] = torch.from_numpy(np.array(coeffs, np.float32))
    return item


def mirror_targets(run, data, train_idx, progress: bool = True) -> tuple[tuple[int, ...], np.ndarray]:
    """What :class:`MirrorAugment` needs for ``data`` (a :class:`hbeo.model.trainingdata.ViewArrays` of the run's
    rendered training set): each class's mirror axis (:func:`mirror_axes` over the training
    objects of ``train_idx``, the validation objects left out) and, for every object of the set, the standardized
    coefficients of its grid (the run's training grid set, by id) flipped across its class's axis. DataError
    when an object has no grid or the grids do not give the set's own coefficients (another grid set)."""
    m = data.manifest
    path = run.grids("train")
    if not path.exists():
        raise DataError(path, "mirror augmentation needs the run's training grids (notebook 01)")
    gs = GridSet.load(path)
    at = gs.rows_of(m.object_ids)
    missing = np.flatnonzero(at < 0)
    if len(missing):
        raise DataError(path, f"{len(missing)} objects of the rendered set have no grid here "
                              f"(first: {m.object_ids[missing[0]]})")
    labels = m.object_labels
    train_objects = np.unique(data.object_index[np.asarray(train_idx)])
    axes = mirror_axes(gs.grids[at[train_objects]], labels[train_objects], len(m.classes))
    sub = ObjectSubspace.load(run.subspace)
    out = np.zeros((len(at), sub.dim_), np.float32)
    for s in tqdm(range(0, len(at), 256), desc="mirrored coefficients", disable=not progress):
        g = gs.grids[at[s:s + 256]]
        first = np.flatnonzero(data.object_index == s)[:1]            # an image of object s, if it has one
        if len(first) and not np.allclose(sub.project(g[:1])[0], data.coeffs_raw[first[0]], atol=1e-3):
            raise DataError(path, f"object {m.object_ids[s]}: its grid here does not give the rendered set's "
                                  f"coefficients (another grid set or subspace)")
        flipped = np.stack([np.flip(x, axes[lab]) for x, lab in zip(g, labels[s:s + 256])])
        out[s:s + 256] = sub.project(flipped)
    return axes, ((out - data.coeff_mean) / data.coeff_std).astype(np.float32)
