#!/usr/bin/env bash
# Make what the device job needs to travel to a lent GPU machine, in .device/ (ignored by git, named in
# the device tool's `carry`): the 30^3 grid file, source.json (the commit that travels) and wheels of what the device image lacks (its Python is
# 3.12 with numpy 2 and torch 2.11 + CUDA; trimesh and pooch are not there, nor embreex: EMBREE=1 adds it). Then, on the device:
#     bash maintainer/device_job.sh            (see maintainer/device_job.py; README "Paper scale on one GPU")
# Usage: bash maintainer/device_prepare.sh [DEST]       (DEST default .device; WHEELS=0 skips the downloads)
# Exit 3 when the working tree and DEST together pass the device tool's 64 MiB (the largest files listed).
set -euo pipefail
cd "$(dirname "$0")/.."
DEST=${1:-.device}
PY=${PY:-python3}
mkdir -p "$DEST/whl"
GRID=$($PY -c "from hbeo import config; print(config.vox30_path())")
cp "$GRID" "$DEST/modelnet10_vox30.npz"
echo "grids: $GRID -> $DEST/modelnet10_vox30.npz"
if [ "${WHEELS:-1}" != "0" ]; then
  # pure-Python or cp312 manylinux wheels, pinned to requirements.txt's versions where the lock has them
  pin() { grep -E "^$1==" requirements.txt | head -1 || echo "$1"; }
  # embreex (14.6 MB) only with EMBREE=1: the grid dataset renders with torch there, and with the committed
  # results the tree would pass the device tool's 64 MiB
  for pkg in trimesh pooch $([ "${EMBREE:-0}" = "1" ] && echo embreex); do
    spec=$(pin "$pkg")
    $PY -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
      --platform any -d "$DEST/whl" "$spec"
  done
fi
# the code that travels, for lease.json (the device's copy has no .git): the commit, and whether tracked files
# outside results/ and docs/history/ (which device_tree.sh slim leaves behind) differ from it
if git rev-parse --git-dir > /dev/null 2>&1; then
  $PY -c "import json; from hbeo.report.provenance import git_state
g = git_state(exclude=('results', 'docs/history'))
print(json.dumps({'commit': g['git_commit'], 'dirty': g['git_dirty']}))" > "$DEST/source.json"
  echo "source: $(cat "$DEST/source.json")"
  # what travels: tracked files, untracked ones git does not ignore, and DEST; the device tool takes 64 MiB at most
  tree=$( { git ls-files -z; git ls-files -z -o --exclude-standard; } | du -cb --files0-from=- 2>/dev/null | tail -1 | cut -f1)
  dest=$(du -sb "$DEST" | cut -f1)
  total=$((tree + dest))
  limit=${LIMIT_MIB:-64}                     # the device tool's; a test sets another to reach the branch below
  echo "to travel: $((total / 1048576)) MiB (working tree $((tree / 1048576)) MiB + $DEST $((dest / 1048576)) MiB; limit $limit MiB)"
  if [ "$total" -gt $((limit * 1048576)) ]; then
    echo "over the device tool's $limit MiB: run 'bash maintainer/device_tree.sh slim' (the committed results and" \
         "docs/history stay behind; 'restore' after the call). The largest files that travel:" >&2
    { git ls-files -z; git ls-files -z -o --exclude-standard; } | du -b --files0-from=- 2>/dev/null | sort -rn | awk 'NR <= 5' >&2   # awk reads it all: head would end sort with SIGPIPE (exit 141 under pipefail)
    exit 3
  fi
else
  du -sh "$DEST" | awk '{print "to carry: " $2 " (" $1 "; the device tool carries 64 MiB at most)"}'
fi
