#!/usr/bin/env bash
# Creates .venv with Ember's pinned dependencies (idempotent, quick when done).
# Optional: EMBER_WITH_BLENDER=1 also installs Debian's Blender 3.4 binary for
# the real-binary test (needs root / apt).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
stamp=.venv/.ember-deps
if [ ! -x .venv/bin/python ]; then
  if ! "$PY" -m venv .venv 2>/dev/null; then
    # Debian's python3 needs python3-venv for `-m venv`.
    if [ "$(id -u)" = 0 ]; then
      apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q python3-venv
      rm -rf .venv && "$PY" -m venv .venv
    else
      echo "error: '$PY -m venv' failed; install python3-venv (sudo apt-get install python3-venv)" >&2
      exit 1
    fi
  fi
fi
if [ ! -f "$stamp" ] || [ requirements.txt -nt "$stamp" ]; then
  .venv/bin/python -m pip install -q --upgrade pip
  .venv/bin/python -m pip install -q -r requirements.txt
  touch "$stamp"
fi
# The checkout on the venv's path (a .pth file, as Makefile's PYTHONPATH):
# engine/ and farm/ then import in every process of the venv, among them a
# `dask scheduler` started from any folder, which unpickles the farm's tasks
# and must import the module they name.  (An editable pip install would do
# the same through a build backend and its own downloads; this needs none.)
site=$(.venv/bin/python -c 'import sysconfig; print(sysconfig.get_paths()["purelib"])')
printf '%s\n' "$PWD" > "$site/ember-checkout.pth"
if [ "${EMBER_WITH_BLENDER:-0}" = 1 ] && ! command -v blender >/dev/null 2>&1; then
  if [ "$(id -u)" = 0 ]; then
    apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q blender python3-numpy
  else
    echo "warning: Debian's blender is not installed and we are not root; the real-binary test will fail under CI=true" >&2
  fi
fi
# Compile Ember's kernels into numba's disk cache now (once per version of the
# engine's sources; seconds when already done), so that no render waits for
# them or runs on NumPy for lack of them.
if [ "${EMBER_JIT:-1}" != 0 ]; then
  PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" .venv/bin/python -m engine --compile-kernels
fi
