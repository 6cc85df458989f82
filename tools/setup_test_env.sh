#!/bin/sh
# Installs what tests/addon needs beyond the project venv (.venv with bpy 5.0):
#   - Debian's Blender 3.4 binary and the numpy its Python uses;
#   - a bpy 4.2 LTS venv in build/venv-bpy42 for the 4.2 test run;
#   - bpy 4.5 LTS / 5.1 / 5.2 / 5.3 venvs (build/venv-bpy45 ... venv-bpy53) with the renderer's wheels;
#   - the wheels the add-on zips bundle, in build/wheels;
#   - Node.js, which runs the Flamenco job type's tests (tests/farm).
# Safe to run again: each step is skipped when already done.
set -eu
cd "$(dirname "$0")/.."

# need_space GIB WHAT: stop with a plain message, before pip does, when the disk cannot hold WHAT
# (a full disk otherwise shows up as pip's "OSError: [Errno 28]" halfway through a wheel).
need_space() {
    free_kib=$(df -Pk . | awk 'NR == 2 {print $4}')
    if [ "$free_kib" -lt $(($1 * 1024 * 1024)) ]; then
        echo "error: $2 needs about $1 GiB of free disk; $(($free_kib / 1024)) MiB are free on $(df -P . | awk 'NR == 2 {print $6}')" >&2
        exit 1
    fi
}

# python3-openvdb: Blender 3.4's Python reads Volume objects' grids with it.
if ! command -v blender >/dev/null 2>&1 || ! /usr/bin/python3 -c 'import numpy, pyopenvdb' 2>/dev/null; then
    if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq blender python3-numpy python3-openvdb >/dev/null
fi

if ! command -v node >/dev/null 2>&1; then
    if [ "$(id -u)" = 0 ]; then SUDO=; else SUDO=sudo; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq nodejs >/dev/null
fi

if [ ! -x build/venv-bpy42/bin/python ] || ! build/venv-bpy42/bin/python -c 'import bpy, pytest' 2>/dev/null; then
    need_space 2 "the bpy 4.2 venv (build/venv-bpy42)"
    PY=$(command -v python3.11 || echo .venv/bin/python)
    "$PY" -m venv build/venv-bpy42
    build/venv-bpy42/bin/pip install -q 'bpy==4.2.23' 'numpy==1.26.4' pytest
fi

# Blender 4.5 LTS (bpy 4.5, CPython 3.11) and 5.1-5.3 (bpy 5.1-5.3, CPython 3.13 only): one venv
# each with the renderer's native wheels, so the portable tests (export, passes, a Cycles parity)
# run there too (tests/addon/test_other_blenders.py).  CPython 3.13 is taken from PATH or pyenv;
# under CI=true a missing interpreter fails the set-up, elsewhere those versions are left out
# (their tests then fail, or skip with EMBER_ALLOW_SKIPS=1).  Each venv's numba kernels are
# compiled into the disk cache here, so no test waits for them.
find_python() {  # find_python 3.13: a CPython 3.13 that runs (a pyenv shim may not)
    root=$(pyenv root 2>/dev/null || echo "${PYENV_ROOT:-$HOME/.pyenv}")
    for candidate in "$(command -v "python$1" || true)" $(ls -d "$root"/versions/"$1".*/bin/python"$1" 2>/dev/null | sort -rV); do
        if [ -n "$candidate" ] && "$candidate" -c "import sys, venv; assert sys.version.startswith('$1.')" 2>/dev/null; then
            echo "$candidate"; return
        fi
    done
}
# venv, bpy pin, numpy pin, Python version.  bpy 5.1.0's metadata asks for numpy < 2, which has no
# CPython 3.13 wheel (5.1.1 corrected it to >= 2.2): its bpy goes in with --no-deps.
BLENDER_VENVS='venv-bpy45 bpy==4.5.15 numpy==1.26.4 3.11
venv-bpy51 bpy==5.1.0 numpy==2.2.6 3.13
venv-bpy52 bpy==5.2.3 numpy==2.2.6 3.13
venv-bpy53 bpy==5.3.0 numpy==2.2.6 3.13'
RENDER_WHEELS='embreex==4.4.0.post1 openimageio==3.0.21.0 numba==0.68.1 llvmlite==0.50.0 threadpoolctl==3.8.0 pytest'
echo "$BLENDER_VENVS" | while read -r venv bpy numpy pyver; do
    dir=build/$venv
    stamp=$dir/.ember-kernels-$(.venv/bin/python -c 'import sys; sys.path.insert(0, "."); from engine import kernels; print(kernels.source_hash())')
    if [ -x "$dir/bin/python" ] && "$dir/bin/python" -c 'import bpy, embreex, numba, OpenImageIO, pytest' 2>/dev/null \
        && { [ -f "$stamp" ] || [ "${EMBER_JIT:-1}" = 0 ]; }; then
        continue
    fi
    PY=$(find_python "$pyver")
    if [ -z "$PY" ]; then
        if [ "${CI:-}" = true ]; then
            echo "error: CPython $pyver is needed for $bpy ($dir) and was found neither on PATH nor under pyenv" >&2
            exit 1
        fi
        echo "warning: no CPython $pyver (PATH or pyenv): $dir ($bpy) not built" >&2
        continue
    fi
    if ! "$dir/bin/python" -c 'import bpy, embreex, numba, OpenImageIO, pytest' 2>/dev/null; then
        need_space 3 "the $bpy venv ($dir)"
        [ -x "$dir/bin/python" ] || "$PY" -m venv "$dir"
        "$dir/bin/pip" install -q --only-binary=:all: "$numpy" $RENDER_WHEELS
        "$dir/bin/pip" install -q --only-binary=:all: --no-deps "$bpy"
        "$dir/bin/pip" install -q --only-binary=:all: cython requests zstandard cattrs
    fi
    if [ "${EMBER_JIT:-1}" != 0 ]; then
        rm -f "$dir"/.ember-kernels-*
        PYTHONPATH="$PWD" "$dir/bin/python" -m engine --compile-kernels
        touch "$stamp"
    fi
done

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
build_zip.extension_wheel_files('build/wheels')  # CPython 3.11 and 3.13
build_zip.fetch_oidn_wheel('build/wheels')
print("wheels ready in build/wheels")
PY
