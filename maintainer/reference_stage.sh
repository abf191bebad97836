#!/usr/bin/env bash
# The reference run (maintainer/reference_run.sh step 1) made in two sittings when the machine is lent for less time than
# the run takes: on 2 cores the cpu profile's run takes about 4.5 h (HBEONet's 60 epochs about 2.5 h of it), and a
# machine that is lent for about 3 h keeps nothing outside what is committed. So the run's notebooks 01-04 are made in the first sitting, in a clean
# clone at a tagged commit, and their products are committed to a stage folder ($R-stage); the next sitting finishes
# the same run from them, in a new clean clone at the same commit. Nothing is staged that would not be committed when
# the run lands (the executed notebooks, tables, figures, training logs and model.hbeo: the same bytes, so the
# repository's history grows by nothing more); no checkpoint is staged unless notebook 04 was stopped after HBEONet's
# training finished or the sitting ended during it (CHECKPOINT=1 or cut below).
#
#   save CLONE     (sitting 1, after `make reproduce PROFILE=$P DATASET=$D` in CLONE finished notebook 04)
#                  copies the run folder's files that the clone's commit does not hold as they are now, less what
#                  this checkout's .gitignore keeps out of a stage folder (checkpoints, renderings, grids, subspace,
#                  the option models), to $R-stage/ here, with STAGE.md saying what they are. Commit that folder.
#                  CHECKPOINT=1, when notebook 04 had to be stopped after HBEONet's 60 epochs finished but before
#                  its option trainings and evaluation (~15 min): HBEONet's final checkpoint is staged as well
#                  (~70 MB, `git add -f`: the one staged file the landed run does not keep), notebook 04's own later
#                  products are not, and finish runs notebook 04 again (it trains nothing: the checkpoint is final).
#                  CHECKPOINT=cut, when the sitting ended during HBEONet's training itself: its latest checkpoint is
#                  staged (~70 MB, `git add -f`) with subspace.sha256 (the run's subspace.npz), nothing else of
#                  notebook 04 (no model.hbeo); finish then fits the subspace again (notebook 02's fit, which must
#                  give the staged bytes, or it stops) and notebook 04 resumes the training from the checkpoint.
#   finish CLONE   (sitting 2, CLONE a new clean clone at the manifest's git_commit) empties the clone's run folder
#                  of models and metrics (as --fresh does), copies the stage into it, writes the run's subspace from
#                  model.hbeo's own basis (notebook 02 is not run again: a subspace fitted again must not differ
#                  from the one HBEONet was trained with), rebuilds the grids and the rendered training set that
#                  notebooks 01 and 03 made (ignored files; `hbeo voxelize`, `hbeo render`: the same settings, the
#                  same bytes; a cut training's subspace fitted again that differs on another CPU is taken from the
#                  seed-0 run's model.hbeo when that gives the staged sha256), runs notebooks 05-08 (04-08 after CHECKPOINT=1 or cut; `reproduce --only`, which writes
#                  REPRODUCTION.md), then
#                  maintainer/reference_run.sh's steps after the run (SKIP_RUN=1). The manifest then holds 01-04's
#                  wall times from sitting 1 and 05-08's from sitting 2, all at one commit.
#   Then land the clone's run folder as maintainer/reference_run.sh step 4 says, and `git rm -r $R-stage`.
# The same for a training seed's run (maintainer/seed_runs.sh: `make reproduce SEED=S`, results/cpu-$D-seedS, its
# stage $R-stage): SEED=S, and without reference_run.sh's later steps (they score the reference's model); its
# model.hbeo, staged, then lands with the run.
# Usage: bash maintainer/reference_stage.sh save|finish CLONE   (run from this checkout; P=PROFILE, D=DATASET, SEED:
# default cpu, modelnet10-vox30, 0; AFTER=0: not reference_run.sh's later steps; HBEO_VOX30 as for the run)
set -euo pipefail
cd "$(dirname "$0")/.."
MAIN=$PWD
P=${P:-cpu}
D=${D:-modelnet10-vox30}
SEED=${SEED:-0}
R=results/$P-$D$([ "$SEED" = 0 ] || echo "-seed$SEED")
S=$R-stage
[ $# = 2 ] || { echo "usage: bash maintainer/reference_stage.sh save|finish CLONE" >&2; exit 2; }
CLONE=$(cd "$2" && pwd)
die() { echo "reference_stage.sh: $*" >&2; exit 1; }
unchanged() {  # unchanged PATH: the clone's commit holds the file at PATH (relative to the clone) as it is now
  git -C "$CLONE" ls-files --error-unmatch -- "$1" >/dev/null 2>&1 && git -C "$CLONE" diff --quiet -- "$1"
}
basis_of() {   # basis_of MODEL: write the subspace held by model file MODEL as the run's subspace.npz (in CLONE)
  $PY -c "from hbeo.model.inference import HBEO
HBEO.load('$1').subspace.save('$R/subspace.npz')"
}
finished() {   # finished MANIFEST NOTEBOOK: the manifest records that notebook's wall time
  python3 -c "import json, sys; sys.exit('$2' not in json.load(open('$1')).get('notebooks', {}))"
}

case $1 in
save)
  src=$CLONE/$R
  [ -f "$src/manifest.json" ] || die "$src/manifest.json: no run there"
  skip=""                                            # files not staged: a regex on paths in the run folder
  cut=0                                              # 1: CHECKPOINT=cut staged a cut training (below)
  if ! finished "$src/manifest.json" 04_train; then
    # CHECKPOINT=1: HBEONet's training finished and notebook 04 was stopped after it (its two option trainings and
    # its evaluation take ~15 min more): its final checkpoint is staged too (~70 MB, the one file the landed run
    # does not keep), so that notebook 04, run again at the same commit, trains nothing and goes on from there
    # CHECKPOINT=cut, when even HBEONet's training was cut off (a session's end): its latest checkpoint is staged
    # (~70 MB, `git add -f`), with the sha256 of the run's subspace.npz, and nothing else of notebook 04 (no
    # model.hbeo); finish fits the subspace again (it must give those bytes) and notebook 04 resumes the training
    # exactly from the checkpoint (provenance.json: resumed_from_step)
    case ${CHECKPOINT:-0} in
    1)
      python3 - "$src" <<'PY' || die "$src: HBEONet's training has not finished: nothing to stage (CHECKPOINT=cut stages its latest checkpoint to resume from)"
import csv, json, sys
from pathlib import Path
run = Path(sys.argv[1])
epochs = json.loads((run / "manifest.json").read_text())["profile_settings"]["epochs"]
log = list(csv.DictReader(open(run / "train_model" / "train_log.csv")))
sys.exit(not ((run / "model.hbeo").is_file() and (run / "train_model" / "checkpoint.pt").is_file()
              and log and int(log[-1]["epoch"]) == epochs and (run / "train_model" / "provenance.json").is_file()))
PY
      skip='^(04_|train_model_opt_)' ;;                 # notebook 04's later products: remade when it runs again
    cut)
      [ -f "$src/train_model/checkpoint.pt" ] || die "$src: no HBEONet checkpoint (train_model/checkpoint.pt) to resume from"
      [ -f "$src/subspace.npz" ] || die "$src: no subspace.npz (notebook 02)"
      skip='^(04_|train_model_opt_|model\.hbeo$|train_model/provenance\.json$)' cut=1 ;;
    *) die "$src: notebook 04 has not finished (CHECKPOINT=1 stages HBEONet's final checkpoint when only its training has, CHECKPOINT=cut its latest one when the training was cut off)" ;;
    esac
  fi
  ! finished "$src/manifest.json" 05_classification || die "$src: notebooks 05-08 ran too; land the run instead"
  [ -z "$(git -C "$CLONE" status --porcelain --untracked-files=no -- hbeo notebooks scripts Makefile)" ] \
    || die "$CLONE: its code differs from its commit"
  for f in "$CLONE/$R"/0[5-8]_*.ipynb; do          # a notebook after 04 started (and was stopped): not staged
    [ -e "$f" ] || continue
    unchanged "${f#$CLONE/}" || die "$f: notebooks after 04 started there; restore or remove their files first (git checkout / rm)"
  done
  rm -rf "$S" && mkdir -p "$S"
  n=0
  # every file of the run folder that the clone's commit does not hold as it is now (a file --fresh deleted, the
  # previous reference's, is not there), less what this checkout's .gitignore keeps out of the stage folder (the
  # run folder's rules: checkpoints, renderings, grids, subspace, the option models)
  while IFS= read -r -d '' f; do
    unchanged "$f" && continue
    [ -n "$skip" ] && [[ ${f#$R/} =~ $skip ]] && continue
    [ -n "$skip" ] && [ "${f#$R/}" = train_model/checkpoint.pt ] \
      || { git check-ignore -q --no-index -- "$S/${f#$R/}" && continue; }
    mkdir -p "$S/$(dirname "${f#$R/}")" && cp -p "$CLONE/$f" "$S/${f#$R/}" && n=$((n + 1))
  done < <(cd "$CLONE" && find "$R" -type f -print0 | sort -z)
  if [ "$cut" = 1 ]; then
    (cd "$src" && sha256sum subspace.npz) > "$S/subspace.sha256"
  else
    [ -f "$S/model.hbeo" ] || die "$src/model.hbeo was not among the changed files"
  fi
  python3 - "$src/manifest.json" "$S/STAGE.md" "$n" <<'PY'
import csv, json, sys
from pathlib import Path
m = json.load(open(sys.argv[1]))
nb = m["notebooks"]
seed = (m.get("seeds") or {}).get("training", 0)
env, make_seed = (f"SEED={seed} ", f" SEED={seed}") if seed else ("", "")
lines = [f"# A run in progress: the first notebooks of `{m['git_tag'] or m['git_commit']}`", "",
         f"Made by `make reproduce PROFILE={m['profile']} DATASET={m['dataset']}{make_seed}` in a clean clone at commit "
         f"`{m['git_commit']}`{f' (tag `' + m['git_tag'] + '`)' if m['git_tag'] else ''}, git_dirty "
         f"{str(m['git_dirty']).lower()}; {sys.argv[3]} files, "
         "staged by `bash maintainer/reference_stage.sh save CLONE` because the run does not fit one session.", "",
         "| notebook | wall s | finished (UTC) |", "| --- | ---: | --- |"]
lines += [f"| {k} | {v['wall_s']} | {v['finished_utc']} |" for k, v in nb.items()]
last = "04" if "04_train" in nb else "03"
staged = Path(sys.argv[2]).parent
if last == "03" and (staged / "subspace.sha256").is_file():
    log = list(csv.DictReader(open(staged / "train_model" / "train_log.csv")))
    done = f"epoch {log[-1]['epoch']} (step {log[-1]['step']})" if log else "no epoch"
    lines += ["", f"Notebook 04 was stopped during HBEONet's training, after {done} of "
              f"{m['profile_settings']['epochs']} epochs: `train_model/checkpoint.pt` is that training's latest checkpoint "
              "(added with `git add -f`; it may be some steps past the log's last epoch), from which notebook 04, run again "
              "at the same commit, resumes the training exactly (provenance.json: resumed_from_step) and then runs its "
              "option trainings and evaluation. `subspace.sha256` is the run's subspace, which finish fits again "
              "(notebook 02's fit; no model file holds it yet) and refuses to go on from if it differs."]
elif last == "03":
    lines += ["", "Notebook 04 was stopped after HBEONet's training finished (its option trainings and evaluation had not "
              "run): `train_model/checkpoint.pt` is that training's final checkpoint (added with `git add -f`), from "
              "which notebook 04, run again at the same commit, trains nothing (provenance.json: resumed_from_step)."]
lines += ["", f"Not a result yet: notebooks {int(last) + 1:02d}-08 have not run. The next session finishes the run from these files "
          f"(`git clone`, `git checkout {m['git_commit']}`, `{env}bash maintainer/reference_stage.sh finish CLONE`), lands it "
          "and removes this folder.", ""]
open(sys.argv[2], "w").write("\n".join(lines))
PY
  echo "staged $n files of $src in $S (see $S/STAGE.md); commit them"
  ;;
finish)
  [ -f "$S/manifest.json" ] || die "$S/manifest.json: nothing staged"
  commit=$(python3 -c "import json; print(json.load(open('$S/manifest.json'))['git_commit'])")
  [ "$(git -C "$CLONE" rev-parse HEAD)" = "$commit" ] || die "$CLONE is not at the run's commit $commit"
  [ -z "$(git -C "$CLONE" status --porcelain --untracked-files=no)$(git -C "$CLONE" ls-files -o -- "$R")" ] \
    || die "$CLONE is not a clean clone (changed files, or files in $R)"
  [ -f "$S/model.hbeo" ] || { [ -f "$S/subspace.sha256" ] && [ -f "$S/train_model/checkpoint.pt" ]; } \
    || die "$S: neither a model.hbeo nor a cut training's checkpoint and subspace.sha256"
  tag=$(python3 -c "import json; print(json.load(open('$S/manifest.json'))['git_tag'] or '')")
  if [ -n "$tag" ] && ! git -C "$CLONE" rev-parse -q --verify "refs/tags/$tag" >/dev/null; then
    git -C "$CLONE" tag "$tag" "$commit"             # tags do not survive a session: the manifest keeps its tag
  fi
  cd "$CLONE"
  PY=.venv/bin/python
  make setup
  mkdir -p "$R"
  $PY -c "from hbeo.report.notebooks import clear_products
for p in clear_products('$R'): print('[stage] removed', p)"
  (cd "$MAIN/$S" && find . -type f ! -name STAGE.md ! -name subspace.sha256 -print0) | (cd "$MAIN/$S" && xargs -0 cp -p --parents -t "$CLONE/$R")
  $PY -m hbeo voxelize --profile $P --dataset $D --out $R
  if [ -f "$MAIN/$S/model.hbeo" ]; then
    basis_of "$R/model.hbeo"
  else                                    # a cut training (CHECKPOINT=cut): notebook 02's fit again, checked
    $PY -c "from hbeo.run import Run
Run.open('$P', '$D', '$R', training_seed=$SEED).fit_subspace(progress=False)"
    want=$(cut -d' ' -f1 "$MAIN/$S/subspace.sha256")
    got=$(sha256sum "$R/subspace.npz" | cut -d' ' -f1)
    ref=$MAIN/results/$P-$D/model.hbeo               # the seed-0 run's model: every seed's run fits seed 0's subspace
    if [ "$got" != "$want" ] && [ "$SEED" != 0 ] && [ -f "$ref" ]; then
      # the fit's floating point differs between CPUs (AVX-512 and AVX2 kernels): the subspace the staged training
      # used is then taken from the seed-0 run's model file, and accepted only if it gives the staged bytes
      echo "[stage] the subspace fitted again on this CPU differs ($got); taking $ref's basis" >&2
      basis_of "$ref"
      got=$(sha256sum "$R/subspace.npz" | cut -d' ' -f1)
    fi
    [ "$got" = "$want" ] || die "$R/subspace.npz (fitted again, or the seed-0 run's) is $got, not the staged training's $want: its checkpoint cannot go on"
  fi
  $PY -m hbeo render --profile $P --dataset $D --out $R --split train --quiet
  if finished "$MAIN/$S/manifest.json" 04_train; then todo="05 06 07 08"; else todo="04 05 06 07 08"; fi
  $PY -m hbeo reproduce --profile $P --dataset $D --seed $SEED --only $todo
  [ "${AFTER:-1}" = 0 ] || [ "$SEED" != 0 ] || SKIP_RUN=1 bash maintainer/reference_run.sh $PY
  ;;
*) die "unknown step $1 (save or finish)" ;;
esac
