"""Why does turning the view to the object (predict --face-object) cost class accuracy on views near the axis?

The reference model on its validation objects, 3 query views each (the evaluation's views, seed 0), answered
four ways: (A) as it answers; (B) --face-object: the image resampled (nearest pixel) into a virtual camera
turned to the observed points' median; (C) the same turned camera, but the object rendered exactly in it (no
resampling); (D) no turn, the image shifted by whole pixels so the points' median sits at the principal point
(the position B gives, without rotation or resampling). Class-mean accuracy, accuracy and median symmetric pose
error (the answer brought back to the camera frame). Run from the repository root; writes why.json here."""
import json
import os
import sys

import numpy as np

os.environ.setdefault("HBEO_VOX30", "/work/shared/modelnet10_vox30/modelnet10_vox30.npz")
from hbeo import config                                            # noqa: E402
from hbeo.conventions import UP_SYMMETRY, backproject             # noqa: E402
from hbeo.data.datasets import get_dataset, validation_records   # noqa: E402
from hbeo.model.inference import HBEO                              # noqa: E402
from hbeo.model.preprocess import to_model_view                    # noqa: E402
from hbeo.rotations import symmetric_pose_error_deg as symmetric_pose_error  # noqa: E402
from hbeo.render.views import ObjectViews, RenderSettings          # noqa: E402
from hbeo.render.renderer import Renderer, record_mesh             # noqa: E402
from hbeo.progress import tqdm                                     # noqa: E402

per_class = int(sys.argv[1]) if len(sys.argv) > 1 else None
prof = config.get_profile("cpu")
ds = get_dataset("modelnet10-vox30", profile=prof)
recs = validation_records(ds, prof, per_class=per_class)
m = HBEO.load("results/cpu-modelnet10-vox30/model.hbeo")
K = m.intrinsics
settings = RenderSettings.from_dict(m.settings.render)
ov = ObjectViews(settings, m.subspace)
classes = list(m.classes)
rows = []
with Renderer(K) as rend:
    for rec in tqdm(recs, desc="validation objects"):
        lab = classes.index(rec.cls)
        try:
            v = ov.query_views(rec, "val", 3, lab)
        except Exception as err:                                   # noqa: BLE001
            print("skip", rec.id, err)
            continue
        mesh = record_mesh(rec, object_size=settings.object_size)
        for j in range(len(v["depth"])):
            d = v["depth"][j].astype(np.float64)
            if not (d > 0).any():
                continue
            R, t = v["rotation"][j].astype(np.float64), v["translation"][j].astype(np.float64)
            view = to_model_view(d, K, K, recenter=True)
            Q = view.Q
            # C: the object rendered exactly in the turned camera (pose Q^T R, Q^T t)
            exact = rend.render(mesh, Q.T @ R, Q.T @ t)
            # D: whole-pixel shift of the points' median to the principal point
            pts, _ = backproject(d, K)
            c = np.median(pts, axis=0)
            du = int(round(K.fx * c[0] / c[2])); dv = int(round(K.fy * c[1] / c[2]))
            shifted = np.zeros_like(d)
            H, W = d.shape
            ys, xs = slice(max(0, -dv), min(H, H - dv)), slice(max(0, -du), min(W, W - du))
            yd, xd = slice(max(0, dv), min(H, H + dv)), slice(max(0, du), min(W, W + du))
            shifted[ys, xs] = d[yd, xd]
            answers = {}
            m.set_face_object(False)
            answers["A"] = m.predict(d, K)
            m.set_face_object(True)
            answers["B"] = m.predict(d, K)
            m.set_face_object(False)
            pc = m.predict(exact, K)
            answers["C"] = pc
            answers["D"] = m.predict(shifted, K) if shifted.any() else None
            row = {"object": rec.id, "class": rec.cls, "view": j}
            sym = UP_SYMMETRY.get(rec.cls, 1)
            for k, p in answers.items():
                if p is None:
                    row[k] = None
                    continue
                Rp = p.rotation[0]
                if k == "C":
                    Rp = Q @ Rp                                    # virtual camera -> camera
                row[k] = {"pred": p.class_names[0], "pose_sym": float(symmetric_pose_error(Rp, R, sym))}
            rows.append(row)


def summary(key):
    ok = [r for r in rows if r[key] is not None]
    acc = {c: np.mean([r[key]["pred"] == c for r in ok if r["class"] == c]) for c in classes
           if any(r["class"] == c for r in ok)}
    return {"n": len(ok), "class_mean": float(np.mean(list(acc.values()))),
            "accuracy": float(np.mean([r[key]["pred"] == r["class"] for r in ok])),
            "pose_sym_median": float(np.median([r[key]["pose_sym"] for r in ok]))}


out = {k: summary(k) for k in "ABCD"}
print(json.dumps(out, indent=1))
json.dump({"summary": out, "rows": rows}, open(os.path.join(os.path.dirname(__file__), "why.json"), "w"))
