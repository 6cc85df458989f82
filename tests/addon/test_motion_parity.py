"""Cycles parity of motion blur (engine/motion.py, addon/export/motion.py):
a sliding cube, a tumbling torus and a box sheared by a shape key, seen by
a moving, turning camera, all keyframed linearly and rendered at frame 2
with a shutter of 0.5 frames, Position Centre, against a converged Cycles
reference (tools/cycles_references.py motion_objects), as
tests/addon/test_light_parity.py compares its scenes.  The same block test
must tell a sharp render from the blurred reference (it sees the blur)."""
import math

import bpy
import numpy as np
import pytest

from parity_scenes import box, light, material, plane, top_camera
import ember_stats as stats
from ember_testlib import check_against_reference, empty_factory_scene, load_reference, render_for_reference

BLOCK = 8
SPP = 256
BOUNCES = 1
FRAME = 2


def _linear_keys(obj, path, values, frames=(1, 3)):
    """Keyframe ``obj.path`` at ``frames`` to ``values``, linearly interpolated."""
    for frame, value in zip(frames, values):
        setattr(obj, path, value)
        obj.keyframe_insert(path, frame=frame)
    action = obj.animation_data.action
    for curve in _fcurves(action):
        for key in curve.keyframe_points:
            key.interpolation = 'LINEAR'


def _fcurves(action):
    """An action's F-curves (Blender 5 keeps them in layered channel bags)."""
    curves = getattr(action, 'fcurves', None)
    if curves is not None and len(curves):
        return list(curves)
    found = []
    for layer in getattr(action, 'layers', ()):
        for strip in layer.strips:
            for bag in strip.channelbags:
                found.extend(bag.fcurves)
    return found


def _blur(scene, on=True):
    scene.render.use_motion_blur = on
    scene.render.motion_blur_shutter = 0.5
    scene.render.motion_blur_position = 'CENTER'
    scene.frame_set(FRAME)


def _stage(scene):
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.5, -0.5, 4.0), 400.0, size=2.0)
    top_camera(scene, 6.0)


def objects(scene, blur=True):
    """A cube sliding along x (2 units per frame, so 1 in the shutter) and a
    torus tumbling about x (120 degrees per frame, 60 in the shutter)."""
    _stage(scene)
    cube = box("cube", material("red", 'diffuse', color=(0.8, 0.15, 0.1)), (-1.2, 0.0, 0.4), (0.8, 0.8, 0.8))
    _linear_keys(cube, 'location', [(-3.2, 0.0, 0.4), (0.8, 0.0, 0.4)])
    bpy.ops.mesh.primitive_torus_add(major_radius=0.7, minor_radius=0.25, major_segments=32, minor_segments=12,
                                     location=(1.0, 0.0, 1.0))
    torus = bpy.context.active_object
    torus.name = "torus"
    bpy.ops.object.shade_smooth()
    torus.data.materials.append(material("green", 'diffuse', color=(0.2, 0.7, 0.2)))
    _linear_keys(torus, 'rotation_euler', [(math.radians(-60.0), 0.0, 0.0), (math.radians(180.0), 0.0, 0.0)])
    _shearing_box()
    # the camera moves along y (1.5 units per frame) and turns about z (20 degrees per frame)
    _linear_keys(scene.camera, 'location', [(0.0, -1.5, 6.0), (0.0, 1.5, 6.0)])
    _linear_keys(scene.camera, 'rotation_euler', [(0.0, 0.0, math.radians(-20.0)), (0.0, 0.0, math.radians(20.0))])
    _blur(scene, blur)
    return BOUNCES


def _shearing_box():
    """A box whose top face slides along x by a shape key (deformation
    blur): its value goes 0 -> 1 over frames 1 -> 3, 0.8 unit of shear."""
    obj = box("shear", material("yellow", 'diffuse', color=(0.8, 0.7, 0.1)), (0.0, -1.1, 0.35), (0.6, 0.6, 0.7))
    obj.shape_key_add(name="Basis")
    key = obj.shape_key_add(name="shear")
    for point in key.data:
        if point.co.z > 0:
            point.co.x += 0.8 / 0.6   # object space: the box is scaled by 0.6 along x
    for frame, value in ((1, 0.0), (3, 1.0)):
        key.value = value
        key.keyframe_insert('value', frame=frame)
    for curve in _fcurves(obj.data.shape_keys.animation_data.action):
        for point in curve.keyframe_points:
            point.interpolation = 'LINEAR'


def _sliding_cube(scene, travel=2.0):
    """The stage and a cube sliding along x by ``travel`` per frame."""
    _stage(scene)
    cube = box("cube", material("red", 'diffuse', color=(0.8, 0.15, 0.1)), (0.0, 0.0, 0.4), (0.8, 0.8, 0.8))
    _linear_keys(cube, 'location', [(-travel, 0.0, 0.4), (travel, 0.0, 0.4)])
    return cube


def late_shutter(scene, curve=True, zoom=True):
    """A cube sliding 2 units in the shutter of 1 frame, seen by a camera
    zooming from lens 25 to 45 over the shutter (focal-length animation),
    the shutter opening slowly (Shutter Curve through (0, 0), (0.5, 0.2),
    (1, 1)): the blur is brighter towards its end.  ``curve`` False keeps
    the flat default curve, ``zoom`` False the lens (the power checks)."""
    _sliding_cube(scene)
    if zoom:
        _linear_keys(scene.camera.data, 'lens', [15.0, 55.0])
    else:
        scene.camera.data.lens = 35.0
    _blur(scene)
    scene.render.motion_blur_shutter = 1.0
    if curve:
        mapping = scene.render.motion_blur_shutter_curve
        points = mapping.curves[0].points
        points[0].location = (0.0, 0.0)
        points[1].location = (0.5, 0.2)
        points[2].location = (1.0, 1.0)
        mapping.update()
    return BOUNCES


def rolling(scene, on=True):
    """The sliding cube under a rolling shutter (Top-Bottom, duration
    0.25) of 1 frame: rows lower in the frame see the cube later, so it
    leans; ``on`` False: no rolling shutter (the power check)."""
    _sliding_cube(scene)
    _blur(scene)
    scene.render.motion_blur_shutter = 1.0
    scene.cycles.rolling_shutter_type = 'TOP' if on else 'NONE'
    scene.cycles.rolling_shutter_duration = 0.25
    return BOUNCES


def moving_lamp(scene):
    """A spot lamp sweeping 3 units along x in the shutter of 1 frame and
    the sliding cube: Cycles syncs lamps at the shutter's centre only
    (BlenderSync::sync_object skips lights at motion steps; scene/light.cpp
    reads the object's centre transform), so the lamp must not blur."""
    _sliding_cube(scene, 1.0)
    lamp = light('SPOT', (0.0, 0.8, 3.0), 300.0, spot_size=math.radians(40.0), spot_blend=0.1)
    _linear_keys(lamp, 'location', [(-3.0, 0.8, 3.0), (3.0, 0.8, 3.0)])
    _blur(scene)
    scene.render.motion_blur_shutter = 1.0
    return BOUNCES


def moving_emitter(scene):
    """A glowing bar sliding 2 units in the shutter of 1 frame, 0.6 above
    a floor it lights (no lamp), unseen by the camera: Cycles samples the bar's triangles where
    they are at each path's time."""
    plane("floor", material("floor", 'diffuse'))
    top_camera(scene, 6.0)
    bar = box("bar", material("glow", 'emission', color=(1.0, 0.8, 0.5), strength=6.0), (0.0, 0.0, 0.6),
              (0.4, 2.4, 0.1))
    _linear_keys(bar, 'location', [(-2.0, 0.0, 0.6), (2.0, 0.0, 0.6)])
    bar.visible_camera = False   # (the test is of the light it casts; its own blur is the objects scene's)
    _blur(scene)
    scene.render.motion_blur_shutter = 1.0
    return BOUNCES


WITHOUT = {'late_shutter': ('curve', 'zoom'), 'rolling': ('on',)}   # the features each scene tests
SCENES = {'objects': objects, 'late_shutter': late_shutter, 'rolling': rolling, 'moving_lamp': moving_lamp,
          'moving_emitter': moving_emitter}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_motion_blur_parity_with_cycles(tmp_path, tapped_engine, name='objects'):
    check_blur_parity(name, SCENES[name], 'motion_', tmp_path, tapped_engine)


def check_blur_parity(name, build, prefix, tmp_path, taps, block=BLOCK):
    """Parity of ``build``'s scene with reference ``prefix + name``; the same
    blocks at the same level tell Cycles' blurred image from a sharp one."""
    scene = empty_factory_scene()
    bounces = build(scene)
    image, var = render_for_reference(scene, tmp_path, name, taps, SPP, 2, bounces)
    check = check_against_reference(prefix + name, scene, bounces, image, var, SPP, block)
    check.assert_agrees(0.005, 0.02)
    still = empty_factory_scene()
    build(still, blur=False)
    sharp, sharp_var = render_for_reference(still, tmp_path, name + '_still', taps, SPP // 2, 2, bounces)
    assert _blocks_beyond(name, sharp, sharp_var, check.details['level'], "a sharp render", prefix, block), \
        f"the test cannot tell {name}'s motion blur from none"


def _blocks_beyond(name, image, var, level, what, prefix='motion_', block=BLOCK, spp=SPP // 2):
    """Whether any block of an Ember render (``spp`` samples) differs from
    reference ``prefix + name`` at ``level`` (a test's power check), printed."""
    ref, ref_var, _ = load_reference(prefix + name)
    a, va = stats.block_means_var(image[..., :3].astype(np.float64), var, block)
    b, vb = stats.block_means_var(ref, ref_var, block)
    t = np.abs(a - b) / np.sqrt(va + vb)
    limit = stats.t_threshold(level, spp - 1)
    print(f"{prefix}{name}: {what} against the reference: max block |t| {t.max():.1f} "
          f"(limit {limit:.1f}), {(t > limit).sum()} of {t.size} blocks beyond")
    return bool((t > limit).any())


def _exported_scene(monkeypatch):
    """Record the engine scene each render receives."""
    from ember_testlib import record_engine_scenes
    return record_engine_scenes(monkeypatch)


@pytest.mark.parametrize("shutter, position", [(0.0, 'CENTER'), (10.0, 'START'), (0.5, 'END')])
def test_shutter_lengths_and_positions(shutter, position, tmp_path, tapped_engine, monkeypatch):
    """A shutter of 0 frames blurs nothing; one of 10 frames (keyframes
    extrapolated far past their range) renders finite pixels with the
    cube's steps spanning 10 frames from the frame (Position Start); Position
    End puts the frame at the shutter's end, as Cycles."""
    seen = _exported_scene(monkeypatch)
    scene, bounces = reference_scene('objects')
    scene.render.motion_blur_shutter = shutter
    scene.render.motion_blur_position = position
    image, _ = render_for_reference(scene, tmp_path, 'shutter', tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()
    assert scene.frame_current == FRAME and scene.frame_subframe == 0.0   # the frame is set back
    cube = next(inst for inst in seen[-1].instances if inst.name == 'cube')
    if shutter == 0.0:
        assert cube.motion is None and seen[-1].camera.motion is None
        return
    x = cube.motion[:, 0, 3]
    centre = {'START': FRAME + shutter / 2, 'END': FRAME - shutter / 2}[position]
    # the cube's x is 2 (frame - 2) - 1.2 (linear keys, extrapolated constant past frames 1 and 3)
    expect = [np.clip(2.0 * (f - 2.0) - 1.2, -3.2, 0.8) for f in (centre - shutter / 2, centre, centre + shutter / 2)]
    assert np.allclose(x, expect, atol=1e-4), (x, expect)
    assert np.isclose(cube.matrix[0, 3], expect[1], atol=1e-4)


@pytest.mark.parametrize("name", ['late_shutter', 'rolling'])
def test_shutter_curve_and_rolling_shutter_parity(name, tmp_path, tapped_engine):
    """Cycles parity of the shutter curve with a zooming camera, and of the
    rolling shutter; the same block test, at the same level, tells the
    reference from Ember's render without the curve / the rolling shutter."""
    scene, bounces = reference_scene(name)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, SPP, 2, bounces)
    check = check_against_reference('motion_' + name, scene, bounces, image, var, SPP, BLOCK)
    check.assert_agrees(0.005, 0.02)
    for without in WITHOUT[name]:
        plain = empty_factory_scene()
        SCENES[name](plain, **{without: False})
        other, other_var = render_for_reference(plain, tmp_path, name + '_plain', tapped_engine, SPP // 2, 2, bounces)
        assert _blocks_beyond(name, other, other_var, check.details['level'], f"without {without}"), \
            f"the test cannot tell {name} from its render without {without}"


def test_moving_lamp_stays_at_the_shutter_centre_as_cycles(tmp_path, tapped_engine):
    """Parity; and the same blocks tell the reference from a lamp swept
    over the shutter (stood in for by 7 still lamps along its path, each
    1/7 of its power)."""
    scene, bounces = reference_scene('moving_lamp')
    image, var = render_for_reference(scene, tmp_path, 'moving_lamp', tapped_engine, SPP, 2, bounces)
    check = check_against_reference('motion_moving_lamp', scene, bounces, image, var, SPP, BLOCK)
    check.assert_agrees(0.005, 0.02)
    swept, _ = reference_scene('moving_lamp')
    lamp = bpy.data.objects['spot']
    lamp.animation_data_clear()
    lamp.data.energy /= 7.0
    for k, x in enumerate(np.linspace(-1.5, 1.5, 7)):
        copy = lamp if k == 0 else lamp.copy()
        if k:
            swept.collection.objects.link(copy)
        copy.location = (x, 0.8, 3.0)
    other, other_var = render_for_reference(swept, tmp_path, 'swept_lamp', tapped_engine, SPP // 2, 2, bounces)
    assert _blocks_beyond('moving_lamp', other, other_var, check.details['level'], "a swept lamp"), \
        "the test cannot tell a still lamp from a moving one"


def test_shutter_settings_are_exported(tmp_path, tapped_engine, monkeypatch):
    """The curve's 256 values, the rolling shutter and the lens at the
    shutter's ends reach the engine camera (Cycles' sync_camera_motion)."""
    seen = _exported_scene(monkeypatch)
    scene, bounces = reference_scene('late_shutter')
    scene.cycles.rolling_shutter_type = 'TOP'
    scene.cycles.rolling_shutter_duration = 0.4
    render_for_reference(scene, tmp_path, 'settings', tapped_engine, 2, 2, bounces)
    cam = seen[-1].camera
    assert cam.shutter_curve.shape == (256,) and abs(cam.shutter_curve[0]) < 1e-6
    assert abs(cam.shutter_curve[-1] - 1.0) < 1e-6 and abs(cam.shutter_curve[128] - 0.2) < 0.05
    assert cam.rolling_shutter == 'TOP' and abs(cam.rolling_duration - 0.4) < 1e-6
    assert np.allclose(cam.lens_motion, (25.0, 45.0), atol=1e-4) and abs(cam.lens - 35.0) < 1e-4


@pytest.mark.parametrize("case", ['zero_curve', 'rolling_0', 'rolling_1', 'nan_keys'])
def test_hostile_shutter_settings_render_finite(case, tmp_path, tapped_engine):
    """A flat-zero shutter curve, rolling durations 0 and 1, NaN keyframes of
    the lens and the cube's location: finite pixels."""
    scene, bounces = reference_scene('late_shutter')
    if case == 'zero_curve':
        for point in scene.render.motion_blur_shutter_curve.curves[0].points:
            point.location = (point.location[0], 0.0)
        scene.render.motion_blur_shutter_curve.update()
    elif case.startswith('rolling'):
        scene.cycles.rolling_shutter_type = 'TOP'
        scene.cycles.rolling_shutter_duration = float(case[-1])
    else:
        for ident in (scene.camera.data, bpy.data.objects['cube']):
            for curve in _fcurves(ident.animation_data.action):
                curve.keyframe_points[-1].co[1] = float('nan')
    image, _ = render_for_reference(scene, tmp_path, 'hostile_' + case, tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()


def test_moving_emitter_parity(tmp_path, tapped_engine):
    """Parity of a moving emissive mesh lighting a floor (light sampling at
    the path's time, MIS with BSDF rays)."""
    scene, bounces = reference_scene('moving_emitter')
    spp = 10 * SPP   # 4 x resolved 1.35 % of the image, not 1 % (the channel sum's variance)
    # (a small light whose light varies much over the shutter: noisier than the others)
    image, var = render_for_reference(scene, tmp_path, 'moving_emitter', tapped_engine, spp, 2, bounces)
    check_against_reference('motion_moving_emitter', scene, bounces, image, var, spp, BLOCK).assert_agrees(0.01, 0.05)


def test_rolling_shutter_in_a_border_keeps_full_frame_rows(tmp_path, tapped_engine):
    """A render border (the top half, cropped) rolls by the full frame's
    rows, as Cycles' (its y and height are the full frame's): the window
    matches the top half of the full-frame reference."""
    from ember_testlib import ReferenceCheck
    scene, bounces = reference_scene('rolling')
    render = scene.render
    render.use_border, render.use_crop_to_border = True, True
    render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y = 0.0, 1.0, 0.5, 1.0
    image, var = render_for_reference(scene, tmp_path, 'rolling_border', tapped_engine, SPP, 2, bounces)
    ref, ref_var, header = load_reference('motion_rolling')
    rows = ref.shape[0] // 2
    assert image.shape[0] == rows and var.shape[0] == rows, (image.shape, var.shape)
    check = ReferenceCheck('motion_rolling_border', image[..., :3].astype(np.float64), var, SPP, ref[:rows],
                           ref_var[:rows], header, BLOCK)
    check.assert_agrees(0.01, 0.02)
