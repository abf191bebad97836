#!/usr/bin/env bash
# Every method of the reproduction (hbeo.evaluation.protocol.EVALUATIONS) under each reading of the view
# protocol (hbeo.render.poses.SAMPLERS: so3, upright, sphere, floor), on the same objects and per-view streams:
# RUN/eval_<method>_<pose>.json under the model's own sampler, RUN/eval_<method>_<pose>_<sampler>.json under
# the others (cached: a finished file with the same request is read, not recomputed). Trains/fits what is missing.
# Usage: bash scripts/readings.sh [PROFILE] [DATASET] [RUN] [PY] [SAMPLER ...]
# e.g.   bash scripts/readings.sh cpu modelnet10-vox30 results/cpu-modelnet10-vox30 .venv/bin/python floor
set -euo pipefail
cd "$(dirname "$0")/.."
PROFILE=${1:-cpu}
DATASET=${2:-modelnet10-vox30}
RUN=${3:-results/$PROFILE-$DATASET}
PY=${4:-.venv/bin/python}
shift $(( $# < 4 ? $# : 4 ))
# (python -c, not a here-document: worker processes started by spawn re-read the main module's file)
PYTHONPATH=$PWD "$PY" -c '
import sys

from hbeo.evaluation.protocol import readings
from hbeo.run import Run

profile, dataset, out, *samplers = sys.argv[1:]
for sampler, evals in readings(Run.open(profile, dataset, out), samplers or None).items():
    for m in evals:
        print("%-8s %-12s %-6s accuracy %.3f  pose median %.1f deg  IoU %.3f  (%d queries)" % (
            sampler, m["method"], m["pose"], m["accuracy"], m["pose_error_deg"]["median"],
            m["completion"]["iou"], m["n_queries"]))
' "$PROFILE" "$DATASET" "$RUN" "$@"
