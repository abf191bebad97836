#!/usr/bin/env bash
# The reference model and every figure of the README's model table, in the order they were made.
# Choices are made on the validation objects (evaluate --split val, scripts/tune_verify.py); the test split
# is evaluated once per chosen row. Files of models the run folder no longer holds are written to $H.
# About 10 h on a 2-core CPU (each 30-epoch training takes about 2 h). Usage: bash scripts/model_table.sh [PY]
# Every command below ran with the cpu profile of its day: shared layers (512, 256, 256) and 30 epochs until
# 2026-11-29, when the profile took 4k's and 4l's choice ((1024, 512, 512), 60 epochs); to repeat a step as it
# ran, add `--fc 512,256,256` and the epochs it names (30 where it names none).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${1:-.venv/bin/python}
D=modelnet10-vox30
R=results/cpu-$D
H=docs/history/cpu-$D      # metrics of models the run folder no longer holds (RunDir.history; read by the model table)
# 1. shape loss: the paper's coefficient loss against the voxel loss, 5 epochs each, compared on validation
for v in coeffs voxels; do
  $PY -m hbeo train --dataset $D --profile cpu --rotation bins --augment-roll --epochs 5 --shape-loss $v \
      --name model_abl5_$v.hbeo --quiet
  $PY -m hbeo evaluate --model $R/model_abl5_$v.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
      --out $H/eval_val-abl5-$v.json
done
# 1b. class balance (issue 29): balanced sampling against a class-weighted loss, 5 epochs each as in 1 (the voxel
#     loss chosen there), compared with 1's voxel row on validation class-mean accuracy; ablation rows only
for b in sampler loss; do
  $PY -m hbeo train --dataset $D --profile cpu --rotation bins --augment-roll --shape-loss voxels --epochs 5 \
      --class-balance $b --name model_abl5_bal-$b.hbeo --quiet
  $PY -m hbeo evaluate --model $R/model_abl5_bal-$b.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
      --out $H/eval_val-abl5-bal-$b.json
done
# 1c. (issue 29 item 2, added 2026-11-27 before its result) fresh views at the same budget: 1b's sampler row trained
#     on `--data stream --backend torch` (a fresh pose for every image, rendered on the CPU as it trains; the same
#     5 epochs of 71,720 images), against 1b's sampler row on validation. An ablation row only: it chooses nothing
#     (the 30-epoch stream candidate is 4f's).
$PY -m hbeo train --dataset $D --profile cpu --rotation bins --augment-roll --shape-loss voxels --epochs 5 \
    --class-balance sampler --data stream --backend torch --name model_abl5_stream.hbeo --checkpoint-every 500 --quiet
$PY -m hbeo evaluate --model $R/model_abl5_stream.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
    --out $H/eval_val-abl5-stream.json
# 2. the reference model then (voxel loss chosen), 30 epochs (the epoch count chosen on validation earlier), on the
#    training split's class mix (the reference run at tag repro-cpu-2026-11-24a; its files now in $H as *-unbal*)
$PY -m hbeo train --dataset $D --profile cpu --class-balance none --name model_unbal.hbeo --checkpoint-every 500 --quiet
$PY -m hbeo evaluate --model $R/model_unbal.hbeo --dataset $D --split val --views 3 --seed 0 --quiet --out $H/eval_val-unbal.json
$PY -m hbeo evaluate --model $R/model_unbal.hbeo --dataset $D --split val --views 3 --seed 0 --rolls 4 --quiet \
    --out $H/eval_val-unbal-rolls4.json
# 2b. (issue 29) the recipe with class-balanced sampling, chosen in 1b, 30 epochs; validation one pass and 4 rolls
#     (its test files only where validation chooses it over the reference rows)
$PY -m hbeo train --dataset $D --profile cpu --class-balance sampler --name model_bal-sampler.hbeo \
    --checkpoint-every 500 --quiet
$PY -m hbeo evaluate --model $R/model_bal-sampler.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
    --out $H/eval_val-bal-sampler.json
$PY -m hbeo evaluate --model $R/model_bal-sampler.hbeo --dataset $D --split val --views 3 --seed 0 --rolls 4 --quiet \
    --out $H/eval_val-bal-sampler-rolls4.json
#     chosen (2026-11-26: validation class mean 71.1 % > 66.9 % one pass, 74.5 % > 69.7 % with 4 rolls), then once on test
$PY -m hbeo evaluate --model $R/model_bal-sampler.hbeo --dataset $D --split test --views 3 --seed 0 --quiet \
    --out $H/eval_test-bal-sampler.json
$PY -m hbeo evaluate --model $R/model_bal-sampler.hbeo --dataset $D --split test --views 3 --seed 0 --rolls 4 --quiet \
    --out $H/eval_test-bal-sampler-rolls4.json
# 3. verify settings, on validation views only (rows appended to verify_sweep.csv; made with the reference then)
$PY scripts/tune_verify.py --model $R/model_unbal.hbeo --per-class 40 --thresholds 0.3,0.45 hbeo default \
    "classes=1,class_weight=0" "classes=1,class_weight=0,rotations=2" "classes=1,class_weight=0,noise_var=0.3"
# 4. the reference then: the chosen rows on validation and once on the test split. VerifyConfig's defaults are the
#    chosen verify settings. (Its one-pass and rolls+verify test files are its run's eval_hbeo{,-verify}_3dof.json,
#    now $H/eval_test-unbal.json and $H/eval_test-unbal-verify-run.json.)
$PY -m hbeo evaluate --model $R/model_unbal.hbeo --dataset $D --split val --views 3 --seed 0 --rolls 4 --verify --quiet \
    --out $H/eval_val-unbal-verify.json
$PY -m hbeo evaluate --model $R/model_unbal.hbeo --dataset $D --split test --views 3 --seed 0 --rolls 4 --verify --quiet \
    --out $H/eval_test-unbal-verify.json
$PY -m hbeo evaluate --model $R/model_unbal.hbeo --dataset $D --split test --views 3 --seed 0 --rolls 4 --quiet \
    --out $H/eval_test-unbal-rolls4.json
# 4b. the prior correction of the class answer: tau chosen on validation (benchmarks/logs/prior.json), then the
#     chosen tau on validation and once on the test split
$PY benchmarks/bench_prior.py --model $R/model_unbal.hbeo --split val
for split in val test; do
  $PY -m hbeo evaluate --model $R/model_unbal.hbeo --dataset $D --split $split --views 3 --seed 0 --prior-tau 1 --quiet \
      --out $H/eval_$split-unbal-prior1.json
done
# 4c. the reference run regenerated with class-balanced sampling (`make reproduce PROFILE=cpu DATASET=$D` at the tag
#     repro-cpu-2026-11-26-bal; its notebook 04 trains $R/model.hbeo, bit-identical in training to model_bal-sampler),
#     then its validation, 4-roll and verify rows and its readings: scripts/reference_run.sh's steps after the run
SKIP_RUN=1 bash scripts/reference_run.sh "$PY"
# 4d. (issue 29 item 4) the same recipe with training seeds 1 and 2, the same views (seed 0): the seeds column
for s in 1 2; do
  $PY -m hbeo train --dataset $D --profile cpu --seed $s --name model-s$s.hbeo --checkpoint-every 500 --quiet
  for split in val test; do
    $PY -m hbeo evaluate --model $R/model-s$s.hbeo --dataset $D --split $split --views 3 --seed 0 --quiet \
        --out $R/eval_$split-ref-s$s.json
    $PY -m hbeo evaluate --model $R/model-s$s.hbeo --dataset $D --split $split --views 3 --seed 0 --rolls 4 --quiet \
        --out $R/eval_$split-ref-rolls4-s$s.json
  done
done
# 4e. the reference model re-timed after the BLAS-thread fix (commit 1c5b4c6): the same views and answers, the time
#     without the stalls (benchmarks/README.md, "Inference: the BLAS threads"); the one-pass target row
for split in val test; do
  $PY -m hbeo evaluate --model $R/model.hbeo --dataset $D --split $split --views 3 --seed 0 --quiet \
      --out $R/eval_$split-ref-retimed.json
done
#     and 8 and 16 camera rolls on validation (ablation: the roll count of the highest class mean, within 0.5 points
#     the fewest; 4 stayed)
for r in 8 16; do
  $PY -m hbeo evaluate --model $R/model.hbeo --dataset $D --split val --views 3 --seed 0 --rolls $r --quiet \
      --out $R/eval_val-ref-rolls$r.json
done
# 4g. (issue 29 item 2) the three training seeds of 4d averaged (--ensemble), one pass and 4 rolls, on validation.
#     Rule fixed before (commit c9432e8): joins the extensions only at a validation class mean with 4 rolls of at
#     least 75.5 % (4 rolls alone + 1 point); it reached 75.1 % (2026-11-27): not chosen, no test files
for r in 1 4; do
  $PY -m hbeo evaluate --model $R/model.hbeo --ensemble $R/model-s1.hbeo --ensemble $R/model-s2.hbeo --dataset $D \
      --split val --views 3 --seed 0 --rolls $r --quiet --out $R/eval_val-ens3-rolls$r.json
done
# Helpers of steps 4f-4m. pair MODEL SPLIT STEM: MODEL scored on SPLIT's 3 views per object (view seed 0), one pass
# into $R/STEM.json and 4 rolls into $R/STEM-rolls4.json. passes_4i FILE: 4i's rule on a validation one-pass file;
# beats_seeds NEW OLD: the 4k/4l rule over three training seeds; clears_bar NEW OLD: 4l's and 4m's bar for one seed
# against three; train_seeds STEM OPTIONS: seeds 1 and 2 of a recipe.
pair() {
  $PY -m hbeo evaluate --model $R/$1 --dataset $D --split $2 --views 3 --seed 0 --quiet --out $R/$3.json
  $PY -m hbeo evaluate --model $R/$1 --dataset $D --split $2 --views 3 --seed 0 --rolls 4 --quiet --out $R/$3-rolls4.json
}
passes_4i() {
  $PY -c "import json, sys; e = json.load(open('$R/$1'))
sys.exit(e['class_mean_accuracy'] < 0.744 or e['pose_error_deg']['within_30'] < 0.439)"
}
beats_seeds() {   # beats_seeds NEW OLD: over training seeds 0, 1, 2 (eval_val-STEM{,-s1,-s2}.json), NEW's mean
  # validation class mean and mean within 30 deg raw both exceed OLD's
  $PY -c "import json, statistics as st, sys
seeds = lambda stem: [json.load(open(f'$R/eval_val-{stem}{s}.json')) for s in ('', '-s1', '-s2')]
new, old = seeds('$1'), seeds('$2')
cm = lambda es: st.mean(x['class_mean_accuracy'] for x in es)
w30 = lambda es: st.mean(x['pose_error_deg']['within_30'] for x in es)
sys.exit(not (cm(new) > cm(old) and w30(new) > w30(old)))"
}
clears_bar() {   # clears_bar NEW OLD: 4l's rule: eval_val-NEW.json's one-pass class mean and within 30 deg raw each
  # at least the mean + sample sd of OLD's three training seeds (eval_val-OLD{,-s1,-s2}.json)
  $PY -c "import json, statistics as st, sys
e = lambda f: json.load(open('$R/' + f))
b, new = [e(f'eval_val-$2{s}.json') for s in ('', '-s1', '-s2')], e('eval_val-$1.json')
bar = lambda get: st.mean(get(x) for x in b) + st.stdev(get(x) for x in b)
cm, w30 = (lambda x: x['class_mean_accuracy']), (lambda x: x['pose_error_deg']['within_30'])
print(f'$1: class mean {cm(new):.3f} (bar {bar(cm):.3f}), within 30 deg {w30(new):.3f} (bar {bar(w30):.3f})')
sys.exit(cm(new) < bar(cm) or w30(new) < bar(w30))"
}
passes_4k() { beats_seeds fc1024 ref; }   # 4k's rule: the wider layers' three seeds against the reference recipe's
train_seeds() {   # train_seeds STEM TRAIN_OPTIONS...: the recipe with training seeds 1 and 2, each scored on validation
  local stem=$1; shift
  for s in 1 2; do
    $PY -m hbeo train --dataset $D --profile cpu "$@" --seed $s --name model_$stem-s$s.hbeo --checkpoint-every 500 --quiet
    $PY -m hbeo evaluate --model $R/model_$stem-s$s.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
        --out $R/eval_val-$stem-s$s.json
  done
}
# 4f. (issue 29 item 2) fresh views every pass: the recipe trained on `--data stream` (a fresh pose per object per
#     pass, rendered by the torch ray marcher as it trains) instead of the 20 fixed views per object, 30 epochs,
#     seed 0 (about 4.7 h alone on the 2-core VM; resumes from its checkpoint). Rule fixed before its result
#     (2026-11-27): it replaces the recipe only if its validation one-pass class mean is at least 72.1 % (the
#     reference's 71.1 % + 1 point); only then is it evaluated on the test split.
#     The same recipe trained on a lent GPU (README "Paper scale on one GPU"; two calls, `--budget 720`) is judged by
#     the same rule on the same queries, and only if its `lease.json` says the whole schedule ran (`steps` 33,630;
#     a cut schedule is lease history, docs/history/gpu-cpu-stream/): the returned model joined
#     (`cat model.hbeo.gz.part* | gunzip > $R/model_stream.hbeo`, SHA-256 checked against lease.json) replaces the
#     training line below, and the evaluations run here on the CPU (written 2026-11-27, before any such lease).
$PY -m hbeo train --dataset $D --profile cpu --data stream --backend torch --name model_stream.hbeo \
    --checkpoint-every 500 --quiet
pair model_stream.hbeo val eval_val-stream
if $PY -c "import json, sys; sys.exit(json.load(open('$R/eval_val-stream.json'))['class_mean_accuracy'] < 0.721)"; then
  pair model_stream.hbeo test eval_test-stream
fi
# 4h. (issue 29 item 4) the 3-D CNN baseline trained again with training seeds 0, 1, 2 in a work folder (the run's
#     rendered training set made again there), each scored on the same test views; its model-table row
#     (2026-11-27, ~5 min a seed on that day's VM)
$PY scripts/voxcnn_seeds.py "${WORK:-/tmp/hbeo-voxcnn-seeds}" --seeds 0 1 2
for s in 0 1 2; do
  cp "${WORK:-/tmp/hbeo-voxcnn-seeds}/eval_test-voxcnn-s$s.json" $R/
  mkdir -p $R/train_voxcnn-s$s && cp "${WORK:-/tmp/hbeo-voxcnn-seeds}/train_voxcnn-s$s/train_log.csv" $R/train_voxcnn-s$s/
done
# 4i. (issue 29 item 2, written 2026-11-27 before its result) the class loss weighted up: the recipe with
#     gamma_c = 4 (`--loss-weights 4,1,1`), 30 epochs, seed 0. Why: the reference's training log shows no
#     overfitting (validation loss below the training loss and still falling at epoch 30), and the class term is the
#     smallest part of the loss (validation CE 0.73 against pose 5.0 and voxels 7.9 at epoch 30), so the shared
#     layers are fitted mostly for pose and shape. Rule: it replaces the recipe only if its validation one-pass
#     class mean is at least 74.4 % (the mean of the recipe's three training seeds on validation, 72.8 %, plus their
#     sd, 1.6: a bar that another seed of the same recipe would rarely pass; 4f's "reference + 1 point" would be
#     passed by the seeds' own mean) and its validation within 30 deg raw is no more than 3 points below the
#     reference's 46.9 %; only then is it evaluated on the test split (one pass and 4 rolls).
$PY -m hbeo train --dataset $D --profile cpu --loss-weights 4,1,1 --name model_cw4.hbeo --checkpoint-every 500 --quiet
pair model_cw4.hbeo val eval_val-cw4
if passes_4i eval_val-cw4.json; then
  pair model_cw4.hbeo test eval_test-cw4
fi
# 4j. (issue 29 item 2, written 2026-11-27 before its result, while 4i trained) more room in the shared layers: the
#     recipe with HBEONet's three fully connected layers widened from the cpu profile's (512, 256, 256) to
#     (1024, 512, 512) (`--fc 1024,512,512`; the convolutions unchanged; ~15 % more arithmetic a step), 30 epochs,
#     seed 0. Why: the same training log as 4i's (no overfitting), and the 4,096-bin pose head and the class head
#     read a 256-wide layer. The rule of 4i, on the same queries; if both pass, the higher validation one-pass class
#     mean is the candidate.
$PY -m hbeo train --dataset $D --profile cpu --fc 1024,512,512 --name model_fc1024.hbeo --checkpoint-every 500 --quiet
pair model_fc1024.hbeo val eval_val-fc1024
if passes_4i eval_val-fc1024.json; then
  pair model_fc1024.hbeo test eval_test-fc1024
fi
# 4k. (issue 29, written 2026-11-27 after 4j's validation result and before any of these) 4j's recipe with training seeds
#     1 and 2 (about 65 min each on a 2-core AVX-512 VM), scored on the same validation queries. Rule: the cpu
#     profile's shared layers become (1024, 512, 512) only if, over seeds 0, 1, 2, the mean validation one-pass class
#     mean exceeds the reference recipe's (72.8 %, eval_val-ref{,-s1,-s2}.json) and the mean within 30 deg raw exceeds
#     the reference recipe's (46.2 %); picking the better of two recipes on three seeds each. Only then: the three
#     seeds' test files (one pass and 4 rolls), and the reference run regenerated with the profile changed.
train_seeds fc1024 --fc 1024,512,512
if passes_4k; then
  for s in "" -s1 -s2; do
    pair model_fc1024$s.hbeo test eval_test-fc1024$s
  done
fi
# 4l. (issue 29 item 2, written 2026-11-27 23:45 UTC while 4k's seed 1 trained, before 4k's and 4l's results) longer
#     training: the recipe 4k leaves in the cpu profile (FC below: (1024, 512, 512) if 4k's rule passed, else the
#     profile's (512, 256, 256)) trained 60 epochs instead of 30 (the cosine schedule stretched over twice the steps),
#     seed 0; about 110 min on a 2-core AVX-512 VM. Why: every 30-epoch log shows underfitting, not overfitting
#     (4j's: validation loss 13.34 below the training loss 13.45 at epoch 30, the validation pose median still falling
#     from 52 to 29 deg over the last 6 epochs). Rule, on the same validation queries, against B, the three training
#     seeds of that recipe at 30 epochs (eval_val-fc1024{,-s1,-s2}.json if 4k passed, else eval_val-ref{,-s1,-s2}.json):
#     the profile's epochs become 60 only if its one-pass class mean is at least mean(B) + sd(B) and its within 30 deg
#     raw at least mean(B) + sd(B) as well (4i's bar for the class mean, applied to pose too, since pose is the larger
#     gap); only then its training seeds 1 and 2, and the test split after them if, as in 4k, the three seeds' means
#     beat B's (beats_seeds; this last clause spelled out in code 2026-11-28 02:10 UTC, 4l at its epoch 3).
if passes_4k; then FC=1024,512,512 B=fc1024; else FC=512,256,256 B=ref; fi
$PY -m hbeo train --dataset $D --profile cpu --fc $FC --epochs 60 --name model_e60.hbeo --checkpoint-every 500 --quiet
pair model_e60.hbeo val eval_val-e60
if clears_bar e60 $B; then
  train_seeds e60 --fc $FC --epochs 60
  if beats_seeds e60 $B; then
    for s in "" -s1 -s2; do
      pair model_e60$s.hbeo test eval_test-e60$s
    done
  fi
fi
# 4m. (issue 29 item 2, written 2026-11-28 05:00 UTC, after 4l's seed-0 result and before any result of its own or
#     of 4l's seeds 1 and 2) more distinct views at the same number of steps: 4l's seed 0 (60 epochs of the 20
#     rendered views per object) passed its bar while its log shows the validation class mean flat from about epoch
#     48 with the training loss now below the validation loss, the first sign of learning the fixed views rather
#     than the objects; the paper rendered ~1,800 views per object. So: the recipe left after 4l (B below: 60 epochs
#     if 4l's three seeds beat the 30-epoch seeds, else 30) trained on 40 rendered views per object (`--views 40`)
#     for half B's epochs, the same 67,260 (or 33,630) optimizer steps and learning-rate schedule, seed 0, in a work
#     folder (a run folder's rendered set is refused under other settings: hbeo.render.renderset). Rule, on the same
#     validation queries against B's three seeds: one-pass class mean and within 30 deg raw each at least mean(B) +
#     sd(B) (4l's); only then its seeds 1 and 2, and the test split if the three seeds' means beat B's. About 2 h a
#     seed at 4l's 67,260 steps (1 h at 33,630) on a 2-core AVX-512 VM, plus ~7 min rendering the 40 views.
#     Run record (2026-11-29, before any result): the first start (06:52 UTC) was OOM-killed while rendering, not
#     training: each Dask render task pickled the whole training split with its records (fixed in 75ace45). The set was
#     finished at 08:51 with `hbeo render ... --views 40 --workers 1` into the same work folder (the same set identity
#     and shards; rendering is resumable) and seed 0 then trained as written below (`--data memory`, 3.9 GB resident).
#     Result (2026-11-29 12:32 UTC; resumed once from its checkpoint at step 53,808): class mean 77.0 % (bar 76.4),
#     within 30 deg 56.7 % (bar 57.4): the rule is not met, so no seeds 1 and 2 and no test files (models.json row;
#     v40_vs_e60_val{,_rolls4}.json: `python scripts/paired_contrast.py` of eval_val-v40 against eval_val-e60).
W4M=${WORK:-/tmp/hbeo-4m}
if beats_seeds e60 fc1024; then B=e60 EP=30; else B=fc1024 EP=15; fi
v40() {   # v40 SEED NAME: the 40-view recipe trained in $W4M with training seed SEED, copied into the run folder
  $PY -m hbeo train --dataset $D --profile cpu --out $W4M --fc 1024,512,512 --views 40 --epochs $EP --seed $1 \
      --name $2 --checkpoint-every 500 --quiet
  cp $W4M/$2 $R/ && mkdir -p $R/train_${2%.hbeo} && cp $W4M/train_${2%.hbeo}/{train_log.csv,provenance.json} $R/train_${2%.hbeo}/
  $PY -c "import numpy as np, sys; a, b = np.load('$W4M/subspace.npz'), np.load('$R/subspace.npz')
sys.exit(sorted(a) != sorted(b) or not all(np.array_equal(a[k], b[k]) for k in a))" \
      || { echo "4m: the work folder's subspace differs from the run's: not the same recipe" >&2; exit 1; }
}
v40 0 model_v40.hbeo
pair model_v40.hbeo val eval_val-v40
for x in "" -rolls4; do
  $PY scripts/paired_contrast.py $R/eval_val-v40$x.json $R/eval_val-e60$x.json --out $R/v40_vs_e60_val${x/-/_}.json \
      --what "4m: the 60-epoch recipe on 40 rendered views per object for 30 epochs (model_v40.hbeo) minus the same steps on 20 views for 60 epochs (model_e60.hbeo), seed 0 each, validation${x:+ with 4 rolls each} (398 objects x 3 views)"
done
if clears_bar v40 $B; then
  for s in 1 2; do
    v40 $s model_v40-s$s.hbeo
    $PY -m hbeo evaluate --model $R/model_v40-s$s.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
        --out $R/eval_val-v40-s$s.json
  done
  if beats_seeds v40 $B; then
    for s in "" -s1 -s2; do
      pair model_v40$s.hbeo test eval_test-v40$s
    done
  fi
fi
# 4n. (issue 29 item 5) the reference run regenerated with the profile 4k and 4l chose ((1024, 512, 512), 60 epochs):
#     a clean clone at the tag repro-cpu-2026-12-01-e60 (commit 78a8306), `make reproduce PROFILE=cpu DATASET=$D`,
#     made over two sessions since a session keeps nothing outside what lands and the run takes ~4.5 h on 2 cores:
#     notebooks 01-04 on 2026-12-01 (stopped after 04; `bash scripts/reference_stage.sh save CLONE`, commit 0ddfc62),
#     05-08 and reference_run.sh's later steps on 2026-12-02 (`bash scripts/reference_stage.sh finish CLONE` in a new
#     clean clone at the same commit). Its model is 4l's recipe with training seed 0, trained again (4l's seed-0 model
#     file was lost). Landing, in the checkout: the previous reference's files retired (`python
#     scripts/retire_reference.py --old ref --new bal30 --label "tag repro-cpu-2026-11-26-bal, commit aa98863"`;
#     the commands of steps 1-4m above that read eval_*-ref*.json now find those files in docs/history/ under
#     -bal30), the clone's new run files copied in, the model table's three rows of the new reference added
#     (`python scripts/reference_rows.py`), then step 5.
# 4o. (issue 29 item 4, written 2026-12-02 03:45 UTC while it trained, before any result) the chosen recipe's training
#     seed 1 trained again, on the regenerated reference run's own subspace and rendered set (4l's seed-1 model file
#     was lost and it had been fitted on the basis before hbeo.subspace.vbpca.fix_signs; seed 2 and the reference's
#     seed 0 are on the rule-signed one): about 110 min alone on a 2-core AVX-512 VM. Its validation file replaces
#     4l's seed 1 in the reference row's seeds column (4l's stays 4l's row), and the test split follows as 4l's last
#     clause already decided for the recipe's three seeds (one pass and 4 rolls). Its final checkpoint is the seed-1
#     run's HBEONet (scripts/seed_runs.sh), so that run trains nothing again.
$PY -m hbeo train --dataset $D --profile cpu --fc 1024,512,512 --epochs 60 --seed 1 --name model_ref-s1.hbeo \
    --checkpoint-every 500
$PY -m hbeo evaluate --model $R/model_ref-s1.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
    --out $R/eval_val-ref-s1.json
pair model_ref-s1.hbeo test eval_test-ref-s1
# 4p. (issue 29 item 2, written 2026-12-04 16:10 UTC, before any result of it) test-time mirror averaging of the class
#     answer (`--mirror`): a depth image mirrored left-right about the principal point is exactly a view of the mirrored
#     object (camera points F p, F = diag(-1, 1, 1): the mirrored object at the proper rotation F R F_obj), and
#     ModelNet10's classes hold mirrored variants of one another (a mirrored chair is a chair), so the class is
#     mirror-invariant where the pose and shape are not (their mirror plane is the class's own). The class
#     probabilities are averaged over each image and its mirror (twice the network passes); pose and completion stay
#     those of the unmirrored passes. Nothing is trained. Rule, on the reference model's validation queries (seed 0,
#     eval_val-ref-rolls4.json): adopted into the project's extension only if 4 rolls + mirror minus 4 rolls alone
#     has a paired 95 % interval of the class mean above 0 (scripts/paired_contrast.py) and training seed 1's model
#     (results/cpu-modelnet10-vox30-seed1/model.hbeo) gains too (point estimate above 0); only then the test split,
#     4 rolls + mirror for seeds 0 and 1. One pass + mirror is measured beside (2 passes: not the paper's one-pass HBEO).
#     Result (2026-12-04, 2-core VM): 4 rolls + mirror minus 4 rolls, class mean +0.6 points [-0.3, +1.7] for seed 0,
#     -0.3 [-1.4, +0.6] for seed 1: the rule is not met, not adopted, no test files. Beside it: one pass + mirror minus
#     one pass +1.8 [+0.1, +3.4] (mirror_vs_one_val.json); chosen for nothing.
$PY -m hbeo evaluate --model $R/model.hbeo --dataset $D --split val --views 3 --seed 0 --mirror --quiet \
    --out $R/eval_val-ref-mirror.json
$PY scripts/paired_contrast.py $R/eval_val-ref-mirror.json $R/eval_val-ref.json --out $R/mirror_vs_one_val.json \
    --what "4p (measured beside its rule): the reference model, one pass + mirror averaging of the class minus one pass, validation (397 objects x 3 views)"
$PY -m hbeo evaluate --model $R/model.hbeo --dataset $D --split val --views 3 --seed 0 --rolls 4 --mirror --quiet \
    --out $R/eval_val-ref-rolls4-mirror.json
$PY -m hbeo evaluate --model $R-seed1/model.hbeo --dataset $D --split val --views 3 --seed 0 --rolls 4 --quiet \
    --out $R/eval_val-ref-s1-rolls4.json
$PY -m hbeo evaluate --model $R-seed1/model.hbeo --dataset $D --split val --views 3 --seed 0 --rolls 4 --mirror --quiet \
    --out $R/eval_val-ref-s1-rolls4-mirror.json
for x in ref ref-s1; do
  $PY scripts/paired_contrast.py $R/eval_val-$x-rolls4-mirror.json $R/eval_val-$x-rolls4.json \
      --out $R/mirror_vs_rolls4_val${x#ref}.json \
      --what "4p: $x with 4 rolls + mirror averaging of the class minus 4 rolls alone, validation (397 objects x 3 views)"
done
if $PY -c "import json, sys
a, b = (json.load(open('$R/mirror_vs_rolls4_val' + s + '.json')) for s in ('', '-s1'))
sys.exit(not (a['contrasts']['class_accuracy']['low'] > 0 and b['contrasts']['class_accuracy']['value'] > 0))"; then
  for m in "" -seed1; do
    $PY -m hbeo evaluate --model $R$m/model.hbeo --dataset $D --split test --views 3 --seed 0 --rolls 4 --mirror \
        --quiet --out $R/eval_test-ref${m/-seed/-s}-rolls4-mirror.json
  done
fi
# 4q. (issue 29 item 2, written 2026-12-04 16:15 UTC, before any training of it) mirror augmentation in training
#     (`--augment-mirror`): 4p found the one-pass class answer not mirror-invariant (one pass + mirror +1.8 points
#     [+0.1, +3.4] on validation, measured beside its rule), so the network may learn more from each object seen
#     mirrored as well, with its pose and shape mirrored across its class's plane. The cpu profile's recipe with it,
#     seed 0, on the run's own subspace and rendered set (about 2 h on 2 cores). Rule: its validation one-pass class
#     mean and within 30 deg raw each at least the reference recipe's three training seeds' mean + sample sd
#     (eval_val-ref.json, eval_val-ref-s1.json, eval_val-e60-s2.json: 75.9 % and 57.2 %); only then its seeds 1
#     and 2, and the test split (one pass and 4 rolls, the three seeds) only if their validation means beat those
#     three seeds' on both.
#     Run record: seed 0 started 2026-12-04 16:12 UTC in the checkout (commit 3e7bb11), ~690 images/s on a 2-core VM,
#     on the reference run's grids, subspace and rendered set (ignored files) copied from a clean clone's
#     `reproduce --seed 2 --only 01 02 03` at the reference's tag: the same basis bytes as model.hbeo's. (That seed-2
#     run of scripts/seed_runs.sh was stopped in its notebook 04 to free the cores for this; nothing of it landed.)
#     Cut off by the end of that session at step 55500 of 67,260 (49 of 60 epochs; ~480-580 images/s, slower than
#     planned): its checkpoint is committed as train_model_mirror/checkpoint-staged.pt (git add -f, ~70 MB, the one
#     such file; remove it once the model is trained). To go on: put the reference run's grids, subspace and
#     rendered set back in $R (a clean clone at tag repro-cpu-2026-12-01-e60, `python -m hbeo reproduce --profile
#     cpu --dataset $D --only 01 02 03`, copied over: the same bytes), copy the staged file to
#     train_model_mirror/checkpoint.pt and run the command below again: it resumes exactly (provenance.json:
#     resumed_from_step).
#     Resumed so 2026-12-04 18:44-19:13 UTC in the next session (the machine had kept the copied grids, subspace and
#     rendered set; provenance.json: resumed_from_step 55500); the staged checkpoint then removed. Result (validation,
#     n = 1,191 queries): class mean 74.2 % < 75.9 %, within 30 deg 58.3 % >= 57.2 %: the rule is not met (both parts
#     were required), so no seeds 1 and 2 and no test evaluation (eval_val-mirror.json, mirroraug_vs_ref_val.json).
$PY -m hbeo train --dataset $D --profile cpu --augment-mirror --seed 0 --name model_mirror.hbeo --checkpoint-every 500
$PY -m hbeo evaluate --model $R/model_mirror.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
    --out $R/eval_val-mirror.json
ref_seeds() {   # ref_seeds KEY STAT: mean or mean + sd of the reference recipe's three seeds on validation
  $PY -c "import json, statistics as st
e = [json.load(open('$R/' + f)) for f in ('eval_val-ref.json', 'eval_val-ref-s1.json', 'eval_val-e60-s2.json')]
v = [x['class_mean_accuracy'] if '$1' == 'cm' else x['pose_error_deg']['within_30'] for x in e]
print(st.mean(v) + (st.stdev(v) if '$2' == 'bar' else 0))"
}
if $PY -c "import json, sys; e = json.load(open('$R/eval_val-mirror.json'))
sys.exit(e['class_mean_accuracy'] < $(ref_seeds cm bar) or e['pose_error_deg']['within_30'] < $(ref_seeds w30 bar))"; then
  for s in 1 2; do
    $PY -m hbeo train --dataset $D --profile cpu --augment-mirror --seed $s --name model_mirror-s$s.hbeo \
        --checkpoint-every 500
    $PY -m hbeo evaluate --model $R/model_mirror-s$s.hbeo --dataset $D --split val --views 3 --seed 0 --quiet \
        --out $R/eval_val-mirror-s$s.json
  done
  if $PY -c "import json, statistics as st, sys
e = [json.load(open('$R/eval_val-mirror' + s + '.json')) for s in ('', '-s1', '-s2')]
sys.exit(st.mean(x['class_mean_accuracy'] for x in e) <= $(ref_seeds cm mean)
         or st.mean(x['pose_error_deg']['within_30'] for x in e) <= $(ref_seeds w30 mean))"; then
    for s in "" -s1 -s2; do
      pair model_mirror$s.hbeo test eval_test-mirror$s
    done
  fi
fi
# 4r. (issue 29 item 4, written 2026-12-04 22:05 UTC while the seed-2 run trained, before any result of it) the seed-2
#     run (scripts/seed_runs.sh) trains the chosen recipe with seed 2 on the reference run's subspace and rendered set:
#     its training log is 4l's seed 2's bit for bit through epoch 52 (train_model_e60-s2/train_log.csv: the same
#     training), its epochs 53-60 resumed on another CPU (reference_stage.sh finish). Its model file is committed
#     (4l's seed-2 model file is not), so it replaces 4l's seed 2 in the reference rows' seeds columns (4l's stays
#     4l's rows), as 4o's seed 1 did: validation and test, one pass and 4 rolls, on the run's views.
pair ../cpu-$D-seed2/model.hbeo val eval_val-ref-s2
pair ../cpu-$D-seed2/model.hbeo test eval_test-ref-s2
# 5. the README's model and targets tables, and the confusion matrices of the chosen rows
$PY -m hbeo report --model-table --run $R --readme README.md
$PY - <<'PYEOF'
import json
from hbeo.report.figures import save
from hbeo.report.paper_figures import confusion_grid
R = "results/cpu-modelnet10-vox30"
ev = [json.load(open(f"{R}/eval_test-ref-rolls4.json")), json.load(open(f"{R}/eval_hbeo-verify_3dof.json"))]
save(confusion_grid(ev, "reference model, test split (907 objects x 3 views, seed 0), 4 rolls"), R, "16_confusion_test")
PYEOF
