"""The add-on in every supported Blender: the real 3.4 binary, bpy 4.2 LTS,
bpy 4.5 LTS and 5.1 / 5.2 / 5.3 (CPython 3.13) and the installed packages
(legacy zip, extension zip).

Each runs in a subprocess with its own BLENDER_USER_RESOURCES: installing the
packages into this test process would register a second EMBER engine.
tools/setup_test_env.sh installs what these need (Debian's blender and
python3-numpy, a bpy 4.2 venv in build/venv-bpy42, the bpy 4.5-5.3 venvs with
the renderer's wheels and warm numba caches, the wheels).
"""
import concurrent.futures
import importlib.util
import os
import subprocess
import sys
import time
import zipfile

import numpy as np
import pytest

from blender34 import BLENDER, require_blender_34
from ember_testlib import ROOT, SCENES_DIR, load_exr, require

BPY42_PYTHON = os.path.join(ROOT, 'build', 'venv-bpy42', 'bin', 'python')
PORTABLE_TESTS = ['tests/addon/test_export.py', 'tests/addon/test_render_engine.py', 'tests/addon/test_blend_scenes.py',
                  'tests/engine/test_stats.py', 'tests/addon/test_pass_names.py',
                  # Renders through the engine, which these interpreters lack
                  # (no embreex there): Blender 3.4's pass names are rendered
                  # through the legacy zip in test_passes_parity instead.
                  '--deselect', 'tests/addon/test_pass_names.py::test_passes_have_this_blenders_names',
                  '--deselect', 'tests/addon/test_pass_names.py::test_written_passes_are_finite_and_meaningful',
                  '--deselect', 'tests/addon/test_pass_names.py::test_cryptomatte_manifest_in_metadata']


# Blender version -> its venv (tools/setup_test_env.sh): bpy with embreex, OpenImageIO and numba,
# so these run the rendering tests too.  5.1-5.3 are CPython 3.13 (numpy 2.2).
BPY_VENVS = {'4.5': 'venv-bpy45', '5.1': 'venv-bpy51', '5.2': 'venv-bpy52', '5.3': 'venv-bpy53'}
# What each of them runs (its count is printed): the export, the RenderEngine
# (registration, progress, errors, previews), the committed .blend files, the
# Cycles-named passes, and version_parity.py: a scene of the API-sensitive
# parts rendered as bpy 5.0 renders it (bpy 5.0's Ember is held to Cycles).
RENDERING_TESTS = ['tests/addon/test_export.py', 'tests/addon/test_render_engine.py',
                   'tests/addon/test_blend_scenes.py', 'tests/addon/test_pass_names.py',
                   'tests/addon/version_parity.py']


def bpy_python(version):
    return os.path.join(ROOT, 'build', BPY_VENVS[version], 'bin', 'python')


def run(cmd, env=None, timeout=600):
    merged = dict(os.environ)
    merged.update(env or {})
    merged.pop('PYTHONPATH', None)
    result = subprocess.run(cmd, cwd=ROOT, env=merged, capture_output=True, text=True, timeout=timeout)
    return result.returncode, result.stdout + result.stderr


def pytest_path(tmp_path):
    """A folder with links to this interpreter's pytest and its dependencies."""
    folder = tmp_path / 'pytest_site'
    folder.mkdir()
    for name in ('pytest', '_pytest', 'pluggy', 'iniconfig', 'packaging', 'py'):
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            continue
        source = os.path.dirname(spec.origin) if spec.submodule_search_locations else spec.origin
        (folder / os.path.basename(source)).symlink_to(source)
    return str(folder)


def install_legacy(legacy_addon):
    """The session's unpacked legacy zip (tests/conftest.py legacy_addon): one
    folder for every 3.4 test, so the binary compiles its kernels once."""
    return legacy_addon[1]


def test_portable_tests_in_blender_34_binary(tmp_path):
    require_blender_34()
    code, out = run([BLENDER, '-b', '--factory-startup', '--python-exit-code', '1',
                     '--python', 'tests/addon/blender_pytest.py', '--',
                     *PORTABLE_TESTS, '-q', '-p', 'no:cacheprovider', '-p', 'no:warnings',
                     # Background previews crash Blender 3.4 (Cycles too): test_previews_34.py
                     # renders them in a window under Xvfb.
                     '--deselect', 'tests/addon/test_render_engine.py::test_material_preview_renders_with_ember'],
                    env={'EMBER_PYTEST_PATH': pytest_path(tmp_path), 'CI': os.environ.get('CI', '')})
    summary = [line for line in out.splitlines() if ' passed' in line or ' failed' in line]
    print(summary[-1:] if summary else out[-3000:])
    assert code == 0, out[-5000:]


def test_portable_tests_in_bpy_42(tmp_path):
    require(os.path.exists(BPY42_PYTHON), f"a bpy 4.2 venv is needed at {BPY42_PYTHON} (tools/setup_test_env.sh)")
    code, out = run([BPY42_PYTHON, '-m', 'pytest', *PORTABLE_TESTS, '-q', '-p', 'no:cacheprovider',
                     '-p', 'no:warnings'], env={'CI': os.environ.get('CI', '')})
    print(out.strip().splitlines()[-1:])
    assert code == 0, out[-5000:]


@pytest.fixture(scope='module')
def version_runs(tmp_path_factory, registered_addon):
    """Each bpy version's run of RENDERING_TESTS, two at a time (they are
    mostly single-threaded: on two cores the four take the time of two), started
    on first use; version -> future of (exit code, output, wall seconds).
    bpy 5.0's render of the parity scene, which they must reproduce, is made
    here first."""
    from ember_testlib import engine_available
    import version_parity
    ok, reason = engine_available()
    require(ok, "engine.render is not importable: " + reason)
    folder = tmp_path_factory.mktemp('version_parity')
    expected = str(folder / 'expected.npz')
    version_parity.save_expected(expected, folder)

    def one(version):
        started = time.perf_counter()
        code, out = run([bpy_python(version), '-m', 'pytest', *RENDERING_TESTS, '-q', '-s',
                         '-p', 'no:cacheprovider', '-p', 'no:warnings'],
                        env={'CI': os.environ.get('CI', ''), 'EMBER_EXPECTED_RENDER': expected})
        return code, out, time.perf_counter() - started

    available = [v for v in BPY_VENVS if os.path.exists(bpy_python(v))]
    with concurrent.futures.ThreadPoolExecutor(2) as pool:
        yield {version: pool.submit(one, version) for version in available}


@pytest.mark.parametrize('version', sorted(BPY_VENVS))
def test_rendering_tests_in_bpy(version, version_runs):
    """bpy 4.5 LTS, 5.1, 5.2, 5.3: the export, RenderEngine, .blend, pass and
    parity tests pass there (the count and the seconds are printed)."""
    require(version in version_runs, f"a bpy {version} venv is needed at {bpy_python(version)} "
            "(tools/setup_test_env.sh; 5.1+ need CPython 3.13)")
    code, out, seconds = version_runs[version].result()
    summary = [line for line in out.splitlines() if ' passed' in line or ' failed' in line]
    parity = [line for line in out.splitlines() if 'largest relative pixel difference' in line]
    print(f"bpy {version}: {summary[-1] if summary else '?'} in {seconds:.1f} s wall; {parity}")
    assert code == 0, out[-5000:]
    assert parity, "version_parity.py did not run: " + out[-3000:]


EXTENSION_CHECK = r'''
import glob, os, sys, tempfile
import bpy
result = bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo='user_default', enable_on_install=True)
assert result == {'FINISHED'}, result
engines = {getattr(c, 'bl_idname', None) for c in bpy.types.RenderEngine.__subclasses__()}
assert 'EMBER' in engines, engines
assert 'addon' not in sys.modules and 'engine' not in sys.modules, "top-level names leaked"
# Blender installed the bundled wheels of this Python only (the zip carries cp311 and cp313).
import OpenImageIO
local = bpy.utils.user_resource('EXTENSIONS', path='.local')
tag = 'cpython-%d%d-' % sys.version_info[:2]
native = glob.glob(os.path.join(local, 'lib', 'python*', 'site-packages', '**', '*.cpython-3*.so'), recursive=True)
assert any('/embreex/' in f for f in native) and any('/numba/' in f for f in native), native
assert all(tag in os.path.basename(f) for f in native), (tag, [f for f in native if tag not in f][:5])
from importlib import import_module
export = import_module('bl_ext.user_default.ember.export.scene')
exported = export.export_scene(bpy.context.evaluated_depsgraph_get())
assert type(exported.scene).__module__ == 'bl_ext.user_default.ember.vendor.engine.scene'
# And renders: Blender's own render operator, through the installed extension.
bpy.ops.wm.open_mainfile(filepath=sys.argv[2])
scene = bpy.context.scene
scene.render.engine = 'EMBER'
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 16, 16, 100
scene.ember.samples, scene.ember.seed, scene.ember.threads = 4, 3, 2
bpy.ops.render.render()
log = import_module('bl_ext.user_default.ember.engine').RENDER_LOG[-1]
assert log['error'] is None, log['error']
path = os.path.join(sys.argv[3], 'extension.exr')
scene.render.image_settings.file_format = 'OPEN_EXR'
bpy.data.images['Render Result'].save_render(path)
image = OpenImageIO.ImageBuf(path).get_pixels(OpenImageIO.FLOAT)
print("EXTENSION OK", bpy.app.version_string, exported.triangles, image.shape, float(image[..., :3].mean()),
      bool((image == image).all()))
'''


@pytest.fixture(scope='module')
def extension_zip(tmp_path_factory):
    import blender34
    built = blender34.build_package(tmp_path_factory.mktemp('extension'), 'extension')
    with zipfile.ZipFile(built) as archive:
        wheels = [n for n in archive.namelist() if n.endswith('.whl')]
    for tag in ('cp311', 'cp313'):
        assert any(f'-{tag}-' in w and w.startswith('wheels/embreex') for w in wheels), (tag, wheels)
    return built


@pytest.mark.parametrize('version', ['5.0', '4.5', '5.3'])
def test_extension_installs_and_renders(tmp_path, extension_zip, version):
    """The one extension zip (cp311 and cp313 wheels) installs into bpy 5.0,
    4.5 LTS and 5.3 through Blender's own extension installer (the operator
    behind `blender --command extension install-file`), which picks the
    wheels of its Python, and renders the Cornell box with Blender's render
    operator: finite, not black, no recorded error."""
    python = sys.executable if version == '5.0' else bpy_python(version)
    require(os.path.exists(python), f"a bpy {version} venv is needed at {python} (tools/setup_test_env.sh)")
    script = tmp_path / 'check.py'
    script.write_text(EXTENSION_CHECK)
    # EMBER_JIT=0: the installed copy's kernels would compile into their own cache (its path is new).
    code, out = run([python, '-P', str(script), extension_zip, os.path.join(SCENES_DIR, 'cornell.blend'),
                     str(tmp_path)], env={'BLENDER_USER_RESOURCES': str(tmp_path / 'user'), 'EMBER_JIT': '0'})
    line = next((line for line in out.splitlines() if line.startswith('EXTENSION OK')), None)
    assert code == 0 and line is not None, out[-4000:]
    print(line)
    mean, finite = float(line.split()[-2]), line.split()[-1] == 'True'
    assert finite and mean > 0.02, line


def test_legacy_zip_renders_with_blender_34_binary(tmp_path, legacy_addon, needs_engine):
    """`blender -b scene --addons ember -E EMBER -f 1` writes the expected image."""
    require_blender_34()
    scripts = install_legacy(legacy_addon)
    settings = ("import bpy; s = bpy.context.scene; s.render.resolution_x = s.render.resolution_y = 32; "
                "s.render.resolution_percentage = 100; s.ember.samples = 16; s.ember.seed = 3; "
                "s.ember.max_bounces = 4; s.ember.threads = 2; s.render.image_settings.color_depth = '32'")
    out_pattern = str(tmp_path / 'frame_####')
    # Argument order matters: the add-on before the file (so the file's EMBER
    # engine exists when it loads), the format before the settings that need it.
    code, out = run([BLENDER, '-b', '--addons', 'ember', os.path.join(SCENES_DIR, 'cornell.blend'),
                     '-E', 'EMBER', '-o', out_pattern, '-F', 'OPEN_EXR', '--python-expr', settings, '-f', '1'],
                    env={'BLENDER_USER_SCRIPTS': scripts})
    image_path = str(tmp_path / 'frame_0001.exr')
    assert code == 0 and os.path.exists(image_path), out[-4000:]
    assert "Error" not in out, out[-4000:]
    image = load_exr(image_path)
    assert image.shape == (32, 32, 4) and np.isfinite(image).all()
    luminance = image[..., :3].mean()
    assert luminance > 0.02, f"image is black ({luminance})"
    # The expected image: the same scene, settings and seed rendered by this
    # process (bpy 5.0).  Ember's random numbers depend only on the seed, the
    # pass and the pixel batch (batches follow the thread count, fixed here),
    # so both Blenders must produce the same pixels up to float rounding;
    # anything else is an export difference between the versions.
    from ember_testlib import open_scene, render_array, setup_ember, small_resolution
    scene = open_scene('cornell')
    small_resolution(scene, 32, 32)
    setup_ember(scene, 16, 3, 4)
    scene.ember.threads = 2
    expected = render_array(scene, tmp_path, 'expected')
    difference = np.abs(image - expected).max() / max(float(np.abs(expected).max()), 1e-6)
    print("Blender 3.4 binary vs bpy 5.0, largest relative pixel difference:", difference)
    assert difference < 1e-5


def test_one_command_install_into_blender_34(tmp_path, needs_engine):
    """tools/install_addon.py installs and enables Ember in the real binary:
    afterwards `blender -b scene -E EMBER -f 1` renders without --addons."""
    require_blender_34()
    # NumPy kernels (EMBER_JIT=0): this install's own folder would compile them
    # cold (60-100 s); the compiled path in this binary is the shared install's
    # (test_legacy_zip_renders_with_blender_34_binary and the others).
    env = {'BLENDER_USER_CONFIG': str(tmp_path / 'config'), 'BLENDER_USER_SCRIPTS': str(tmp_path / 'scripts'),
           'EMBER_JIT': '0'}
    code, out = run([sys.executable, os.path.join(ROOT, 'tools', 'install_addon.py'), '--blender', BLENDER], env=env)
    assert code == 0 and "Ember installed" in out, out[-4000:]
    assert (tmp_path / 'scripts' / 'addons' / 'ember' / '__init__.py').exists()
    settings = ("import bpy; s = bpy.context.scene; s.render.resolution_x = s.render.resolution_y = 16; "
                "s.render.resolution_percentage = 100; s.ember.samples = 4")
    code, out = run([BLENDER, '-b', os.path.join(SCENES_DIR, 'cornell.blend'), '-E', 'EMBER',
                     '-o', str(tmp_path / 'frame_####'), '-F', 'PNG', '--python-expr', settings, '-f', '1'],
                    env=env)
    assert code == 0 and (tmp_path / 'frame_0001.png').exists(), out[-4000:]
    assert "Error" not in out, out[-4000:]


def test_legacy_zip_denoises_in_blender_34(tmp_path, legacy_addon):
    """The OIDN program bundled in the legacy zip runs inside Debian's 3.4
    (which ships no OIDN): addon/denoise.py finds it in vendor/oidn."""
    require_blender_34()
    scripts = install_legacy(legacy_addon)
    expr = ("import numpy as np; from ember import denoise; rng = np.random.default_rng(0); "
            "flat = np.full((24, 24, 3), 0.5, np.float32); noisy = flat * rng.exponential(1, flat.shape)"
            ".astype(np.float32); out = denoise.denoise(noisy, flat, None); "
            "print('DENOISED', denoise.describe(), float(np.abs(noisy - flat).mean()), "
            "float(np.abs(out - flat).mean()))")
    code, out = run([BLENDER, '-b', '--addons', 'ember', '--python-expr', expr],
                    env={'BLENDER_USER_SCRIPTS': scripts})
    line = next((line for line in out.splitlines() if line.startswith('DENOISED')), None)
    assert code == 0 and line is not None, out[-4000:]
    assert 'vendor/oidn/bin/oidnDenoise' in line, line
    before, after = (float(v) for v in line.split()[-2:])
    assert after < 0.5 * before, line


# Hosek-Wilkie's own pixels are held to 3.4's Cycles in tests/engine/test_sky.py and its lit
# scene to Cycles in bpy 5.0 (test_world_sky.py); the binary's run (97 s) is spent on Nishita,
# whose 3.x table layout only this binary has.
@pytest.mark.parametrize('sky_type', ['NISHITA'])
def test_sky_in_blender_34_matches_its_cycles(tmp_path, legacy_addon, needs_engine, sky_type):
    """Blender 3.4's Nishita sky (the 3.x / 4.x table layout, ground fade and
    disc; sky_scene_34.py renders Hosek-Wilkie too), lighting a plane and seen above it,
    through the legacy zip in the real binary, against that binary's Cycles:
    blocks and image / quadrant means, their power printed
    (tests/addon/sky_scene_34.py renders both; the skies' own pixels are
    checked against 3.4's Cycles in tests/engine/test_sky.py)."""
    require_blender_34()
    scripts = install_legacy(legacy_addon)
    code, out = run([BLENDER, '-b', '--factory-startup', '--addons', 'ember', '--python',
                     os.path.join(ROOT, 'tests', 'addon', 'sky_scene_34.py'), '--', str(tmp_path), sky_type],
                    env={'BLENDER_USER_SCRIPTS': scripts})
    assert code == 0 and 'SKY SCENE DONE' in out, out[-4000:]
    assert 'Error' not in out, out[-4000:]
    from ember_testlib import assert_no_failing_blocks, compare_with_cycles
    # sky_scene_34.py's seeds (8 Ember x 16 spp, 12 Cycles x 8 spp; were 4 and 6).
    ember = np.array([load_exr(str(p))[..., :3] for p in sorted(tmp_path.glob('ember_*.exr'))], np.float64)
    cycles = np.array([load_exr(str(p))[..., :3] for p in sorted(tmp_path.glob('cycles_*.exr'))], np.float64)
    assert (len(ember), len(cycles)) == (8, 12), (len(ember), len(cycles))
    assert np.isfinite(ember).all() and ember.mean() > 0.05
    failures, details, _, _ = compare_with_cycles(f"Blender 3.4 {sky_type} sky plane", ember, cycles, 4)
    assert_no_failing_blocks(failures, details)
