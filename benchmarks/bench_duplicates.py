"""Near-duplicates in ModelNet10 (30^3 grids) and how well each validation split predicts test (issue 29).

    python benchmarks/bench_duplicates.py [--run results/cpu-modelnet10-vox30]

Measures, on the grids as stored (ModelNet is aligned per class), each training object's largest grid
IoU to another training object of its class, and each test object's largest IoU to a training object of
its class: quantiles and the share above 0.8 / 0.9 / 0.95, overall and per class. Then, for the object
split every committed result used (``split_objects``, VAL_SEED) and for the grouped split
(:func:`hbeo.data.dedup.split_groups` at each threshold; the profiles' default is
:data:`hbeo.data.dedup.TWIN_IOU`), the validation objects' largest IoU to the
training part: how often a validation object keeps a twin in training, against how often a test object
has one. Last, the diagnostic: the reference model's validation queries (``eval_val-ref.json``, the
object split) scored apart for objects with and without a training twin, beside its test queries
(``07_per_query.csv``, read for this comparison only; nothing is chosen on it). Writes
``benchmarks/logs/duplicates.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

THRESHOLDS = (0.8, 0.85, 0.9, 0.95)
QUANTILES = (0.1, 0.25, 0.5, 0.75, 0.9)


def describe(x) -> dict:
    x = np.asarray(x, np.float64)
    out = {"n": int(len(x))}
    if len(x):
        out.update({f"q{int(q * 100)}": round(float(np.quantile(x, q)), 4) for q in QUANTILES})
        out.update({f"share_ge_{t}": round(float((x >= t).mean()), 4) for t in THRESHOLDS})
    return out


def accuracy(rows) -> dict:
    """Query accuracy and class-mean accuracy (mean over classes of per-class accuracy) of rows
    (class, pred, object) with the number of queries and objects."""
    if not rows:
        return {"n_queries": 0, "n_objects": 0}
    cls = np.array([r[0] for r in rows])
    ok = np.array([r[0] == r[1] for r in rows], np.float64)
    from hbeo.evaluation.evaluate import class_mean_accuracy
    return {"n_queries": len(rows), "n_objects": len({r[2] for r in rows}), "accuracy": round(float(ok.mean()), 4),
            "class_mean_accuracy": round(class_mean_accuracy(cls, np.array([r[1] for r in rows])), 4)}


def interval(rows, n_boot: int = 1000, seed: int = 0) -> dict:
    """95 % bootstrap intervals of accuracy and class-mean accuracy over objects (resampled within
    each class, an object bringing all its queries)."""
    objs = sorted({(r[0], r[2]) for r in rows})
    index = {o: i for i, o in enumerate(objs)}
    ok, n = np.zeros(len(objs)), np.zeros(len(objs))
    for c, pred, o in rows:
        ok[index[(c, o)]] += c == pred
        n[index[(c, o)]] += 1
    cls = np.array([c for c, _ in objs])
    rng = np.random.default_rng(seed)
    acc, cm = [], []
    for _ in range(n_boot):
        k, m, per = 0.0, 0.0, []
        for c in np.unique(cls):
            members = np.flatnonzero(cls == c)
            pick = members[rng.integers(0, len(members), len(members))]
            per.append(ok[pick].sum() / n[pick].sum())
            k, m = k + ok[pick].sum(), m + n[pick].sum()
        acc.append(k / m)
        cm.append(np.mean(per))
    return {"accuracy_ci95": np.percentile(acc, [2.5, 97.5]).round(4).tolist(),
            "class_mean_accuracy_ci95": np.percentile(cm, [2.5, 97.5]).round(4).tolist()}


def per_class(rows) -> dict:
    out = {}
    for c in sorted({r[0] for r in rows}):
        sel = [r for r in rows if r[0] == c]
        out[c] = {"n_queries": len(sel), "accuracy": round(float(np.mean([r[0] == r[1] for r in sel])), 4)}
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", default=str(ROOT / "results" / "cpu-modelnet10-vox30"))
    p.add_argument("--out", default=str(ROOT / "benchmarks" / "logs" / "duplicates.json"))
    a = p.parse_args(argv)

    from hbeo.data import dedup
    from hbeo.data.datasets import VAL_FRACTION, VAL_SEED, get_dataset, split_objects
    t_thr = dedup.TWIN_IOU
    t0 = time.perf_counter()
    ds = get_dataset("modelnet10-vox30")
    data = {}
    for split in ("train", "test"):
        recs = ds.records(split)
        data[split] = (np.stack([r.grid() for r in recs]), np.array([ds.classes.index(r.cls) for r in recs]),
                       [r.id for r in recs])
    (Gtr, ytr, ids_tr), (Gte, yte, ids_te) = data["train"], data["test"]
    log = {"dataset": ds.name, "n_train": len(ytr), "n_test": len(yte), "thresholds": THRESHOLDS,
           "twin_threshold": t_thr}

    nn_tr, _ = dedup.nearest_iou(Gtr, ytr)
    nn_te, _ = dedup.nearest_iou(Gte, yte, Gtr, ytr)
    log["nearest_train_iou"] = {
        "train_vs_train": {"all": describe(nn_tr), **{ds.classes[c]: describe(nn_tr[ytr == c]) for c in range(10)}},
        "test_vs_train": {"all": describe(nn_te), **{ds.classes[c]: describe(nn_te[yte == c]) for c in range(10)}}}
    hist_edges = np.round(np.arange(0.0, 1.0001, 0.05), 2)
    top_edges = np.round(np.arange(0.8, 1.0001, 0.01), 2)
    log["histogram_top"] = {"edges": top_edges.tolist(), "train_vs_train": np.histogram(nn_tr, top_edges)[0].tolist(),
                            "test_vs_train": np.histogram(nn_te, top_edges)[0].tolist()}
    log["histogram"] = {"edges": hist_edges.tolist(),
                        "train_vs_train": np.histogram(nn_tr, hist_edges)[0].tolist(),
                        "test_vs_train": np.histogram(nn_te, hist_edges)[0].tolist()}
    t_iou = time.perf_counter() - t0

    # groups at each threshold, and the validation objects' nearest IoU to their training part
    def val_nearest(val):
        best, _ = dedup.nearest_iou(Gtr[val], ytr[val], Gtr[~val], ytr[~val])
        return best

    splits = {"object": split_objects(ytr, VAL_FRACTION, VAL_SEED)}
    log["groups"] = {}
    for t in THRESHOLDS:
        g = dedup.twin_groups(Gtr, ytr, t)
        sizes = np.bincount(g)
        val = dedup.split_groups(ytr, g, VAL_FRACTION, VAL_SEED)
        splits[f"grouped@{t}"] = val
        log["groups"][str(t)] = {"n_groups": int(len(sizes)), "largest": int(sizes.max()),
                                 "objects_in_groups_of_2_plus": int(sizes[sizes >= 2].sum()),
                                 "n_val": int(val.sum()),
                                 "val_per_class": {ds.classes[c]: int(val[ytr == c].sum()) for c in range(10)}}
    log["val_nearest_train_iou"] = {name: describe(val_nearest(v)) for name, v in splits.items()}
    log["val_nearest_train_iou"]["test (reference)"] = describe(nn_te)

    # the reference model: its validation queries (object split) by twin / no twin, beside its test queries
    run = Path(a.run)
    ev_val, per_query = run / "eval_val-ref.json", run / "07_per_query.csv"
    if ev_val.exists() and per_query.exists():
        import pandas as pd
        m = json.loads(ev_val.read_text())
        q = m["per_query"]
        old_val = splits["object"]
        near = dict(zip([ids_tr[i] for i in np.flatnonzero(old_val)], val_nearest(old_val)))
        rows = list(zip(q["class"], q["pred"], q["object"]))
        missing = sorted({o for o in q["object"] if o not in near})
        if missing:
            raise SystemExit(f"{ev_val}: objects not in the object split's validation part: {missing[:5]}")
        te = pd.read_csv(per_query)
        te = te[(te.method == "hbeo") & (te.pose == "3dof")]
        test_rows = list(zip(te["class"], te["pred"], te["object"]))
        te_near = dict(zip(ids_te, nn_te))
        diag = {"source": {"val": str(ev_val.relative_to(ROOT)), "test": str(per_query.relative_to(ROOT)),
                           "views": m["views"]},
                "val_all": {**accuracy(rows), **interval(rows)}, "test_all": {**accuracy(test_rows), **interval(test_rows)},
                "per_class": {"val": per_class(rows), "test": per_class(test_rows)}}
        # validation's per-class accuracies weighted by the test split's class counts (public dataset
        # metadata, not results): what overall validation accuracy says of a test split with the test's mix
        te_counts = {ds.classes[c]: int((yte == c).sum()) for c in range(10)}
        va_pc = diag["per_class"]["val"]
        diag["val_reweighted_to_test_mix"] = round(sum(va_pc[c]["accuracy"] * te_counts[c] for c in va_pc)
                                                   / sum(te_counts[c] for c in va_pc), 4)
        for t in THRESHOLDS:
            diag[f"val_twin@{t}"] = accuracy([r for r in rows if near[r[2]] >= t])
            diag[f"val_no_twin@{t}"] = accuracy([r for r in rows if near[r[2]] < t])
            diag[f"test_twin@{t}"] = accuracy([r for r in test_rows if te_near[r[2]] >= t])
            diag[f"test_no_twin@{t}"] = accuracy([r for r in test_rows if te_near[r[2]] < t])
        log["reference_model"] = diag
    log["seconds"] = round(time.perf_counter() - t0, 1)
    log["seconds_nearest_iou"] = round(t_iou, 1)

    # print
    print(f"{ds.name}: {len(ytr)} train, {len(yte)} test objects ({log['seconds']} s)")
    print("nearest same-class training IoU (quantiles 10/25/50/75/90; share >= " + "/".join(map(str, THRESHOLDS)) + ")")
    for side in ("train_vs_train", "test_vs_train"):
        for name, d in log["nearest_train_iou"][side].items():
            print(f"  {side:15s} {name:12s} n={d['n']:4d} " + " ".join(f"{d[f'q{int(q * 100)}']:.3f}" for q in QUANTILES)
                  + "   " + " ".join(f"{d[f'share_ge_{t}']:.3f}" for t in THRESHOLDS))
    print("histogram of nearest IoU (bins of 0.05 from 0):")
    print("  train:", log["histogram"]["train_vs_train"])
    print("  test: ", log["histogram"]["test_vs_train"])
    print("  train, bins of 0.01 from 0.8:", log["histogram_top"]["train_vs_train"])
    print("  test,  bins of 0.01 from 0.8:", log["histogram_top"]["test_vs_train"])
    for t, g in log["groups"].items():
        print(f"groups at IoU >= {t}: {g['n_groups']} groups, largest {g['largest']}, "
              f"{g['objects_in_groups_of_2_plus']} objects in groups of 2+, grouped validation {g['n_val']} objects")
    print("validation objects' nearest IoU to the training part:")
    for name, d in log["val_nearest_train_iou"].items():
        print(f"  {name:18s} n={d['n']:4d} median {d['q50']:.3f}  share >= " +
              " ".join(f"{t}: {d[f'share_ge_{t}']:.3f}" for t in THRESHOLDS))
    if "reference_model" in log:
        print("reference model (accuracy / class-mean accuracy, queries, objects):")
        for k, d in log["reference_model"].items():
            if isinstance(d, dict) and d.get("n_queries"):
                print(f"  {k:22s} {d['accuracy']:.3f} / {d['class_mean_accuracy']:.3f}  "
                      f"n={d['n_queries']} queries, {d['n_objects']} objects"
                      + (f"  ci95 {d['accuracy_ci95']} / {d['class_mean_accuracy_ci95']}" if "accuracy_ci95" in d else ""))
        rm = log["reference_model"]
        print("  per class (val / test):", {c: (rm["per_class"]["val"][c]["accuracy"], rm["per_class"]["test"][c]["accuracy"])
                                           for c in rm["per_class"]["val"]})
        print(f"  validation accuracy reweighted to the test split's class counts: {rm['val_reweighted_to_test_mix']:.3f}")
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(log, indent=1) + "\n")
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
