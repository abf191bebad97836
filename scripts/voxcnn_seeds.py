"""The 3-D CNN baseline (VoxCNN, known pose) trained with other training seeds: in a work folder
of the `cpu` profile on ModelNet10 grids (the reference run's rendered training set and partial grids, remade
there: the same settings, so the same images), VoxCNN is trained once per seed (`train_voxcnn(seed=S)`) and kept
as ``voxcnn-sS.hbeo``; each is then scored with the paired protocol on the test split (3 views, view seed 0, the
reference model's camera), the seed's file made the folder's ``voxcnn.hbeo`` for the call:

    python scripts/voxcnn_seeds.py WORK [--seeds 0 1 2] [--model results/cpu-modelnet10-vox30/model.hbeo]
                                        [--into RUN]

writes ``WORK/eval_test-voxcnn-sS.json`` for each seed (the training logs in ``WORK/train_voxcnn-sS/``); with
``--into RUN`` copies both into the run folder RUN as well (``RUN/eval_test-voxcnn-sS.json``,
``RUN/train_voxcnn-sS/train_log.csv``: the model table's baseline row, experiments/*/NN-voxcnn-seeds.toml). Seed 0
repeats the reference run's own VoxCNN (``eval_voxcnn_known.json``) only on a machine whose torch dispatches to
the same CPU kernels: on another it trains to slightly different weights (README, "Determinism": 112 of 2,721
answers differed). About 4–5 minutes a seed on a 2-core CPU. A seed already trained is not
trained again.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--model", type=Path, default=ROOT / "results/cpu-modelnet10-vox30/model.hbeo")
    ap.add_argument("--into", type=Path, help="also copy each seed's metrics file and training log into this run folder")
    args = ap.parse_args(argv)
    from hbeo.baselines.voxcnn import train_voxcnn
    from hbeo.run import Run
    run = Run.open("cpu", "modelnet10-vox30", args.work)
    run.renders("train", progress=False)
    base = run.dir.baseline("voxcnn")
    for s in args.seeds:
        kept = args.work / f"voxcnn-s{s}.hbeo"
        if not kept.exists():
            train_voxcnn(run.dir, "cpu", seed=s, progress=False)
            shutil.move(run.dir.training(base), args.work / f"train_voxcnn-s{s}")
            shutil.move(base, kept)
            print(f"seed {s}: {kept}", flush=True)
    if args.model.resolve() != (args.work / "model.hbeo").resolve():
        shutil.copyfile(args.model, args.work / "model.hbeo")
    for s in args.seeds:
        shutil.copyfile(args.work / f"voxcnn-s{s}.hbeo", base)
        subprocess.run([sys.executable, "-m", "hbeo", "evaluate", "--method", "voxcnn", "--pose", "known",
                        "--model", str(args.work / "model.hbeo"), "--dataset", "modelnet10-vox30", "--split", "test",
                        "--views", "3", "--seed", "0", "--quiet", "--out", str(args.work / f"eval_test-voxcnn-s{s}.json")],
                       check=True, cwd=ROOT, stdout=subprocess.DEVNULL)
        print(f"seed {s}: {args.work / f'eval_test-voxcnn-s{s}.json'}", flush=True)
        if args.into:
            (args.into / f"train_voxcnn-s{s}").mkdir(parents=True, exist_ok=True)
            shutil.copyfile(args.work / f"eval_test-voxcnn-s{s}.json", args.into / f"eval_test-voxcnn-s{s}.json")
            shutil.copyfile(args.work / f"train_voxcnn-s{s}" / "train_log.csv",
                            args.into / f"train_voxcnn-s{s}" / "train_log.csv")
    return 0


if __name__ == "__main__":
    sys.exit(main())
