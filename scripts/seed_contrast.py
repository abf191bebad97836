"""Two configurations, each trained with several seeds, compared on the same queries: the difference of their
seed means, with 95 % intervals over seeds and over objects.

Usage: python scripts/seed_contrast.py --a A_s0.json A_s1.json ... --b B_s0.json B_s1.json ... --out OUT.json
       [--what TEXT]
Statistics: hbeo.evaluation.paired.CONTRASTS, on the (object, view) pairs every file answered
(hbeo.evaluation.paired.contrast_seeds: at least two files an arm; Welch's t over the per-seed figures, and the
paired bootstrap over objects of the seed-averaged figures, seed 0). Prints one line per statistic; writes
OUT.json atomically.
"""
import argparse
import sys
from dataclasses import asdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hbeo.evaluation.paired import SHOW, contrast_seeds, read_metrics  # noqa: E402
from hbeo.storage import atomic_text, json_text  # noqa: E402


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--a", nargs="+", required=True, help="the first configuration's metrics files, one per seed")
    p.add_argument("--b", nargs="+", required=True, help="the second configuration's metrics files, one per seed")
    p.add_argument("--out", required=True)
    p.add_argument("--what", default="", help="what the two arms are (written into OUT)")
    args = p.parse_args(argv)
    try:
        a, b = read_metrics(args.a), read_metrics(args.b)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    try:
        est = contrast_seeds(a, b)
    except (KeyError, ValueError) as err:
        print(f"error: {' '.join(args.a)} vs {' '.join(args.b)}: {err}", file=sys.stderr)
        return 2
    for what, e in est.items():
        fmt, scale, unit = SHOW[what]
        f = lambda v: fmt.format(scale * v)  # noqa: E731
        print(f"{what}: a {', '.join(map(f, e.a))}; b {', '.join(map(f, e.b))}; a - b {f(e.value)}{unit} "
              f"[seeds {f(e.seeds_low)}, {f(e.seeds_high)}] [objects {f(e.objects_low)}, {f(e.objects_high)}] "
              f"({e.n_queries} queries, {e.n_objects} objects)")
    doc = {"what": args.what or f"mean over {' '.join(args.a)} minus mean over {' '.join(args.b)} (95 %)",
           "made_by": "python scripts/seed_contrast.py " + " ".join(sys.argv[1:] if argv is None else argv),
           "a": args.a, "b": args.b,
           "contrasts": {k: asdict(e) for k, e in est.items()}}
    atomic_text(args.out, json_text(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
