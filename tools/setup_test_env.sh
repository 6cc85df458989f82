#!/bin/sh
# Installs what tests/addon needs beyond the project venv (.venv with bpy 5.0):
#   - Debian's Blender 3.4 binary and the numpy its Python uses;
#   - a bpy 4.2 LTS venv in build/venv-bpy42 for the 4.2 test run;
#   - the wheels the add-on zips bundle, in build/wheels;
#   - Node.js, which runs the Flamenco job type's tests (tests/farm).
# Safe to run again: each step is skipped when already done.
set -eu
cd "$(dirname "$0")/.."

if ! command -v blender >/dev/null 2>&1 || ! /usr/bin/python3 -c 'import numpy' 2>/dev/null; then
    if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq blender python3-numpy >/dev/null
fi

if ! command -v node >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq nodejs >/dev/null
fi

if [ ! -x build/venv-bpy42/bin/python ] || ! build/venv-bpy42/bin/python -c 'import bpy, pytest' 2>/dev/null; then
    PY=$(command -v python3.11 || echo .venv/bin/python)
    "$PY" -m venv build/venv-bpy42
    build/venv-bpy42/bin/pip install -q 'bpy==4.2.23' 'numpy==1.26.4' pytest
fi

# The Rendered viewport test runs a real Blender window under Xvfb.
if ! command -v xvfb-run >/dev/null 2>&1 || ! command -v xauth >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq xvfb xauth >/dev/null
fi

.venv/bin/python - <<'PY'
import sys
sys.path.insert(0, 'tools')
import build_zip
build_zip.fetch_wheels(build_zip.needed_wheels(), 'build/wheels')
build_zip.fetch_oidn_wheel('build/wheels')
print("wheels ready in build/wheels")
PY
