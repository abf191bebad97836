"""Follow-up to why.py: where to turn the view. On the same validation views: the offsets of the observed points'
median from the optical axis (x/z, y/z), and two more answers: (E) the camera turned to the object's *true*
centre (an oracle: rendered exactly), and (G) the view turned only by the part of the median's offset beyond
R_KEEP per axis (the 95th percentile of |offset| over these views, printed), resampled as --face-object does.
Run from the repository root after why.py; writes why2.json here."""
import json
import os

import numpy as np

os.environ.setdefault("HBEO_VOX30", "/work/shared/modelnet10_vox30/modelnet10_vox30.npz")
from hbeo import config                                            # noqa: E402
from hbeo.conventions import UP_SYMMETRY, backproject             # noqa: E402
from hbeo.data.datasets import get_dataset, validation_records   # noqa: E402
from hbeo.model.inference import HBEO                              # noqa: E402
from hbeo.rotations import direction_to_matrix, symmetric_pose_error_deg  # noqa: E402
from hbeo.render.views import ObjectViews, RenderSettings          # noqa: E402
from hbeo.render.renderer import Renderer, record_mesh             # noqa: E402
from hbeo.progress import tqdm                                     # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))


def resample(d, K, Q):
    """The image seen by a virtual camera of the same intrinsics turned by Q (virtual -> camera): nearest pixel,
    depth re-expressed as the virtual z (as hbeo.model.preprocess.to_model_view)."""
    v, u = np.mgrid[0:K.height, 0:K.width]
    rays = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, float)], -1) @ Q.T
    uu = np.rint(K.fx * rays[..., 0] / rays[..., 2] + K.cx)
    vv = np.rint(K.fy * rays[..., 1] / rays[..., 2] + K.cy)
    ok = (rays[..., 2] > 0) & (uu >= 0) & (uu < K.width) & (vv >= 0) & (vv < K.height)
    out = np.zeros((K.height, K.width))
    ui, vi = uu[ok].astype(int), vv[ok].astype(int)
    z = d[vi, ui]
    hit = z > 0
    p = np.stack([(ui[hit] - K.cx) * z[hit] / K.fx, (vi[hit] - K.cy) * z[hit] / K.fy, z[hit]], -1)
    vals = np.zeros(ok.sum())
    vals[hit] = p @ Q[:, 2]
    out[ok] = vals
    return out.astype(np.float32)


prof = config.get_profile("cpu")
ds = get_dataset("modelnet10-vox30", profile=prof)
recs = validation_records(ds, prof)
m = HBEO.load("results/cpu-modelnet10-vox30/model.hbeo")
K = m.intrinsics
settings = RenderSettings.from_dict(m.settings.render)
ov = ObjectViews(settings, m.subspace)
classes = list(m.classes)
views = []
for rec in tqdm(recs, desc="render"):
    v = ov.query_views(rec, "val", 3, classes.index(rec.cls))
    for j in range(len(v["depth"])):
        d = v["depth"][j].astype(np.float64)
        if (d > 0).any():
            pts, _ = backproject(d, K)
            c = np.median(pts, axis=0)
            views.append((rec, j, d, v["rotation"][j].astype(np.float64), v["translation"][j].astype(np.float64),
                          c[:2] / c[2]))
offs = np.array([o for *_, o in views])
true_offs = np.array([t[:2] / t[2] for _, _, _, _, t, _ in views])
R_KEEP = float(np.percentile(np.abs(offs), 95))
stats = {"median_offset_abs_p50": float(np.percentile(np.abs(offs), 50)), "p95": R_KEEP,
         "max": float(np.abs(offs).max()), "true_centre_offset_abs_max": float(np.abs(true_offs).max()),
         "median_minus_true_abs_p50": float(np.percentile(np.abs(offs - true_offs), 50)),
         "median_minus_true_abs_p95": float(np.percentile(np.abs(offs - true_offs), 95))}
print(stats)
rows = []
with Renderer(K) as rend:
    for rec, j, d, R, t, o in tqdm(views, desc="answers"):
        row = {"object": rec.id, "class": rec.cls, "view": j}
        sym = UP_SYMMETRY.get(rec.cls, 1)
        Qe = direction_to_matrix(t)                                 # E: to the true centre, exact
        pe = m.predict(rend.render(record_mesh(rec, object_size=settings.object_size), Qe.T @ R, Qe.T @ t), K)
        keep = np.clip(o, -R_KEEP, R_KEEP)                          # G: turn by the offset beyond R_KEEP
        excess = o - keep
        Qg = direction_to_matrix(np.array([excess[0], excess[1], 1.0]))
        pg = m.predict(resample(d, K, Qg), K) if np.any(excess) else m.predict(d, K)
        for k, p, Q in (("E", pe, Qe), ("G", pg, Qg)):
            row[k] = {"pred": p.class_names[0],
                      "pose_sym": float(symmetric_pose_error_deg(Q @ p.rotation[0], R, sym)), "turned": bool(k == "E" or np.any(excess))}
        rows.append(row)


def summary(key):
    acc = {c: np.mean([r[key]["pred"] == c for r in rows if r["class"] == c]) for c in classes}
    return {"n": len(rows), "class_mean": float(np.mean(list(acc.values()))),
            "accuracy": float(np.mean([r[key]["pred"] == r["class"] for r in rows])),
            "pose_sym_median": float(np.median([r[key]["pose_sym"] for r in rows])),
            "turned": int(sum(r[key]["turned"] for r in rows))}


out = {"offsets": stats, **{k: summary(k) for k in "EG"}}
print(json.dumps(out, indent=1))
json.dump({"summary": out, "rows": rows}, open(os.path.join(HERE, "why2.json"), "w"))
