"""Two metrics files of the same queries compared, pair by pair: A minus B with 95 % paired intervals.

Usage: python scripts/paired_contrast.py A.json B.json --out OUT.json [--what TEXT]
Statistics: hbeo.evaluation.paired.CONTRASTS (class-mean accuracy, accuracy, within 30 degrees, median pose
error, mean IoU), on the (object, view) pairs both files answered; objects resampled within class
(hbeo.evaluation.paired.PairedBootstrap, seed 0). Prints one line per statistic; writes OUT.json atomically.
"""
import argparse
import sys
from dataclasses import asdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hbeo.evaluation.paired import SHOW, contrast_pair, read_metrics  # noqa: E402
from hbeo.storage import atomic_text, json_text  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("a")
    p.add_argument("b")
    p.add_argument("--out", required=True)
    p.add_argument("--what", default="", help="what the two files are (written into OUT)")
    args = p.parse_args(argv)
    try:
        evals = read_metrics([args.a, args.b])
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        est = contrast_pair(*evals)
    except (KeyError, ValueError) as err:
        print(f"error: {args.a} vs {args.b}: {err}", file=sys.stderr)
        return 2
    for what, e in est.items():
        fmt, scale, unit = SHOW[what]
        print(f"{what}: {e.text(fmt, scale)}{unit} ({e.n_queries} pairs, {e.n_objects} objects)")
    doc = {"what": args.what or f"{args.a} minus {args.b}, paired over the queries both answered (95 %)",
           "made_by": "python scripts/paired_contrast.py " + " ".join(sys.argv[1:] if argv is None else argv),
           "contrasts": {k: asdict(e) for k, e in est.items()}}
    atomic_text(args.out, json_text(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
