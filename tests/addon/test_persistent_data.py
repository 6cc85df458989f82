"""Persistent Data (Render > Performance > Final Render): the frames of an
animation re-export only the geometry the depsgraph says changed, and reuse
the BVH when the triangles are the same (addon/export/persistent.py,
engine/accel.py BuiltScenes).  Each frame must render what a render without
Persistent Data renders; the log says what was reused."""
import bpy
import numpy as np
import pytest

from addon import engine as ember_engine
from ember_testlib import empty_factory_scene, render_array


def animated_scene():
    """A sphere displaced by a keyframed modifier (its geometry changes from
    frame 2 to 3), a cube sliding from frame 1 to 2 and then still, a
    light whose power changes from 3 to 4 (only that)."""
    scene = empty_factory_scene()
    scene.render.engine = 'EMBER'
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    scene.render.resolution_percentage = 100
    scene.ember.samples = 4
    scene.ember.seed = 3
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, location=(-1, 0, 0))
    sphere = bpy.context.object
    displace = sphere.modifiers.new('displace', 'DISPLACE')
    displace.strength = 0.0
    displace.keyframe_insert('strength', frame=2)
    displace.strength = 0.6
    displace.keyframe_insert('strength', frame=3)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(1, 0, 0))
    cube = bpy.context.object
    cube.keyframe_insert('location', frame=1)
    cube.location.y = 0.5
    cube.keyframe_insert('location', frame=2)
    bpy.ops.mesh.primitive_plane_add(size=20, location=(0, 0, -1))
    bpy.ops.object.light_add(type='POINT', location=(0, -2, 3))
    light = bpy.context.object.data
    light.energy = 800
    light.keyframe_insert('energy', frame=3)
    light.energy = 300
    light.keyframe_insert('energy', frame=4)
    for fcurve in _fcurves(cube) + _fcurves(sphere) + _fcurves(light):
        for key in fcurve.keyframe_points:
            key.interpolation = 'CONSTANT'
    return scene


def _fcurves(ident):
    """The F-curves of an ID's action (the layered action API of Blender
    4.4+ keeps them in channel bags, ``action.fcurves`` before)."""
    action = ident.animation_data.action
    curves = getattr(action, 'fcurves', None)
    if curves is not None:
        return list(curves)
    return [c for layer in action.layers for strip in layer.strips for bag in strip.channelbags for c in bag.fcurves]


FRAMES = (1, 2, 3, 4)


def render_frames(scene, folder, persistent):
    scene.render.use_persistent_data = persistent
    images, logs = [], []
    for frame in FRAMES:
        scene.frame_set(frame)
        images.append(render_array(scene, folder, f"frame{frame}_{persistent}"))
        logs.append(dict(ember_engine.RENDER_LOG[-1]))
        assert logs[-1]['error'] is None, logs[-1]['error']
    return images, logs


def test_persistent_frames_match_and_reuse(tmp_path):
    scene = animated_scene()
    plain, _ = render_frames(scene, tmp_path, False)
    kept, logs = render_frames(scene, tmp_path, True)
    for frame, log in zip(FRAMES, logs):
        print(f"frame {frame}: meshes reused {log.get('meshes_reused')}, exported {log.get('meshes_exported')}, "
              f"BVH reused {log['stats'].get('bvh_reused')}, export {log['export_seconds'] * 1e3:.1f} ms, "
              f"prepare {log['stats'].get('prepare_seconds', 0) * 1e3:.1f} ms")
    # Frame 1 exports the three meshes.  Blender tags the sphere's geometry
    # at every frame (its modifier is animated), so it is exported again each
    # time; the cube (moved on frame 2) and the floor never are.  Frame 4
    # changes only a light: the same triangles, so the same BVH.
    assert [log['meshes_exported'] for log in logs] == [3, 1, 1, 1]
    assert [log['meshes_reused'] for log in logs] == [0, 2, 2, 2]
    assert [log['stats']['bvh_reused'] for log in logs] == [False, False, False, True]
    # The frames differ from one another (the test would see a stale mesh)...
    for a, b in zip(plain, plain[1:]):
        assert np.abs(a - b).max() > 1e-3
    # ... and each persistent frame is its plain render: the same samples of
    # the same scene (only the order of the film's float sums may differ).
    for frame, a, b in zip(FRAMES, plain, kept):
        np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-6, err_msg=f"frame {frame}")


def test_persistent_data_off_keeps_nothing(tmp_path):
    """Without Persistent Data nothing is reused and the kept BVH is freed."""
    from engine import accel
    scene = animated_scene()
    _, logs = render_frames(scene, tmp_path, True)
    assert accel.PERSISTENT.entry is not None
    _, logs = render_frames(scene, tmp_path, False)
    assert all(log.get('meshes_reused') is None and not log['stats']['bvh_reused'] for log in logs)
    assert accel.PERSISTENT.entry is None


@pytest.mark.parametrize("edit", ["vertex", "topology"])
def test_mesh_edit_between_renders_is_exported_again(tmp_path, edit):
    """A mesh edited between two renders (no animation: a user's edit, F12
    again) is exported again, not taken from the cache."""
    scene = animated_scene()
    scene.frame_set(4)
    scene.render.use_persistent_data = True
    before = render_array(scene, tmp_path, "before")
    plane = bpy.data.objects['Plane']
    if edit == "vertex":
        plane.data.vertices[0].co.z += 3.0
    else:
        plane.modifiers.new('sub', 'SUBSURF').levels = 1
    plane.data.update()
    kept = render_array(scene, tmp_path, "after")
    assert np.abs(kept - before).max() > 1e-3     # the edit shows
    log = ember_engine.RENDER_LOG[-1]
    # The floor, and the sphere (its animated modifier is tagged every time)
    assert (log['meshes_exported'], log['meshes_reused']) == (2, 1), log
    scene.render.use_persistent_data = False
    plain = render_array(scene, tmp_path, "plain")
    np.testing.assert_allclose(kept, plain, rtol=1e-4, atol=1e-6)
