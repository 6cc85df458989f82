"""Denoising with Intel Open Image Denoise in every supported Blender.

The Cornell box is rendered once here (bpy 5.0) at 16 and 128 samples plus a
512-sample reference (a 64x64 window of a 256x256 frame, 4 bounces); then addon.denoise runs on the 16-sample image, its
albedo and normal in this process (Blender 5.0's own OIDN), in the bpy 4.2
module (its own OIDN) and in Debian's Blender 3.4 binary (the bundled
oidnDenoise program).  In each, the denoised 16-sample image must be closer
to the reference than the noisy 128-sample one.  The reference's own noise
adds the same expected error to both sides, so it cannot favour either.
"""
import dataclasses
import json
import os
import shutil
import subprocess

import bpy
import numpy as np
import pytest

from addon import denoise
from addon import engine as ember_engine
from addon.export import scene as scene_export
from ember_testlib import ROOT, SCENES_DIR, require, setup_ember, small_resolution

BLENDER = shutil.which('blender') or '/usr/bin/blender'
BPY42_PYTHON = os.path.join(ROOT, 'build', 'venv-bpy42', 'bin', 'python')
SIZE = 64
# The Cornell box at 256x256, rendered in a 64x64 window (the short box's
# edges, its shadow, floor and wall): image features at the scale of a real
# render at the cost of a thumbnail.
FRAME = 256
BORDER = (0.5, 0.75, 0.15, 0.4)

CHECK = r'''
import json, os, sys
import numpy as np
sys.path.insert(0, {root!r})
sys.path.append({site!r})
import bpy
from addon import denoise
data = np.load({inputs!r})
out = denoise.denoise(data['color'], data['albedo'], data['normal'])
np.save({output!r}, out)
print("DENOISER", json.dumps(denoise.describe()))
'''


def rel_mse(image, reference):
    """Relative MSE (bright pixels do not dominate), averaged over pixels."""
    return float(np.mean((image - reference) ** 2 / (reference ** 2 + 1e-2)))


@pytest.fixture(scope='module')
def renders(registered_addon, tmp_path_factory):
    ok, reason = __import__('ember_testlib').engine_available()
    require(ok, reason)
    from addon import backend
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES_DIR, 'cornell.blend'))
    scene = bpy.context.scene
    small_resolution(scene, FRAME, FRAME)
    setup_ember(scene, 16, 1, 4)
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    exported.scene.camera = dataclasses.replace(exported.scene.camera, border=BORDER)
    render = backend.engine().render
    out = {}
    for name, samples, seed in (('16', 16, 1), ('128', 128, 2), ('reference', 512, 3)):
        settings = scene_export.render_settings(scene)
        settings.samples, settings.seed, settings.samples_per_pass = samples, seed, samples
        settings.aovs = ("normal", "albedo")   # the denoiser's guides
        out[name] = render(exported.scene, settings)
    folder = tmp_path_factory.mktemp('denoise')
    inputs = folder / 'inputs.npz'
    np.savez(inputs, color=out['16'].image[..., :3], albedo=out['16'].albedo, normal=out['16'].normal)
    return out, folder, inputs


def _judge(renders, denoised, where):
    out = renders[0]
    reference = out['reference'].image[..., :3]
    noisy = rel_mse(out['128'].image[..., :3], reference)
    raw = rel_mse(out['16'].image[..., :3], reference)
    clean = rel_mse(denoised, reference)
    print(f"{where}: relMSE 16 spp {raw:.5f}, 128 spp {noisy:.5f}, denoised 16 spp {clean:.5f}")
    assert np.isfinite(denoised).all() and denoised.shape == (SIZE, SIZE, 3)
    assert clean < noisy


def _in_other_python(cmd_prefix, renders, tmp_name, site=''):
    _, folder, inputs = renders
    output = folder / f'{tmp_name}.npy'
    script = folder / f'{tmp_name}.py'
    script.write_text(CHECK.format(root=ROOT, site=site, inputs=str(inputs), output=str(output)))
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(folder / 'user'))
    env.pop('PYTHONPATH', None)
    done = subprocess.run([*cmd_prefix, str(script)], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)
    text = done.stdout + done.stderr
    assert done.returncode == 0 and output.exists(), text[-4000:]
    line = next(line for line in text.splitlines() if line.startswith('DENOISER'))
    return np.load(output), json.loads(line.split(' ', 1)[1])


def test_denoised_16_samples_beat_128_in_bpy_50(renders):
    out = renders[0]['16']
    denoised = denoise.denoise(out.image[..., :3], out.albedo, out.normal)
    assert denoise.describe().startswith('OIDN in-process')
    _judge(renders, denoised, 'Blender 5.0 (bpy)')


def test_denoised_16_samples_beat_128_in_bpy_42(renders):
    require(os.path.exists(BPY42_PYTHON), f"a bpy 4.2 venv is needed at {BPY42_PYTHON}")
    denoised, used = _in_other_python([BPY42_PYTHON], renders, 'bpy42')
    assert used.startswith('OIDN in-process'), used
    _judge(renders, denoised, 'Blender 4.2 (bpy)')


def test_denoised_16_samples_beat_128_in_blender_34(renders, tmp_path):
    version = subprocess.run([BLENDER, '--version'], capture_output=True, text=True).stdout \
        if os.path.exists(BLENDER) else ''
    require(version.startswith('Blender 3.4'), f"Debian's Blender 3.4 binary is needed at {BLENDER}")
    import importlib.util
    spec = importlib.util.find_spec('pyoidn')  # its Python part needs cffi; only its files are used
    require(spec is not None and spec.origin, "pyoidn==2.5.1.0 (requirements.txt) provides oidnDenoise")
    site = tmp_path / 'site'
    site.mkdir()
    (site / 'pyoidn').symlink_to(os.path.dirname(spec.origin))
    denoised, used = _in_other_python([BLENDER, '-b', '--factory-startup', '--python-exit-code', '1',
                                       '--python'], renders, 'blender34', str(site))
    assert used.startswith('OIDN program'), used
    _judge(renders, denoised, 'Blender 3.4 (binary)')


def test_final_render_denoises_combined_and_keeps_noisy_image(registered_addon, monkeypatch, needs_engine):
    """F12 with Denoise: Combined is denoised, the Noisy Image pass (registered
    for the view layer) holds the raw render, as Cycles."""
    from addon import output
    written = []
    real_write = output.ResultWriter.write

    def write(self, image, extra=None):
        written.append((image.copy(), dict(extra or {}), self.layer.passes.get('Noisy Image') is not None))
        return real_write(self, image, extra)
    monkeypatch.setattr(output.ResultWriter, 'write', write)
    bpy.ops.wm.open_mainfile(filepath=os.path.join(SCENES_DIR, 'cornell.blend'))
    scene = bpy.context.scene
    small_resolution(scene, 32, 32)
    setup_ember(scene, 4, 0, 4)
    scene.ember.use_denoising = True
    bpy.ops.render.render()
    info = ember_engine.RENDER_LOG[-1]
    assert info['error'] is None and 'denoiser' in info, info
    combined, extra, registered = written[-1]
    assert registered, "the Noisy Image pass must exist in the render result"
    noisy = extra['Noisy Image']
    assert np.array_equal(noisy, written[-2][0]), "Noisy Image is the last progressive (raw) image"
    assert np.isfinite(combined).all() and combined[..., :3].mean() > 0.01
    assert np.array_equal(combined[..., 3], noisy[..., 3])

    def rough(image):
        return float(np.abs(np.diff(image[..., :3], axis=1)).mean())
    print("pixel-to-pixel variation: noisy", rough(noisy), "denoised", rough(combined))
    assert rough(combined) < 0.7 * rough(noisy)
    assert abs(combined[..., :3].mean() - noisy[..., :3].mean()) < 0.1 * noisy[..., :3].mean()


def _noisy_gradient(size=40, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:size, 0:size] / size
    clean = np.stack([x, y, 0.3 + 0 * x], -1).astype(np.float32)
    return clean, (clean * rng.exponential(1.0, clean.shape)).astype(np.float32)


def test_program_and_in_process_backends_agree(tmp_path):
    """The subprocess path (PFM files, rows flipped twice) gives what OIDN in
    this process gives: orientation and channels survive the files."""
    clean, noisy = _noisy_gradient()
    normal = np.zeros_like(clean)
    normal[..., 2] = 1.0
    try:
        program = denoise.Program(denoise.oidn_program())
    except denoise.DenoiseError as err:
        require(False, str(err))
    in_process = denoise.backend().run(noisy, clean, normal)
    via_files = program.run(noisy, clean, normal)
    assert via_files.shape == in_process.shape == noisy.shape
    assert np.abs(via_files - in_process).mean() < 1e-3 * np.abs(in_process).mean() + 1e-6
    assert np.mean((via_files - clean) ** 2) < 0.1 * np.mean((noisy - clean) ** 2)


def test_bad_input_gives_finite_output_or_a_clear_error():
    clean, noisy = _noisy_gradient(16)
    noisy[3, 4] = np.nan
    noisy[5, 6] = np.inf
    out = denoise.denoise(noisy, clean, None)
    assert np.isfinite(out).all()
    assert denoise.denoise(np.zeros((0, 0, 3), np.float32)).shape == (0, 0, 3)
    with pytest.raises(ValueError, match="quality"):
        denoise.denoise(noisy, quality='best')


def test_pfm_round_trip(tmp_path):
    image = np.random.default_rng(3).random((5, 7, 3), dtype=np.float32)
    path = denoise._write_pfm(str(tmp_path), 'x', image)
    assert np.array_equal(denoise.read_pfm(path), image)
