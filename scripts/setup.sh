#!/usr/bin/env bash
# Set up hbeo on a fresh Debian machine: Debian libraries for headless rendering, a virtual
# environment, the pinned Python packages, and the package itself (editable). Idempotent.
set -euo pipefail
PYTHON=${PYTHON:-python3}
VENV=${VENV:-.venv}
cd "$(dirname "$0")/.."

# Debian packages: python3-venv (a stock Debian python3 makes no virtual environment without it), the
# renderer's libraries (OSMesa for CPU machines, EGL for GPUs), and the headless browser that tests the run's
# book (tests/test_book.py drives it through playwright, which must not download its own).
DEB_PACKAGES="python3-venv libosmesa6 libegl1 libgl1 libgles2 libglu1-mesa chromium"
missing=""
for p in $DEB_PACKAGES; do
  dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"
done
if [ -n "$missing" ]; then
  if command -v apt-get >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
    echo "[setup] installing Debian packages:$missing"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
  else
    echo "[setup] warning: not a Debian system; install OSMesa/EGL (and chromium) yourself:$missing" >&2
  fi
fi

if [ ! -x "$VENV/bin/python" ]; then
  "$PYTHON" -c 'import sys; assert sys.version_info[:2] >= (3, 11), "Python >= 3.11 needed (the pinned pandas)"'
  "$PYTHON" -m venv "$VENV"
fi
# pip, quiet on success; on failure its whole output (minus mirror "is ignored" noise) and exit 1.
pip_q() {
  local out
  if ! out=$("$VENV/bin/python" -m pip -q "$@" 2>&1); then
    printf '%s\n' "$out" | grep -v "is ignored" >&2
    echo "[setup] pip $* failed" >&2
    return 1
  fi
}
pip_q install --upgrade pip
pip_q install -r requirements.txt
pip_q install --no-deps -r requirements-nodeps.txt
pip_q install --no-deps -e .
"$VENV/bin/python" -m ipykernel install --sys-prefix --name python3 >/dev/null
"$VENV/bin/python" -c "import hbeo, torch, trimesh, pyrender, papermill, nbval, nbconvert, latex2mathml, playwright; print('[setup] ok:', hbeo.__file__)"
