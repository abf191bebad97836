#!/usr/bin/env bash
# The first target runs, compared on the test split before the validation protocol existed: the `cpu` profile on the real ModelNet10 grids, evaluated on the whole
# test split (907 usable objects, one view each). Models: the paper's axis-angle head, the 6-D head and the
# rotation-bins head (plain, with camera-roll augmentation, and with roll augmentation for 20 and 30 epochs) under
# uniform SO(3) views, and the 6-D head under upright views. Writes into results/cpu-modelnet10-vox30*
# and docs/history/cpu-modelnet10-vox30
# (about 4 h on a 2-core CPU; each model ~20 min per 10 epochs). Usage: bash maintainer/cpu_targets.sh [PY]
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${1:-.venv/bin/python}
D=modelnet10-vox30
R=results/cpu-$D
RU=results/cpu-$D-upright
H=docs/history/cpu-$D      # metrics of models the run folder no longer holds (RunDir.history)
# The cpu profile at the time: 10 epochs, the paper's recipe unless a flag says otherwise (the profile now
# trains the recipe chosen on validation). Evaluation views are now the paired protocol's, so a rerun
# scores other views of the same objects than the committed docs/history/cpu-modelnet10-vox30/eval_so3_*.json files (docs/history.md).
P="--epochs 10 --rotation axis_angle --no-augment-roll --shape-loss coeffs"
# (the axis-angle model was the run's model.hbeo until the reference model replaced it: the model table's
#  first row, experiments/cpu-modelnet10-vox30/00-axis-angle.toml)
$PY -m hbeo train --dataset $D --profile cpu $P --name model_axis_angle.hbeo --quiet
$PY -m hbeo evaluate --model $R/model_axis_angle.hbeo --dataset $D --split test --views 1 --seed 0 --quiet --out $H/eval_so3_axis_angle.json
$PY -m hbeo train --dataset $D --profile cpu $P --rotation 6d --name model_6d.hbeo --quiet
$PY -m hbeo evaluate --model $R/model_6d.hbeo --dataset $D --split test --views 1 --seed 0 --quiet --out $H/eval_so3_6d.json
for opts in "bins:" "bins_roll:--augment-roll" "bins_roll20:--augment-roll --epochs 20" "bins_roll30:--augment-roll --epochs 30"; do
  name=${opts%%:*}
  # shellcheck disable=SC2086
  $PY -m hbeo train --dataset $D --profile cpu $P --rotation bins ${opts#*:} --name model_$name.hbeo --quiet
  $PY -m hbeo evaluate --model $R/model_$name.hbeo --dataset $D --split test --views 1 --seed 0 --quiet --out $H/eval_so3_$name.json
done
# test-time roll averaging (4 rolls) on the bins models; the 20-epoch model also over 3 views per object
$PY -m hbeo evaluate --model $R/model_bins_roll.hbeo --dataset $D --split test --views 1 --seed 0 --rolls 4 --quiet --out $H/eval_so3_bins_roll_rolls4.json
$PY -m hbeo evaluate --model $R/model_bins_roll20.hbeo --dataset $D --split test --views 1 --seed 0 --rolls 4 --quiet --out $H/eval_so3_bins_roll20_rolls4.json
for m in bins_roll20 bins_roll30; do
  for r in 1 4; do
    $PY -m hbeo evaluate --model $R/model_$m.hbeo --dataset $D --split test --views 3 --seed 0 --rolls $r --quiet --out $H/eval_so3_${m}_views3_rolls$r.json
  done
done
$PY -m hbeo train --dataset $D --profile cpu $P --sampler upright --rotation 6d --name model_6d.hbeo --out $RU --quiet
$PY -m hbeo evaluate --model $RU/model_6d.hbeo --dataset $D --split test --views 1 --seed 0 --quiet --out $RU/eval_upright_6d.json
