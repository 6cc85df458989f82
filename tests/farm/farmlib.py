"""Helpers shared by the render-farm tests."""
import os
import subprocess
import sys

import numpy as np

from prerequisites import require  # noqa: F401  (the suite's one require: tests/prerequisites.py)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

# A tiny animation made from the Cornell box: the short box slides and turns
# over frames 1-4, so every frame differs.
MAKE_ANIMATION = r'''
import sys, bpy
out, size, samples = sys.argv[-3], int(sys.argv[-2]), int(sys.argv[-1])
bpy.ops.wm.open_mainfile(filepath=sys.argv[-4])
scene = bpy.context.scene
box = bpy.data.objects['ShortBox']
for frame, x, turn in ((1, 0.35, 0.0), (4, -0.1, 0.9)):
    box.location.x = x
    box.rotation_euler.z = turn
    box.keyframe_insert('location', frame=frame)
    box.keyframe_insert('rotation_euler', frame=frame)
scene.frame_start, scene.frame_end = 1, 4
scene.render.resolution_x = scene.render.resolution_y = size
scene.render.resolution_percentage = 100
scene.ember.samples = samples
scene.ember.seed = 7
scene.ember.max_bounces = 3
bpy.ops.wm.save_as_mainfile(filepath=out)
'''


def make_animation(path, size=32, samples=8):
    script = (f"import sys; sys.path.insert(0, {ROOT!r}); import addon; addon.register()\n" + MAKE_ANIMATION)
    cmd = [sys.executable, '-P', '-c', script, os.path.join(ROOT, 'blend_scenes', 'cornell.blend'),
           str(path), str(size), str(samples)]
    env = dict(os.environ, BLENDER_USER_RESOURCES=os.path.join(os.path.dirname(str(path)), 'user'))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0 and os.path.isfile(path), out.stdout[-2000:] + out.stderr[-2000:]
    return str(path)


SAMPLES = 8
THREADS = 1          # per render: two workers share the two cores


def read_exr(path):
    from engine.imageio import read_image
    return read_image(str(path))


def assert_same_image(got, want, what):
    scale = max(float(np.abs(want).max()), 1e-6)
    worst = float(np.abs(got - want).max()) / scale
    assert got.shape == want.shape and worst < 1e-5, f"{what}: largest relative difference {worst}"


def render_locally(blend, folder, frames, samples=SAMPLES, threads=THREADS):
    """Frames rendered by one local bpy process, no farm involved: {frame: RGBA}."""
    from farm.bpy_render import frames_of
    from farm.commands import BPY_RENDER, setup_code
    cmd = [sys.executable, '-P', BPY_RENDER, str(blend), '-o', str(folder / 'frame_####'),
           '--python-expr', setup_code(samples, threads), '-f', frames]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=dict(os.environ, PYTHONPATH=ROOT))
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    return {f: read_exr(folder / f"frame_{f:04d}.exr") for f in frames_of(frames)}


def make_job(blend, out_dir, frames=(1, 2, 3, 4), **kw):
    from farm import client, plan
    kw.setdefault('samples', SAMPLES)
    kw.setdefault('threads', THREADS)
    return plan.Job(blend=str(blend), out_dir=str(out_dir), frames=list(frames), python=sys.executable,
                    blend_sha256=client.blend_hash(str(blend)), **kw)


def run_job(dask_client, job, **kw):
    from farm import client
    written, failures = client.run(dask_client, job, **kw)
    assert not failures, failures
    return written


def make_animation_with_binary(blender, path, scripts, size=32, samples=SAMPLES):
    """The same animation saved by a Blender binary (3.4 cannot open 5.0 files)."""
    script = os.path.join(os.path.dirname(str(path)), 'make_animation.py')
    with open(script, 'w') as handle:
        handle.write(MAKE_ANIMATION)
    cmd = [blender, '-b', '--factory-startup', '--addons', 'ember', '--python', script, '--',
           os.path.join(ROOT, 'blend_scenes', 'cornell.blend'), str(path), str(size), str(samples)]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120,
                         env=dict(os.environ, BLENDER_USER_SCRIPTS=str(scripts)))
    assert out.returncode == 0 and os.path.isfile(path), out.stdout[-2000:] + out.stderr[-2000:]
    return str(path)
