"""Follow-up to why.py and why2.py: turn the view to an *estimate* of the object's centre. Run with the argument
``clip``, (H): turn only by the part of the estimated centre's offset (x/z, y/z) beyond the model's training shift,
so that an estimate within the training range leaves the view as it is; writes why3-clip.json. (F) two passes: the
view turned to the observed points' median (--face-object) gives a pose and a shape; the centre at which that
shape at that pose shows the depth (hbeo.model.verify.align_translation, on the working view verify uses) is
the estimate; the view turned to it is answered again, and that answer is brought back to the camera frame.
On the validation views of why.py (class-mean accuracy, median symmetric pose error) and on the off-axis sample
bathtubs of off_axis.py (median symmetric pose error per offset). Run from the repository root; writes why3.json."""
import json
import math
import os
import glob

import numpy as np

os.environ.setdefault("HBEO_VOX30", "/work/shared/modelnet10_vox30/modelnet10_vox30.npz")
from hbeo import config                                            # noqa: E402
from hbeo.conventions import UP_SYMMETRY, Intrinsics              # noqa: E402
from hbeo.data.datasets import get_dataset, validation_records   # noqa: E402
from hbeo.data.meshio import read_mesh                             # noqa: E402
from hbeo.model.inference import HBEO                              # noqa: E402
from hbeo.model.preprocess import to_model_view                    # noqa: E402
from hbeo.model.verify import align_translation, surface_points, working_view  # noqa: E402
from hbeo.rotations import symmetric_pose_error_deg, yaw_elevation_to_matrix  # noqa: E402
from hbeo.render.views import ObjectViews, RenderSettings          # noqa: E402
from hbeo.render.renderer import Renderer, prepare_mesh            # noqa: E402
from hbeo.progress import tqdm                                     # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
m = HBEO.load("results/cpu-modelnet10-vox30/model.hbeo")


CLIP = len(__import__("sys").argv) > 1 and __import__("sys").argv[1] == "clip"
SHIFT = float(m.settings.render["shift"])


def two_pass(d, K):
    """(class name, rotation in the camera frame) of the two-pass answer."""
    m.set_face_object(True)
    p1 = m.predict(d, K)
    m.set_face_object(False)
    pts = surface_points(m.paper_grids(p1.coeffs[0][None])[0], m.settings.object_size * float(p1.scale[0]))
    if not len(pts):
        return p1.class_names[0], p1.rotation[0]
    dw, Kw = working_view(d, K, m.intrinsics)
    t = align_translation(dw, p1.rotation[0], p1.translation[0], pts, Kw)
    if CLIP:
        off = t[:2] / t[2]
        excess = off - np.clip(off, -SHIFT, SHIFT)
        if not np.any(excess):
            p = m.predict(d, K)
            return p.class_names[0], p.rotation[0]
        t = np.array([excess[0], excess[1], 1.0])
    v = to_model_view(d, K, m.intrinsics, recenter=True, toward=t)
    p2 = m.predict(v.depth, m.intrinsics)
    return p2.class_names[0], v.Q @ p2.rotation[0]


out = {}
# the validation views
prof = config.get_profile("cpu")
ds = get_dataset("modelnet10-vox30", profile=prof)
K = m.intrinsics
ov = ObjectViews(RenderSettings.from_dict(m.settings.render), m.subspace)
classes = list(m.classes)
rows = []
for rec in tqdm(validation_records(ds, prof), desc="validation"):
    v = ov.query_views(rec, "val", 3, classes.index(rec.cls))
    for j in range(len(v["depth"])):
        d = v["depth"][j].astype(np.float64)
        if (d > 0).any():
            c, R = two_pass(d, K)
            rows.append({"object": rec.id, "class": rec.cls, "view": j, "pred": c, "pose_sym": float(
                symmetric_pose_error_deg(R, v["rotation"][j].astype(np.float64), UP_SYMMETRY.get(rec.cls, 1)))})
acc = {c: np.mean([r["pred"] == c for r in rows if r["class"] == c]) for c in classes}
out["validation"] = {"n": len(rows), "class_mean": float(np.mean(list(acc.values()))),
                     "accuracy": float(np.mean([r["pred"] == r["class"] for r in rows])),
                     "pose_sym_median": float(np.median([r["pose_sym"] for r in rows]))}
print(out["validation"], flush=True)
# the off-axis sample bathtubs (the frames of off_axis.py: same meshes, poses, offsets and random directions)
Kk = Intrinsics.kinect(640, 480)
OFFSETS = (0.0, 0.15, 0.30)
meshes = sorted(glob.glob("../shared/modelnet10_sample/bathtub/train/*.off"))
rng = np.random.default_rng(0)
res = {o: [] for o in OFFSETS}
with Renderer(Kk) as r:
    for f in meshes:
        mesh = prepare_mesh(read_mesh(f), 1.0)
        for yaw, el in [(35, 30), (0, 20), (90, 40), (200, 15), (300, 45)]:
            R = yaw_elevation_to_matrix(math.radians(yaw), math.radians(el))
            for off in OFFSETS:
                a = rng.uniform(0, 2 * np.pi)
                t = np.array([off * np.cos(a), off * np.sin(a) * 0.75, 1.7])
                c, Rp = two_pass(r.render(mesh, R, t), Kk)
                res[off].append((c == "bathtub", float(symmetric_pose_error_deg(Rp, R, 2))))
out["off_axis"] = {str(o): {"n": len(v), "bathtub": float(np.mean([a for a, _ in v])),
                            "pose_sym_median": float(np.median([e for _, e in v])),
                            "within_30": float(np.mean([e < 30 for _, e in v]))} for o, v in res.items()}
print(json.dumps(out, indent=1))
json.dump({"summary": out, "rows": rows}, open(os.path.join(HERE, "why3-clip.json" if CLIP else "why3.json"), "w"))
