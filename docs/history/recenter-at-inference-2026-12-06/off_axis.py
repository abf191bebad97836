"""The reference model on the five ModelNet10 sample bathtubs (shared/modelnet10_sample), rendered at 640x480
(Kinect-like) at 1.7 m, 5 views each, with the object's centre 0, 0.15 or 0.30 m off the optical axis (random
direction): class accuracy, median symmetric pose error (bathtub: 180-degree turn forgiven), share warned as
off-axis, as the model answers (recenter False) and with the view turned to the object (predict --face-object).
Run from the repository root; writes off_axis.json beside this file."""
import dataclasses
import glob
import json
import math
from pathlib import Path

import numpy as np

from hbeo.conventions import Intrinsics
from hbeo.data.meshio import read_mesh
from hbeo.model.inference import HBEO
from hbeo.render.renderer import Renderer, prepare_mesh
from hbeo.rotations import geodesic_deg, yaw_elevation_to_matrix, z_angle_to_matrix

K = Intrinsics.kinect(640, 480)
OFFSETS = (0.0, 0.15, 0.30)
meshes = sorted(glob.glob("../shared/modelnet10_sample/bathtub/train/*.off"))
rng = np.random.default_rng(0)
frames = []
with Renderer(K) as r:
    for f in meshes:
        mesh = prepare_mesh(read_mesh(f), 1.0)
        for yaw, el in [(35, 30), (0, 20), (90, 40), (200, 15), (300, 45)]:
            R = yaw_elevation_to_matrix(math.radians(yaw), math.radians(el))
            for off in OFFSETS:
                a = rng.uniform(0, 2 * np.pi)
                t = np.array([off * np.cos(a), off * np.sin(a) * 0.75, 1.7])
                frames.append((off, R, r.render(mesh, R, t)))
out = {"meshes": meshes, "intrinsics": dataclasses.asdict(K), "n_per_offset": len(frames) // len(OFFSETS)}
for face in (False, True):
    m = HBEO.load("results/cpu-modelnet10-vox30/model.hbeo")
    if face:
        m.settings = dataclasses.replace(m.settings, recenter=True)
    rows = {o: [] for o in OFFSETS}
    for off, R, d in frames:
        p = m.predict(d, K)
        err = min(float(geodesic_deg(p.rotation[0], R)), float(geodesic_deg(p.rotation[0], R @ z_angle_to_matrix(math.pi))))
        rows[off].append((p.class_names[0] == "bathtub", err, any("off the optical axis" in w for w in p.warnings[0])))
    key = "face_object" if face else "as_trained"
    out[key] = {}
    for off, v in rows.items():
        v = np.array(v, float)
        out[key][f"{off:.2f}"] = {"accuracy": float(v[:, 0].mean()), "pose_median_deg": float(np.median(v[:, 1])),
                                  "within_30": float((v[:, 1] < 30).mean()), "warned": float(v[:, 2].mean())}
        print(key, f"offset {off:.2f} m", out[key][f"{off:.2f}"], flush=True)
(Path(__file__).parent / "off_axis.json").write_text(json.dumps(out, indent=1))
