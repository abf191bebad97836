"""A run's baseline fitted again on this machine, and the main reading's evaluations of it made with that fit.

Usage: python scripts/refit.py PROFILE DATASET RUN [--method beo] [--keep]

Some baselines are fitted beside the model (BEO's class densities: ``beo.npz``) and not committed; fitted again
on another CPU from the same training grids, recipe and seed, the file can differ in its last bits (VBPCA's
subspace and scikit-learn's EM sum in another order), so evaluations that record another ``baseline_sha256`` are
not the run's own. This script fits the baseline in a temporary folder beside links to RUN's model, manifest,
training grids and subspace (where RUN has no subspace, the one its model holds: ``hbeo.run.Run.subspace``; RUN
itself is not written until the end), evaluates every setting of that baseline in
``hbeo.evaluation.protocol.EVALUATIONS`` under the run's main reading on the same queries as RUN's
``eval_<method>_<pose>.json``, and, when the fit's sha256 differs from the one those files record, moves the
evaluations to ``RUN/refit-<sha>/`` (``hbeo.report.readings.refit_folder``), where REPRODUCTION.md's section on
the readings compares them with the run's, query by query. ``--keep`` also keeps the fitted file there
(large; never committed). When the fit is the run's own, nothing is written: there is nothing to compare.
"""
import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hbeo.errors import HBEOError  # noqa: E402
from hbeo.rundir import BASELINE_FILES, RunDir  # noqa: E402
from hbeo.storage import read_json  # noqa: E402

#: What the temporary run folder links from RUN: what fitting and evaluating a baseline reads.
LINKED = ("model.hbeo", "manifest.json", "grids_train.npz", "grids_test.npz", "subspace.npz")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("profile")
    p.add_argument("dataset")
    p.add_argument("run", type=Path)
    p.add_argument("--method", default="beo", choices=[m for m in BASELINE_FILES if m != "voxcnn"],
                   help="the baseline to fit again (default beo)")
    p.add_argument("--keep", action="store_true", help="keep the fitted baseline file in the refit folder")
    args = p.parse_args(argv)
    from hbeo.evaluation.protocol import EVALUATIONS, evaluations
    from hbeo.report.readings import BASELINE, refit_folder
    from hbeo.run import Run

    run = RunDir(args.run)
    settings = [k for k in EVALUATIONS if k[0] == args.method]
    theirs = {}
    for k in settings:
        path = run.evaluation(*k)
        if not path.is_file():
            print(f"error: {path}: missing; evaluate the run's main reading first (notebooks 05-07)", file=sys.stderr)
            return 2
        theirs[k] = (read_json(path, "metrics", dict).get("request") or {}).get(BASELINE)
    if not run.model.is_file():
        print(f"error: {run.model}: missing", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="refit-") as tmp:
        for name in LINKED:
            if (run.path / name).exists():
                os.symlink((run.path / name).resolve(), Path(tmp) / name)
        try:
            made = evaluations(Run.open(args.profile, args.dataset, tmp), settings)
        except (HBEOError, OSError, ValueError) as err:
            print(f"error: {err}", file=sys.stderr)
            return 1
        sha = {(m.get("request") or {}).get(BASELINE) for m in made}
        if len(sha) != 1 or None in sha:
            print(f"error: the evaluations record baseline files {sorted(map(str, sha))}", file=sys.stderr)
            return 1
        sha = sha.pop()
        if all(v == sha for v in theirs.values()):
            print(f"the fit here is the run's own (baseline sha256 {sha}): nothing to compare, nothing written")
            return 0
        out = refit_folder(run, sha)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=run.path))
        for k in settings:
            shutil.copy2(Path(tmp) / run.evaluation(*k).name, staging / run.evaluation(*k).name)
        if args.keep:
            shutil.copy2(Path(tmp) / BASELINE_FILES[args.method], staging / BASELINE_FILES[args.method])
        if out.exists():
            shutil.rmtree(out)
        staging.rename(out)              # the folder appears whole, or not at all
    print(f"baseline sha256 {sha} (the run's: {', '.join(sorted(set(map(str, theirs.values()))))}): "
          f"{len(settings)} evaluations in {out}")
    for k in settings:
        print(f"  {out / run.evaluation(*k).name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
