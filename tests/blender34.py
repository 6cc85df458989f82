"""Debian's Blender 3.4 binary and the legacy zip installed into it, shared
by every test that runs that binary (tests/addon, tests/farm).

The zip is built and unpacked once per session: numba keys its kernel cache
by the source folder, so one unpacked add-on compiles its kernels once
(60-100 s in the binary's Python, more on a busy machine) and every later test
loads them; an unpacked copy per test paid that compile six times.  The
session fixture compiles them before the first test (``compile_kernels``), so
no test's own time limit holds the compile.
"""
import os
import shutil
import subprocess
import sys
import zipfile

from prerequisites import require

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLENDER = shutil.which('blender') or '/usr/bin/blender'


def blender_version():
    if not os.path.exists(BLENDER):
        return None
    out = subprocess.run([BLENDER, '--version'], capture_output=True, text=True)
    lines = (out.stdout + out.stderr).splitlines()
    return lines[0] if out.returncode == 0 and lines else None


def require_blender_34():
    version = blender_version()
    require(version is not None and version.startswith('Blender 3.4'),
            f"Debian's Blender 3.4 binary is needed at {BLENDER} (tools/setup_test_env.sh): found {version}")


def build_legacy_zip(folder):
    return build_package(folder, 'legacy')


def build_package(folder, kind):
    """tools/build_zip.py's 'legacy' or 'extension' zip, built in folder."""
    sys.path.insert(0, os.path.join(ROOT, 'tools'))
    try:
        import build_zip
    finally:
        sys.path.pop(0)
    try:
        (zip_path,) = build_zip.main(['--dist', str(folder), '--build', os.path.join(str(folder), 'build'),
                                      '--wheels', os.path.join(ROOT, 'build', 'wheels'), '--' + kind])
    except (subprocess.CalledProcessError, SystemExit) as err:
        require(False, f"could not build the {kind} zip (wheels need pip and PyPI): {err}")
    return zip_path


def unpack_addon(zip_path, folder):
    """The zip unpacked as Blender's user scripts folder (BLENDER_USER_SCRIPTS)."""
    scripts = os.path.join(str(folder), 'scripts')
    addons = os.path.join(scripts, 'addons')
    os.makedirs(addons)
    with zipfile.ZipFile(zip_path) as archive:
        archive.extractall(addons)
    for path, _, files in os.walk(addons):  # zipfile drops the execute bits
        for name in files:
            if '.so' in name:
                os.chmod(os.path.join(path, name), 0o755)
    return scripts


COMPILE_SCRIPT = """
import sys
from ember import backend
backend.require_ray_tracer()
seconds = backend.engine().warm_kernel_cache()
print(f"ember kernels compiled in {seconds:.1f} s")
sys.stdout.flush()
"""


def compile_kernels(scripts, timeout=1800):
    """Compile the unpacked add-on's kernels into numba's cache in the 3.4
    binary (its Python and numba), once per session; a failure names itself
    (the tests then compile in their first render)."""
    if blender_version() is None:
        return None
    env = dict(os.environ, BLENDER_USER_SCRIPTS=str(scripts))
    env.pop('PYTHONPATH', None)
    cmd = [BLENDER, '-b', '--addons', 'ember', '--python-expr', COMPILE_SCRIPT]
    try:
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return f"kernels not compiled within {timeout} s"
    lines = [line for line in (out.stdout + out.stderr).splitlines() if 'ember kernels compiled' in line]
    return lines[0] if lines else f"kernel compile failed: {(out.stdout + out.stderr)[-800:]}"
