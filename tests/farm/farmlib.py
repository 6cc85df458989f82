"""Helpers shared by the render-farm tests."""
import os
import subprocess
import sys

import pytest

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


def in_ci():
    return os.environ.get('CI', '').lower() == 'true'


def require(condition, reason):
    """Skip locally, fail in CI, when a prerequisite is missing."""
    if condition:
        return
    if in_ci():
        pytest.fail("missing prerequisite (CI=true): " + reason)
    pytest.skip(reason)


def make_animation(path, size=32, samples=8):
    script = (f"import sys; sys.path.insert(0, {ROOT!r}); import addon; addon.register()\n" + MAKE_ANIMATION)
    cmd = [sys.executable, '-P', '-c', script, os.path.join(ROOT, 'blend_scenes', 'cornell.blend'),
           str(path), str(size), str(samples)]
    env = dict(os.environ, BLENDER_USER_RESOURCES=os.path.join(os.path.dirname(str(path)), 'user'))
    out = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0 and os.path.isfile(path), out.stdout[-2000:] + out.stderr[-2000:]
    return str(path)
