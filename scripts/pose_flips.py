"""Where a model's large pose errors point, per class (hbeo.evaluation.flips): front/back flips about the up axis?

Usage: python scripts/pose_flips.py --model M.hbeo [--dataset modelnet10-vox30] [--split val] [--views 3]
                                    [--seed 0] [--per-class N] [--rolls 1] --out FLIPS.json
Scores the model on the evaluation's own paired query views (the same images as `python -m hbeo evaluate`
with the same split, views and seed), prints one line per class and writes FLIPS.json atomically.
"""
import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hbeo.data.datasets import get_dataset  # noqa: E402
from hbeo.evaluation.flips import pose_flips  # noqa: E402
from hbeo.model.inference import HBEO  # noqa: E402
from hbeo.storage import atomic_text, json_text  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", required=True)
    p.add_argument("--dataset", default="modelnet10-vox30")
    p.add_argument("--split", choices=("val", "test"), default="val")
    p.add_argument("--views", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--per-class", type=int)
    p.add_argument("--rolls", type=int, default=1)
    p.add_argument("--out", required=True)
    args = p.parse_args(argv)
    out = pose_flips(HBEO.load(args.model), get_dataset(args.dataset), args.split, args.views, args.seed,
                     args.per_class, args.rolls, progress=True)
    made_by = "python scripts/pose_flips.py " + " ".join(sys.argv[1:] if argv is None else argv)
    out = {"model": args.model, "made_by": made_by, **out}
    for c in out["classes"]:
        up = "-" if c["about_up"] is None else f"{100 * c['about_up']:.0f} %"
        print(f"{c['class']:12s} n={c['n']:5d}  errors >= {out['big_deg']:.0f} deg: {100 * c['flips']:5.1f} %  "
              f"of which about the up axis: {up}")
    atomic_text(args.out, json_text(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
