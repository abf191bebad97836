#!/usr/bin/env bash
# Every method of the reproduction (hbeo.evaluation.protocol.EVALUATIONS) under each reading of the view
# protocol (hbeo.render.poses.SAMPLERS: so3, upright, sphere, floor), on the same objects and per-view streams:
# RUN/eval_<method>_<pose>.json under the model's own sampler, RUN/eval_<method>_<pose>_<sampler>.json under
# the others (cached: a finished file with the same request is read, not recomputed). Trains/fits what is missing.
# REPRODUCTION.md ("The paper's claims under each reading of the view protocol") shows what the run holds.
# Usage: [METHODS="method:pose ..."] bash scripts/readings.sh [PROFILE] [DATASET] [RUN] [PY] [SAMPLER ...]
#   METHODS: only these settings of EVALUATIONS (space- or comma-separated method:pose), in EVALUATIONS order;
#   default all. The cheap ones first, under every reading, then the searches (the ModelNet10 cpu run on 2 cores,
#   per reading, from its 07_table2.md: BEO 1-DOF about 8 min, BEO 3-DOF about 16 min, the others seconds to minutes):
#   METHODS="hbeo:3dof hbeo-verify:3dof beo:known voxcnn:known icp:3dof" bash scripts/readings.sh cpu modelnet10-vox30 \
#       results/cpu-modelnet10-vox30 .venv/bin/python upright sphere floor
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
import os
import sys

from hbeo.evaluation.protocol import EVALUATIONS, readings

asked = [tuple(s.split(":", 1)) for s in os.environ.get("METHODS", "").replace(",", " ").split()]
unknown = [":".join(s) for s in asked if s not in EVALUATIONS]
if unknown:
    print("readings.sh: METHODS names %s; expected method:pose among %s" % (
        " ".join(unknown), " ".join("%s:%s" % s for s in EVALUATIONS)), file=sys.stderr)
    sys.exit(2)
settings = [s for s in EVALUATIONS if s in asked] if asked else EVALUATIONS

from hbeo.run import Run

profile, dataset, out, *samplers = sys.argv[1:]
for sampler, evals in readings(Run.open(profile, dataset, out), samplers or None, settings).items():
    for m in evals:
        print("%-8s %-12s %-6s accuracy %.3f  pose median %.1f deg  IoU %.3f  (%d queries)" % (
            sampler, m["method"], m["pose"], m["accuracy"], m["pose_error_deg"]["median"],
            m["completion"]["iou"], m["n_queries"]))
' "$PROFILE" "$DATASET" "$RUN" "$@"
