"""Converting an old-format model file (``python -m hbeo convert-model``): the check that the
converted file predicts bit-identically to the old one.

The old file's content (read without unpickling by :func:`hbeo.model.modelfile.convert_legacy`) is
put together the way the old loader did, and both answer the same fixed inputs: 4 synthetic depth
images (an ellipsoid's near side, seed 0) for an HBEO model, 4 random partial grids for a 3-D CNN.
It lives here, not in :mod:`hbeo.model`, because it knows both kinds of model file.

May import: foundation, data, subspace, render, model and the other hbeo.baselines modules.
"""
from __future__ import annotations

import io

import numpy as np

from hbeo.baselines.voxcnn import VoxCNN, VoxCNNBaseline, VoxCNNConfig
from hbeo.conventions import Intrinsics
from hbeo.errors import DataError
from hbeo.model.inference import HBEO
from hbeo.model.network import HBEONet, NetConfig
from hbeo.subspace.basis import ObjectSubspace


def same_predictions(legacy, converted) -> None:
    """DataError unless the converted file predicts bit-identically to the old file's content put
    together the way the old loader did (4 synthetic depth images / partial grids, fixed seed)."""
    b, rng = legacy.blob, np.random.default_rng(0)
    # the converted file first: its reader checks everything (weights against net_cfg, settings) and says
    # what is wrong, where the old loader's way would fail inside torch or numpy
    new = (HBEO if legacy.kind == "hbeo" else VoxCNNBaseline).load(converted)
    if legacy.kind == "hbeo":
        net = HBEONet(NetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in b["net_cfg"].items()}))
        net.load_state_dict(b["state_dict"])
        old = HBEO(net, ObjectSubspace.load(io.BytesIO(b["subspace"])), Intrinsics(*b["intrinsics"]),
                   b["classes"], b["settings"])
        K = old.intrinsics
        v, u = np.mgrid[:K.height, :K.width]
        depth = []
        for z, cu, cv, r in zip(rng.uniform(1.4, 2.0, 4), rng.uniform(0.35, 0.65, 4) * K.width,
                                rng.uniform(0.35, 0.65, 4) * K.height, rng.uniform(0.12, 0.3, 4) * K.width):
            q = 1 - ((u - cu) ** 2 + (v - cv) ** 2) / r ** 2           # an ellipsoid's near side
            depth.append(np.where(q > 0, z - 0.3 * np.sqrt(np.clip(q, 0, None)), 0.0))
        a, c = old.predict(np.stack(depth), K), new.predict(np.stack(depth), K)
        pairs = [(getattr(a, f), getattr(c, f)) for f in ("probabilities", "rotation", "translation", "coeffs",
                                                         "grids")]
    else:
        net = VoxCNN(VoxCNNConfig.from_dict(b["net_cfg"]))
        net.load_state_dict(b["state_dict"])
        filled = rng.random((4, 30, 30, 30)) < 0.1
        known = filled | (rng.random((4, 30, 30, 30)) < 0.4)
        pairs = zip(VoxCNNBaseline(net, b["classes"], b["settings"]).predict_partial(filled, known),
                    new.predict_partial(filled, known))
    if not all(np.array_equal(x, y) for x, y in pairs):
        raise DataError(converted, "the converted model predicts differently from the old file; not written")
