"""Compare two run folders' tables (*.csv, *.md), the measured timing columns aside (hbeo.report.compare).

Usage: python scripts/compare_runs.py RUN_A RUN_B
Prints each difference (file, row, column) and exits 1 when there is any, 0 when the runs agree; 2 when a
folder is missing. E.g. after `make reproduce` in a fresh clone, against the committed run:
    python scripts/compare_runs.py ../fresh/results/quick-procedural results/quick-procedural
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hbeo.report.compare import table_differences  # noqa: E402

if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    try:
        diffs = table_differences(sys.argv[1], sys.argv[2])
    except FileNotFoundError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print("\n".join(diffs) if diffs else "the runs' tables agree (timing columns aside)")
    sys.exit(1 if diffs else 0)
