"""predict --face-object as the package does it (hbeo.model.facing: two passes, the view turned toward the
estimated centre only beyond the training shift), measured as rc_val.py and off_axis.py measured the first
version (the view turned to the observed points' median): the reference model's validation queries (3 views per
object, seed 0) and the off-axis sample bathtubs (the same frames as off_axis.py). Run from the repository root;
writes face_object.json here."""
import glob
import json
import math
import os

import numpy as np

os.environ.setdefault("HBEO_VOX30", "/work/shared/modelnet10_vox30/modelnet10_vox30.npz")
from hbeo import config                                              # noqa: E402
from hbeo.conventions import Intrinsics                              # noqa: E402
from hbeo.data.datasets import get_dataset                           # noqa: E402
from hbeo.data.meshio import read_mesh                               # noqa: E402
from hbeo.evaluation.evaluate import evaluate_model                  # noqa: E402
from hbeo.model.inference import HBEO                                # noqa: E402
from hbeo.render.renderer import Renderer, prepare_mesh              # noqa: E402
from hbeo.rotations import symmetric_pose_error_deg, yaw_elevation_to_matrix  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
out = {}
ds = get_dataset("modelnet10-vox30", profile=config.get_profile("cpu"))
for face in (False, True):
    m = HBEO.load("results/cpu-modelnet10-vox30/model.hbeo").set_face_object(face)
    r = evaluate_model(m, ds, split="val", views=3, seed=0, progress=False)
    q = r["per_query"]
    out[f"validation, face_object={face}"] = {
        "class_mean": r["class_mean_accuracy"], "accuracy": r["accuracy"], "n": r["n_queries"],
        "pose_sym_median": float(np.median(q["pose_sym_deg"])),
        "within_30_sym": float(np.mean(np.array(q["pose_sym_deg"]) < 30)),
        "ms_median": r["runtime_ms"]["median_per_query"]}
    print(face, out[f"validation, face_object={face}"], flush=True)
K = Intrinsics.kinect(640, 480)
OFFSETS = (0.0, 0.15, 0.30)
meshes = sorted(glob.glob("../shared/modelnet10_sample/bathtub/train/*.off"))
rng = np.random.default_rng(0)
frames = []
with Renderer(K) as rend:
    for f in meshes:
        mesh = prepare_mesh(read_mesh(f), 1.0)
        for yaw, el in [(35, 30), (0, 20), (90, 40), (200, 15), (300, 45)]:
            R = yaw_elevation_to_matrix(math.radians(yaw), math.radians(el))
            for off in OFFSETS:
                a = rng.uniform(0, 2 * np.pi)
                t = np.array([off * np.cos(a), off * np.sin(a) * 0.75, 1.7])
                frames.append((off, R, rend.render(mesh, R, t)))
m = HBEO.load("results/cpu-modelnet10-vox30/model.hbeo").set_face_object(True)
rows = {o: [] for o in OFFSETS}
for off, R, d in frames:
    p = m.predict(d, K)
    rows[off].append((p.class_names[0] == "bathtub", float(symmetric_pose_error_deg(p.rotation[0], R, 2)),
                      bool(p.warnings[0])))
for off, v in rows.items():
    v = np.array(v, float)
    out[f"off axis {off:.2f} m, face_object=True"] = {
        "n": len(v), "bathtub": float(v[:, 0].mean()), "pose_sym_median": float(np.median(v[:, 1])),
        "within_30": float((v[:, 1] < 30).mean()), "warned": float(v[:, 2].mean())}
print(json.dumps(out, indent=1))
with open(os.path.join(HERE, "face_object.json"), "w") as f:
    json.dump(out, f, indent=1)
