"""Builds the installable Ember packages for Blender.

    python tools/build_zip.py            # both zips into dist/
    python tools/build_zip.py --legacy   # only the legacy add-on zip

* ``dist/ember-<version>-addon.zip``: a legacy add-on for Blender 3.4 and later
  (Preferences > Add-ons > Install, or unzip into scripts/addons/).  The wheels
  Blender lacks are unpacked into ``ember/vendor/site`` and put on sys.path by
  ``ember/backend.py``.  They are CPython 3.11 wheels (Blender 3.4-5.0); in
  Blender 5.1+ (Python 3.13) install the extension.
* ``dist/ember-<version>-extension.zip``: an extension for Blender 4.2+
  (``blender --command extension install-file -r user_default FILE`` or drag
  and drop), with ``blender_manifest.toml`` listing the bundled wheels, which
  Blender installs itself: CPython 3.11 wheels (Blender 4.2-5.0) and 3.13
  wheels (5.1+) side by side, of which Blender installs those matching its
  Python (``bl_pkg`` filters a manifest's wheels by their python tag).

Both contain ``addon/`` as the package ``ember`` (its modules import each other
relatively) with the renderer vendored as ``ember.vendor.engine``, so nothing
installed is called ``addon`` or ``engine`` and nothing collides with other
modules.  The wheels are the ones the renderer imports (found by scanning
engine/ for imports), downloaded once with pip into build/wheels for CPython
3.11 and 3.13 on Linux x86-64, the platforms of Blender 3.4-5.0 and 5.1-5.3.
"""
import argparse
import ast
import os
import re
import shutil
import subprocess
import sys
import zipfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PACKAGE = 'ember'
# Native packages Blender does not ship, by import name -> pip requirement.
WHEELS = {
    'embreex': 'embreex==4.4.0.post1',
    'OpenImageIO': 'openimageio==3.0.21.0',
    'numba': 'numba==0.68.1',       # compiled kernels (engine/kernels.py)
    'llvmlite': 'llvmlite==0.50.0',  # numba's compiler, needed with it
    'threadpoolctl': 'threadpoolctl==3.8.0',  # one BLAS thread while rendering (engine/blas.py)
}
# Wheels another bundled wheel needs, by import name.
DEPENDS = {'numba': ('llvmlite',)}
PYTHON_VERSION = '3.11'           # Blender 3.4-5.0: the legacy zip's wheels
EXTENSION_PYTHONS = ('3.11', '3.13')  # Blender 4.2-5.0 and 5.1+: the extension's
PLATFORM_TAG = 'manylinux_2_28_x86_64'
# Intel Open Image Denoise for addon/denoise.py where Blender has none (3.4):
# only the CPU device, its TBB and the oidnDenoise program of the wheel.
OIDN_REQUIREMENT = 'pyoidn==2.5.1.0'
OIDN_FILES = re.compile(r'^pyoidn/oidn/(bin/oidnDenoise|lib/libOpenImageDenoise\.so\.2'
                        r'|lib/libOpenImageDenoise_(core|device_cpu)\.so\.[.0-9]+|lib/libtbb\.so\.12)$')
IGNORED = shutil.ignore_patterns('__pycache__', '*.pyc', '*.pyo', '.pytest_cache')


def addon_version():
    """(major, minor, patch) from bl_info, read without importing bpy."""
    with open(os.path.join(ROOT, 'addon', '__init__.py'), encoding='utf-8') as handle:
        tree = ast.parse(handle.read())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], 'id', '') == 'bl_info':
            return tuple(ast.literal_eval(node.value)['version'])
    raise SystemExit("addon/__init__.py has no bl_info")


def engine_imports():
    """Top-level modules imported anywhere in engine/."""
    names = set()
    for folder, _, files in os.walk(os.path.join(ROOT, 'engine')):
        for name in files:
            if name.endswith('.py'):
                with open(os.path.join(folder, name), encoding='utf-8') as handle:
                    tree = ast.parse(handle.read())
                for node in ast.walk(tree):
                    if isinstance(node, ast.Import):
                        names.update(alias.name.split('.')[0] for alias in node.names)
                    elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                        names.add(node.module.split('.')[0])
    return names


def check_engine_is_relocatable():
    """The vendored renderer must import itself relatively (it becomes ember.vendor.engine)."""
    if 'engine' in engine_imports():
        raise SystemExit("engine/ imports 'engine' absolutely; use relative imports so it can be vendored")


def needed_wheels():
    imported = engine_imports() | {'embreex'}  # the renderer's ray tracer
    for module in list(imported):
        imported.update(DEPENDS.get(module, ()))
    return [requirement for module, requirement in WHEELS.items() if module in imported]


def fetch_wheels(requirements, wheel_dir, python=PYTHON_VERSION):
    """Wheel files for the requirements and CPython ``python`` ('3.11'),
    downloaded once into wheel_dir."""
    os.makedirs(wheel_dir, exist_ok=True)
    tag = 'cp' + python.replace('.', '')
    found = []
    for requirement in requirements:
        name, version = requirement.split('==')
        pattern = re.compile(rf"^{re.escape(name)}-{re.escape(version)}-({tag}-.*x86_64.*|py3-none-any)\.whl$", re.I)
        matches = [f for f in os.listdir(wheel_dir) if pattern.match(f)]
        if not matches:
            subprocess.check_call([
                sys.executable, '-m', 'pip', 'download', '--quiet', '--no-deps', '--only-binary=:all:',
                '--python-version', python, '--platform', PLATFORM_TAG,
                '-d', wheel_dir, requirement])
            matches = [f for f in os.listdir(wheel_dir) if pattern.match(f)]
        if not matches:
            raise SystemExit(f"no Linux x86-64 CPython {python} wheel for {requirement}")
        found.append(os.path.join(wheel_dir, sorted(matches)[-1]))
    return found


def extension_wheel_files(wheel_dir):
    """The extension's wheels: every needed wheel for each of EXTENSION_PYTHONS
    (a pure-Python wheel once)."""
    files = []
    for python in EXTENSION_PYTHONS:
        files.extend(w for w in fetch_wheels(needed_wheels(), wheel_dir, python) if w not in files)
    return files


def fetch_oidn_wheel(wheel_dir):
    """The pyoidn wheel (pure-Python tag, native libraries inside), downloaded once."""
    os.makedirs(wheel_dir, exist_ok=True)
    prefix = OIDN_REQUIREMENT.replace('==', '-') + '-'
    matches = [f for f in os.listdir(wheel_dir) if f.startswith(prefix) and f.endswith('x86_64.whl')]
    if not matches:
        subprocess.check_call([sys.executable, '-m', 'pip', 'download', '--quiet', '--no-deps',
                               '--only-binary=:all:', '--platform', 'manylinux2014_x86_64',
                               '-d', wheel_dir, OIDN_REQUIREMENT])
        matches = [f for f in os.listdir(wheel_dir) if f.startswith(prefix) and f.endswith('x86_64.whl')]
    if not matches:
        raise SystemExit(f"no Linux x86-64 wheel for {OIDN_REQUIREMENT}")
    return os.path.join(wheel_dir, sorted(matches)[-1])


def vendor_oidn(package, wheel):
    """Unpack OIDN's CPU libraries and oidnDenoise into <package>/vendor/oidn."""
    target = os.path.join(package, 'vendor', 'oidn')
    with zipfile.ZipFile(wheel) as archive:
        for member in archive.namelist():
            if OIDN_FILES.match(member):
                path = os.path.join(target, member[len('pyoidn/oidn/'):])
                os.makedirs(os.path.dirname(path), exist_ok=True)
                with archive.open(member) as source, open(path, 'wb') as dest:
                    shutil.copyfileobj(source, dest)
                os.chmod(path, 0o755)
    return target


def stage_package(stage):
    """addon/ as ember/ with engine/ vendored inside; returns the package folder."""
    package = os.path.join(stage, PACKAGE)
    shutil.rmtree(stage, ignore_errors=True)
    shutil.copytree(os.path.join(ROOT, 'addon'), package, ignore=IGNORED)
    vendor = os.path.join(package, 'vendor')
    os.makedirs(vendor, exist_ok=True)
    with open(os.path.join(vendor, '__init__.py'), 'w', encoding='utf-8') as handle:
        handle.write('"""Third-party code bundled with Ember: the renderer and, in the legacy zip, wheels."""\n')
    shutil.copytree(os.path.join(ROOT, 'engine'), os.path.join(vendor, 'engine'), ignore=IGNORED)
    return package


def unpack_wheels(wheels, site):
    os.makedirs(site, exist_ok=True)
    for wheel in wheels:
        with zipfile.ZipFile(wheel) as archive:
            archive.extractall(site)


def write_zip(source, zip_path, prefix=''):
    """Zip a folder; entries are stored under ``prefix``.  Keeps file modes (the
    unpacked wheels' shared libraries)."""
    os.makedirs(os.path.dirname(zip_path), exist_ok=True)
    with zipfile.ZipFile(zip_path, 'w', zipfile.ZIP_DEFLATED) as archive:
        for folder, dirs, files in os.walk(source):
            dirs.sort()
            for name in sorted(files):
                path = os.path.join(folder, name)
                # Wheels are zips already: stored, not deflated again (seconds per build).
                compress = zipfile.ZIP_STORED if name.endswith('.whl') else zipfile.ZIP_DEFLATED
                archive.write(path, os.path.join(prefix, os.path.relpath(path, source)), compress_type=compress)
    return zip_path


def manifest(version, wheels):
    wheel_lines = ",\n".join(f'  "./wheels/{os.path.basename(w)}"' for w in wheels)
    return f'''schema_version = "1.0.0"

id = "{PACKAGE}"
version = "{'.'.join(map(str, version))}"
name = "Ember"
tagline = "Physically based path tracer written in Python"
maintainer = "Ember developers"
type = "add-on"
tags = ["Render"]
blender_version_min = "4.2.0"
license = ["SPDX:GPL-3.0-or-later"]
platforms = ["linux-x64"]
wheels = [
{wheel_lines}
]
'''


def build_legacy(version, wheels, build_dir, dist_dir, oidn_wheel=None):
    stage = os.path.join(build_dir, 'legacy')
    package = stage_package(stage)
    if oidn_wheel:
        vendor_oidn(package, oidn_wheel)
    unpack_wheels(wheels, os.path.join(package, 'vendor', 'site'))
    name = f"{PACKAGE}-{'.'.join(map(str, version))}-addon.zip"
    return write_zip(stage, os.path.join(dist_dir, name))


def build_extension(version, wheels, build_dir, dist_dir, oidn_wheel=None):
    stage = os.path.join(build_dir, 'extension')
    package = stage_package(stage)
    if oidn_wheel:
        vendor_oidn(package, oidn_wheel)
    wheel_dir = os.path.join(package, 'wheels')
    os.makedirs(wheel_dir)
    for wheel in wheels:
        shutil.copy2(wheel, wheel_dir)
    with open(os.path.join(package, 'blender_manifest.toml'), 'w', encoding='utf-8') as handle:
        handle.write(manifest(version, wheels))
    name = f"{PACKAGE}-{'.'.join(map(str, version))}-extension.zip"
    # Extension zips hold the manifest at their root.
    return write_zip(package, os.path.join(dist_dir, name))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--dist', default=os.path.join(ROOT, 'dist'), help="output folder (default dist/)")
    parser.add_argument('--build', default=os.path.join(ROOT, 'build'), help="scratch folder (default build/)")
    parser.add_argument('--wheels', default=None, help="wheel cache (default BUILD/wheels)")
    parser.add_argument('--legacy', action='store_true', help="build only the legacy add-on zip")
    parser.add_argument('--extension', action='store_true', help="build only the extension zip")
    args = parser.parse_args(argv)
    check_engine_is_relocatable()
    version = addon_version()
    wheel_dir = args.wheels or os.path.join(args.build, 'wheels')
    wheels = fetch_wheels(needed_wheels(), wheel_dir)
    oidn_wheel = fetch_oidn_wheel(wheel_dir)
    built = []
    if not args.extension:
        built.append(build_legacy(version, wheels, args.build, args.dist, oidn_wheel))
    if not args.legacy:
        extension_wheels = extension_wheel_files(wheel_dir)
        built.append(build_extension(version, extension_wheels, args.build, args.dist, oidn_wheel))
    for path in built:
        print(f"{path} ({os.path.getsize(path) / 1e6:.1f} MB)")
    return built


if __name__ == '__main__':
    main()
