"""Post-hoc prior correction (logit adjustment) of HBEO's class answer, chosen on validation (issue 29).

    python benchmarks/bench_prior.py [--model results/cpu-modelnet10-vox30/model.hbeo] [--split val]
                                     [--taus 0,0.25,0.5,0.75,1] [--views 3] [--per-class N]

One evaluation pass (:func:`hbeo.evaluation.evaluate.score_methods`, the loop ``python -m hbeo evaluate``
runs, at prior_tau 0) records each query's class probabilities; every ``tau`` then re-answers the same
queries with :meth:`hbeo.model.inference.HBEO.adjust_probabilities` (probabilities x prior^-tau,
renormalized; the pose and shape do not depend on the class answer). The training class prior is the
model file's ``class_counts``, or for a file without them the dataset's training objects per class
under the model's profile (:func:`hbeo.evaluation.protocol.model_prior`, named in the output).

The rule, fixed before any number was seen: tau = the value of ``--taus`` with the highest validation
class-mean accuracy (the paper's Table I total); a tie goes to the smaller tau (nearer the paper). The
chosen tau's difference from tau 0 gets a paired bootstrap interval over validation objects
(:class:`hbeo.evaluation.paired.PairedBootstrap`: resampled within class, an object brings its views).
The test split is scored once, afterwards, for the chosen tau and 0 only (``--split test --taus 0,T``):
it chooses nothing. Results are merged into ``benchmarks/logs/prior.json`` under the split's key.
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

from hbeo.evaluation.evaluate import EvaluationSetup, class_mean_accuracy, score_methods, summarize  # noqa: E402
from hbeo.evaluation.method import HBEOMethod  # noqa: E402
from hbeo.evaluation.paired import PairedBootstrap  # noqa: E402
from hbeo.evaluation.protocol import model_prior  # noqa: E402
from hbeo.model.inference import HBEO  # noqa: E402
from hbeo.run import load_dataset  # noqa: E402
from hbeo.storage import atomic_text  # noqa: E402

LOG = ROOT / "benchmarks" / "logs" / "prior.json"


class Recording:
    """A :class:`~hbeo.evaluation.method.Method` that answers as ``inner`` does and keeps each query's
    class probabilities in call order (a repeated call on the same depth array, the loop's warm-up,
    replaces the last entry instead of adding one)."""

    def __init__(self, inner):
        self.inner, self.name, self.poses = inner, inner.name, inner.poses
        self.probs, self._last = [], None

    def describe(self) -> dict:
        return self.inner.describe()

    def predict_view(self, depth, intrinsics, **kw) -> dict:
        out = self.inner.predict_view(depth, intrinsics, **kw)
        if depth is self._last:
            self.probs[-1] = np.asarray(out["probabilities"], np.float64)
        else:
            self.probs.append(np.asarray(out["probabilities"], np.float64))
        self._last = depth
        return out


def per_tau(metrics: dict, probs: np.ndarray, model: HBEO, counts, source: str, taus) -> dict:
    """{tau: metrics of the same queries answered with the prior correction tau} (class answers only)."""
    classes = list(model.classes)
    true = np.array(metrics["per_query"]["class"])
    out = {}
    for tau in taus:
        model.set_prior_tau(tau, counts, source)
        pred = np.array(classes)[model.adjust_probabilities(probs).argmax(1)]
        m = {"method": f"hbeo-tau{tau:g}", "pose": "3dof",
             "per_query": {**metrics["per_query"], "pred": pred.tolist()}}
        out[tau] = {"tau": tau, "accuracy": float((pred == true).mean()),
                    "class_mean_accuracy": class_mean_accuracy(true, pred),
                    "per_class_accuracy": {c: float((pred[true == c] == c).mean()) for c in classes if (true == c).any()},
                    "metrics": m}
    model.set_prior_tau(0.0)
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", default=str(ROOT / "results" / "cpu-modelnet10-vox30" / "model.hbeo"))
    ap.add_argument("--dataset", default="modelnet10-vox30")
    ap.add_argument("--split", choices=("val", "test"), default="val")
    ap.add_argument("--taus", default="0,0.25,0.5,0.75,1")
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--per-class", type=int)
    ap.add_argument("--n-boot", type=int, default=2000)
    ap.add_argument("--out", default=str(LOG))
    args = ap.parse_args(argv)
    taus = sorted({float(t) for t in args.taus.split(",")})
    if 0.0 not in taus:
        raise SystemExit("--taus must include 0 (the paper's answer, the baseline of every difference)")
    if args.split == "test" and len(taus) > 2:
        raise SystemExit("the test split scores only tau 0 and the tau chosen on validation (--taus 0,T)")
    t0 = time.perf_counter()
    model = HBEO.load(args.model)
    ds = load_dataset(args.dataset, model.settings.profile or "cpu")
    model_prior(model, ds, 1.0)                     # the counts (file's, or the dataset's with its source)
    counts, source = model.class_counts, model.prior_source
    model.set_prior_tau(0.0)
    rec = Recording(HBEOMethod(model))
    rows, failures, records, rs = score_methods({"hbeo": (rec, "3dof")}, ds, EvaluationSetup.of_model(model),
                                                args.split, args.views, args.seed, per_class=args.per_class,
                                                progress=False)
    rows = rows["hbeo"]
    if len(rows) != len(rec.probs):
        raise RuntimeError(f"{len(rows)} scored queries but {len(rec.probs)} recorded answers")
    metrics = summarize(rows, model.classes, ds.name, args.split, args.views, args.seed, rs.sampler, False,
                        len(records) - len(failures))
    probs = np.stack(rec.probs)
    res = per_tau(metrics, probs, model, counts, source, taus)
    if res[0.0]["accuracy"] != metrics["accuracy"]:
        raise RuntimeError("tau 0 does not reproduce the evaluation's own answers")
    best = max(taus, key=lambda t: (res[t]["class_mean_accuracy"], -t))
    boot = PairedBootstrap([r["metrics"] for r in res.values()], n_boot=args.n_boot)
    diff = {}
    for t in taus:
        if t:
            for what in ("class_accuracy", "accuracy"):
                e = boot.contrast((f"hbeo-tau{t:g}", "3dof"), ("hbeo-tau0", "3dof"), what)
                diff.setdefault(f"{t:g}", {})[what] = {"value": e.value, "low": e.low, "high": e.high}
    report = {"model": str(Path(args.model).resolve().relative_to(ROOT)) if Path(args.model).resolve().is_relative_to(ROOT)
              else args.model, "dataset": ds.name, "split": args.split, "views": args.views, "seed": args.seed,
              "per_class": args.per_class, "n_objects": metrics["n_objects"], "n_queries": metrics["n_queries"],
              "failures": len(failures), "class_counts": dict(zip(model.classes, counts)), "counts_source": source,
              "rule": "tau with the highest class-mean accuracy on validation; ties to the smaller tau",
              **({"chosen_tau": best} if args.split == "val" else {}), "seconds": round(time.perf_counter() - t0, 1),
              "taus": [{k: v for k, v in res[t].items() if k != "metrics"} for t in taus],
              "difference_vs_tau0": diff, "bootstrap": {"n_boot": args.n_boot, "level": boot.level,
                                                        "unit": "objects, resampled within class"}}
    out = Path(args.out)
    log = json.loads(out.read_text()) if out.exists() else {}
    log[args.split + ("" if args.per_class is None else f"-per{args.per_class}")] = report
    atomic_text(out, json.dumps(log, indent=1))
    for t in taus:
        r = res[t]
        d = diff.get(f"{t:g}", {}).get("class_accuracy")
        print(f"tau {t:<5g} accuracy {r['accuracy']:.4f}  class-mean {r['class_mean_accuracy']:.4f}"
              + (f"  (vs 0: {d['value']:+.4f} [{d['low']:+.4f}, {d['high']:+.4f}])" if d else ""))
    print(f"{args.split}: n = {metrics['n_queries']} queries of {metrics['n_objects']} objects; "
          + (f"chosen: tau {best:g}; " if args.split == "val" else "") + f"{report['seconds']} s; counts from {source} -> {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
