"""Predict -> verify (issue 16, groundwork): where the verify step's gain is lost, on real views.

For the committed real-data model (`results/cpu-modelnet10-vox30/model.hbeo`, axis-angle head) and
``--per-class`` ModelNet10 validation objects per class (held out of the model's training, from the
training split; one view each, the model's render settings; an exploration, no setting is chosen
here, and the test split is not touched), prints mean
completion IoU (threshold 0.5) of:

- HBEO alone;
- verify (:class:`hbeo.model.verify.Verifier`, one rotation, class density off) at the *true*
  rotation and translation: what MAP completion from the carved depth gives when the pose is right;
- the same at the true rotation with HBEO's translation estimate, after aligning HBEO's completion
  rendered at that rotation onto the depth (:func:`hbeo.model.verify.align_translation`), after one
  more alignment on verify's own completion (``realign=1``), and after aligning the *true* shape
  (what a perfect shape would give the alignment);

with the translation errors (median, metres; along the ray: signed median), class accuracy with
the class density on at the true pose, and verify's time per query.

Usage: python benchmarks/bench_verify.py [--per-class 4]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--per-class", type=int, default=4)
    ap.add_argument("--model", default=str(ROOT / "results/cpu-modelnet10-vox30/model.hbeo"))
    args = ap.parse_args()
    from hbeo import config, conventions as C
    from hbeo.data import datasets
    from hbeo.data.gridset import record_grid
    from hbeo.model.inference import HBEO
    from hbeo.model.verify import Verifier, VerifyConfig, align_translation, surface_points
    from hbeo.render.torch_datasets import split_objects
    from hbeo.render.views import ObjectViews, RenderSettings
    from hbeo.subspace.metrics import iou
    m = HBEO.load(args.model)
    ds = datasets.get_dataset("modelnet10-vox30", profile=config.get_profile("cpu"))
    # the validation objects the model was trained without (split_objects over the training records,
    # as training_data splits them), not test objects: later choices of verify's settings are made here
    prof = config.get_profile("cpu")
    train = datasets.select(ds, "train", prof)
    held = split_objects([ds.classes.index(r.cls) for r in train], 0.1, 0)
    recs = [r for c in ds.classes for r in [x for x, h in zip(train, held) if h and x.cls == c][:args.per_class]]
    views = ObjectViews(replace(RenderSettings.from_dict(m.settings["render"]), views_per_object=1))
    plain = Verifier(m, VerifyConfig(rotations=1, class_weight=0.0, refine_translation=False))
    with_class = Verifier(m, VerifyConfig(rotations=1, class_weight=1.0, refine_translation=False))
    realign = Verifier(m, VerifyConfig(rotations=1, class_weight=0.0, realign=1))
    rows = {k: [] for k in ("hbeo", "true pose", "estimated t", "aligned t", "aligned, realigned once t",
                            "true shape aligned t")}
    terr = {k: [] for k in rows if k.endswith(" t")}
    along, acc_hbeo, acc_class, ms = [], [], [], []
    for i, r in enumerate(recs):
        a = views.views(r, i, ds.classes.index(r.cls), "train", 0)
        d, K, truth = a["depth"][0].astype(np.float32), m.intrinsics, record_grid(r)
        p = m.predict(d, K)
        R, t_true = a["rotation"][:1].astype(np.float64), a["translation"][0].astype(np.float64)
        size = m.settings["object_size"]
        t_al = align_translation(d, R[0], p.translation[0], surface_points(p.grids[0], size), K)
        t0 = time.perf_counter()
        re = realign.verify(d, K, replace(p, rotation=R, translation=p.translation[:1]))
        ms.append((time.perf_counter() - t0) * 1e3)
        ts = {"true pose": t_true, "estimated t": p.translation[0], "aligned t": t_al,
              "true shape aligned t": align_translation(d, R[0], p.translation[0], surface_points(truth, size), K)}
        rows["hbeo"].append(iou(truth, p.grids[0]))
        for k, t in ts.items():
            rows[k].append(iou(truth, plain.verify(d, K, replace(p, rotation=R, translation=t[None]))["grid"]))
        rows["aligned, realigned once t"].append(iou(truth, re["grid"]))
        ts["aligned, realigned once t"] = re["translation"]
        for k in terr:
            terr[k].append(float(np.linalg.norm(ts[k] - t_true)))
        e = p.translation[0] - t_true
        along.append(float(e @ (p.translation[0] / np.linalg.norm(p.translation[0]))))
        acc_hbeo.append(p.class_names[0] == r.cls)
        x = with_class.verify(d, K, replace(p, rotation=R, translation=t_true[None]))
        acc_class.append(m.classes[x["label"]] == r.cls)
    views.close()
    print(f"{len(recs)} ModelNet10 validation objects (<= {args.per_class} per class), one view each; "
          f"{Path(args.model).name}")
    print("mean completion IoU:")
    for k, v in rows.items():
        extra = f"   translation error median {np.median(terr[k]):.3f} m" if k in terr else ""
        print(f"  {k:28s} {np.mean(v):.3f}{extra}")
    print(f"HBEO's translation estimate, signed error along the viewing ray: median {np.median(along):+.3f} m")
    print(f"class accuracy: HBEO {np.mean(acc_hbeo):.3f}; verify with the class density at the true pose "
          f"{np.mean(acc_class):.3f}")
    print(f"verify, one rotation x 3 classes, aligned and realigned once: {np.median(ms):.1f} ms (median)")


if __name__ == "__main__":
    main()
