import dataclasses, json, os, sys, numpy as np
os.environ.setdefault("HBEO_VOX30", "/work/shared/modelnet10_vox30/modelnet10_vox30.npz")
from hbeo import config
from hbeo.data.datasets import get_dataset
from hbeo.model.inference import HBEO
from hbeo.evaluation.evaluate import evaluate_model
ds = get_dataset("modelnet10-vox30", profile=config.get_profile("cpu"))
out = {}
for rc in (False, True):
    m = HBEO.load("results/cpu-modelnet10-vox30/model.hbeo")
    m.settings = dataclasses.replace(m.settings, recenter=rc)
    r = evaluate_model(m, ds, split="val", views=3, seed=0, progress=False)
    q = r["per_query"]
    out[rc] = dict(cm=r["class_mean_accuracy"], acc=r["accuracy"], n=r["n_queries"],
                   pose_med=float(np.median(q["pose_sym_deg"])), pose30=float(np.mean(np.array(q["pose_sym_deg"]) < 30)),
                   pred=q["pred"], cls=q["class"], pose=q["pose_sym_deg"])
    print(rc, {k: v for k, v in out[rc].items() if k not in ("pred", "cls", "pose")}, flush=True)
json.dump({str(k): v for k, v in out.items()}, open("rc_val.json", "w"))
