#!/usr/bin/env bash
# The device job's entry on a lent GPU machine (run from the repository root, with .device carried):
#     bash maintainer/device_job.sh [device_job.py options]     e.g. --profile gpu-lease --wait 540
# Installs the carried wheels (.device/whl) into /tmp/site, points HBEO_VOX30 at the carried grids, then runs
# maintainer/device_job.py, which starts or resumes the background worker, waits, and packs $OUT.
set -uo pipefail
cd "$(dirname "$0")/.."
DEV=${HBEO_DEVICE_DIR:-.device}
if compgen -G "$DEV/whl/*.whl" > /dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site \
    "$DEV"/whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site${PYTHONPATH:+:$PYTHONPATH}
fi
[ -f "$DEV/modelnet10_vox30.npz" ] && export HBEO_VOX30=${HBEO_VOX30:-$DEV/modelnet10_vox30.npz}
[ -f "$DEV/source.json" ] && export HBEO_DEVICE_SOURCE=${HBEO_DEVICE_SOURCE:-$DEV/source.json}
export PYTHONPATH=$PWD${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
exec "${PYTHON:-python3}" maintainer/device_job.py "$@"
