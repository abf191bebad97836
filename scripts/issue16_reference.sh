#!/usr/bin/env bash
# Issue 16: the reference model and every figure of the README's model table, in the order they were made.
# Choices are made on the validation objects (evaluate --split val, scripts/tune_verify.py); the test split
# is evaluated once per chosen row, with two seeds to show how much the figures move.
# About 2 h on a 2-core CPU (the 30-epoch training takes most of it). Usage: bash scripts/issue16_reference.sh [PY]
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${1:-.venv/bin/python}
D=modelnet10-vox30
R=results/cpu-$D
# 1. shape loss: the paper's coefficient loss against the voxel loss, 5 epochs each, compared on validation
for v in coeffs voxels; do
  $PY -m hbeo train --dataset $D --profile cpu --rotation bins --augment-roll --epochs 5 --shape-loss $v \
      --name model_abl5_$v.hbeo --quiet
  $PY -m hbeo evaluate --model $R/model_abl5_$v.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
      --out $R/eval_val-abl5-$v.json
done
# 2. the reference model (voxel loss chosen), 30 epochs (the epoch count chosen on validation earlier)
$PY -m hbeo train --dataset $D --profile cpu --rotation bins --augment-roll --shape-loss voxels --epochs 30 \
    --checkpoint-every 500 --quiet
$PY -m hbeo evaluate --model $R/model.hbeo --dataset $D --split val --views 3 --seed 0 --quiet --out $R/eval_val-ref.json
$PY -m hbeo evaluate --model $R/model.hbeo --dataset $D --split val --views 3 --seed 0 --rolls 4 --quiet \
    --out $R/eval_val-ref-rolls4.json
# 3. verify settings, on validation views only (rows appended to verify_sweep.csv)
$PY scripts/tune_verify.py --model $R/model.hbeo --per-class 40 --thresholds 0.3,0.45 hbeo default \
    "classes=1,class_weight=0" "classes=1,class_weight=0,rotations=2" "classes=1,class_weight=0,noise_var=0.3"
