"""The add-on in every supported Blender: the real 3.4 binary, bpy 4.2 LTS and
the installed packages (legacy zip, extension zip).

Each runs in a subprocess with its own BLENDER_USER_RESOURCES: installing the
packages into this test process would register a second EMBER engine.
tools/setup_test_env.sh installs what these need (Debian's blender and
python3-numpy, a bpy 4.2 venv in build/venv-bpy42, the wheels).
"""
import importlib.util
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from ember_testlib import ROOT, SCENES_DIR, load_exr, require

BLENDER = shutil.which('blender') or '/usr/bin/blender'
BPY42_PYTHON = os.path.join(ROOT, 'build', 'venv-bpy42', 'bin', 'python')
PORTABLE_TESTS = ['tests/addon/test_export.py', 'tests/addon/test_render_engine.py', 'tests/addon/test_blend_scenes.py',
                  'tests/engine/test_stats.py', 'tests/addon/test_pass_names.py',
                  # Renders through the engine, which these interpreters lack
                  # (no embreex there): Blender 3.4's pass names are rendered
                  # through the legacy zip in test_passes_parity instead.
                  '--deselect', 'tests/addon/test_pass_names.py::test_passes_have_this_blenders_names',
                  '--deselect', 'tests/addon/test_pass_names.py::test_written_passes_are_finite_and_meaningful',
                  '--deselect', 'tests/addon/test_pass_names.py::test_cryptomatte_manifest_in_metadata']


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


def blender_version():
    if not os.path.exists(BLENDER):
        return None
    code, out = run([BLENDER, '--version'])
    return out.splitlines()[0] if code == 0 and out else None


def install_legacy(legacy_addon):
    """The session's unpacked legacy zip (tests/conftest.py legacy_addon): one
    folder for every 3.4 test, so the binary compiles its kernels once."""
    return legacy_addon[1]


def test_portable_tests_in_blender_34_binary(tmp_path):
    version = blender_version()
    require(version is not None and version.startswith('Blender 3.4'),
            f"Debian's Blender 3.4 binary is needed at {BLENDER} (tools/setup_test_env.sh): found {version}")
    code, out = run([BLENDER, '-b', '--factory-startup', '--python-exit-code', '1',
                     '--python', 'tests/addon/blender_pytest.py', '--',
                     *PORTABLE_TESTS, '-q', '-p', 'no:cacheprovider', '-p', 'no:warnings'],
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


EXTENSION_CHECK = r'''
import os, sys, tempfile
import bpy
result = bpy.ops.extensions.package_install_files(filepath=sys.argv[1], repo='user_default', enable_on_install=True)
assert result == {'FINISHED'}, result
engines = {getattr(c, 'bl_idname', None) for c in bpy.types.RenderEngine.__subclasses__()}
assert 'EMBER' in engines, engines
assert 'addon' not in sys.modules and 'engine' not in sys.modules, "top-level names leaked"
from importlib import import_module
export = import_module('bl_ext.user_default.ember.export.scene')
exported = export.export_scene(bpy.context.evaluated_depsgraph_get())
assert type(exported.scene).__module__ == 'bl_ext.user_default.ember.vendor.engine.scene'
print("EXTENSION OK", exported.triangles)
'''


def test_extension_installs_and_registers(tmp_path):
    sys.path.insert(0, os.path.join(ROOT, 'tools'))
    try:
        import build_zip
    finally:
        sys.path.pop(0)
    try:
        built = build_zip.main(['--dist', str(tmp_path), '--build', str(tmp_path / 'build'),
                                '--wheels', os.path.join(ROOT, 'build', 'wheels'), '--extension'])
    except (subprocess.CalledProcessError, SystemExit) as err:
        require(False, f"could not build the extension zip: {err}")
    script = tmp_path / 'check.py'
    script.write_text(EXTENSION_CHECK)
    code, out = run([sys.executable, '-P', str(script), built[0]],
                    env={'BLENDER_USER_RESOURCES': str(tmp_path / 'user')})
    assert code == 0 and "EXTENSION OK" in out, out[-4000:]


def test_legacy_zip_renders_with_blender_34_binary(tmp_path, legacy_addon, needs_engine):
    """`blender -b scene --addons ember -E EMBER -f 1` writes the expected image."""
    version = blender_version()
    require(version is not None and version.startswith('Blender 3.4'),
            f"Debian's Blender 3.4 binary is needed at {BLENDER}: found {version}")
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
    version = blender_version()
    require(version is not None and version.startswith('Blender 3.4'),
            f"Debian's Blender 3.4 binary is needed at {BLENDER}: found {version}")
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
    version = blender_version()
    require(version is not None and version.startswith('Blender 3.4'),
            f"Debian's Blender 3.4 binary is needed at {BLENDER}: found {version}")
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
    version = blender_version()
    require(version is not None and version.startswith('Blender 3.4'),
            f"Debian's Blender 3.4 binary is needed at {BLENDER}: found {version}")
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
