#!/usr/bin/env bash
# The committed reference run and the model table's rows for its model, in the order they are made.
#   1. `make reproduce PROFILE=cpu DATASET=modelnet10-vox30` from a clean clone at a tagged commit: notebooks
#      01-08, every model trained inside the run, paper/REPRODUCTION.md written by the run.
#   2. the validation files of the run's model.hbeo (one pass, 4 rolls, 4 rolls + verify: the extensions chosen
#      on validation, checked again for this model) and the test split with 4 rolls alone (the run's
#      eval_hbeo_3dof.json and eval_hbeo-verify_3dof.json are the other two test files): the commands of the
#      reference's specs, experiments/cpu-modelnet10-vox30/NN-ref*.toml.
#   2b. the other readings of the view protocol for the fast settings (REPRODUCTION.md's claims under each
#      reading); the slow ones (beo:1dof, beo:3dof, icp:3dof) take hours: METHODS="beo:1dof icp:3dof beo:3dof".
#   3. models.json and the model and targets tables (`python -m hbeo experiment table --readme docs/experiments.md`) and
#      REPRODUCTION.md's summary block.
#   4. (in the checkout, before the clone's run folder is copied into it) the previous reference retired:
#      `python maintainer/retire_reference.py --new STEM --label "commit SHA"` moves its files to
#      docs/history and turns its specs into the previous reference's (maintainer/README.md); then the run folder
#      copied over without deleting (the ablations' files stay), the new reference's specs written (the target
#      roles the script printed go to them), and step 3 again in the checkout.
# When only the evaluation changed, not the models (e.g. HBEO's default completion rule): notebooks 05-08 alone from
# a clean clone at a tagged commit, `python -m hbeo reproduce --profile cpu --dataset $D --only 05 06 07 08` (the
# committed model.hbeo, icp.npz and voxcnn.hbeo are read; grids, subspace and BEO are made again), the seed runs'
# eval_hbeo_3dof.json and eval_hbeo-verify_3dof.json made again at that commit
# (hbeo.evaluation.protocol.evaluation), `python -m hbeo report --seeds R R-seed1 R-seed2`, then steps 2-3.
# A run cut off before its end goes on with `make reproduce PROFILE=cpu DATASET=$D RESUME=1` (finished stages
# are skipped, the training resumes from its checkpoint), then SKIP_RUN=1.
# Usage: bash maintainer/reference_run.sh [PY]   (steps 2-3 only with SKIP_RUN=1)
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${1:-.venv/bin/python}
D=modelnet10-vox30
R=results/cpu-$D
[ "${SKIP_RUN:-0}" = 1 ] || make reproduce PROFILE=cpu DATASET=$D
E="$PY -m hbeo evaluate --model $R/model.hbeo --dataset $D --views 3 --seed 0 --quiet"
$E --split val --out $R/eval_val-ref.json
$E --split val --rolls 4 --out $R/eval_val-ref-rolls4.json
$E --split val --rolls 4 --verify --out $R/eval_val-ref-verify.json
$E --split test --rolls 4 --out $R/eval_test-ref-rolls4.json
METHODS="hbeo:3dof hbeo-verify:3dof beo:known voxcnn:known" bash scripts/readings.sh cpu $D $R $PY sphere floor upright
$PY -m hbeo experiment table --readme docs/experiments.md
$PY -m hbeo report --run $R --out paper/REPRODUCTION.md --readme README.md
