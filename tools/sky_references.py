"""Cycles' Sky Texture seen by the camera, stored small for the engine tests.

Run once per Blender version (each writes tests/data/sky_<major><minor>.npz):

    .venv/bin/python -P tools/sky_references.py                     # bpy 5.0
    build/venv-bpy42/bin/python -P tools/sky_references.py          # bpy 4.2
    blender -b --factory-startup --python tools/sky_references.py   # Debian's 3.4

A world of one Sky Texture (the version's Nishita models) is rendered by Cycles
with one sample, which sits at each pixel centre, for a few parameter cases
(the Nishita models, Preetham and Hosek-Wilkie)
and camera views (the horizon with the ground below it, the zenith, the sun
disc close up).  The file holds, per pixel, the world direction through the
pixel centre (from the camera's view frame, as Cycles' raster-to-camera
mapping is linear), Cycles' RGB, and the sky node's properties as Ember's
exporter reads them in that Blender.  tests/engine/test_sky.py evaluates the
engine at the same directions.
"""
import json
import math
import os
import sys

import bpy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.join(ROOT, 'blend_scenes'))
import build_scenes as bs  # noqa: E402

SIZE = (24, 16)
# (name, properties): sun sizes of 4-5 degrees so that the disc covers pixels.
CASES = [
    ("clear", dict(sun_elevation=math.radians(15.0), sun_rotation=math.radians(40.0), altitude=500.0,
                   sun_size=math.radians(5.0), sun_intensity=1e-3)),
    ("low_sun", dict(sun_elevation=math.radians(1.5), sun_rotation=math.radians(-100.0), altitude=3000.0,
                     air_density=2.0, ozone_density=3.0, sun_size=math.radians(4.0), sun_intensity=1e-3,
                     density=0.5)),
]
# Camera views (rotation in degrees, lens in mm); 'sun' aims at the disc.
VIEWS = [("horizon", (80.0, 0.0, -140.0), 14.0), ("zenith", (170.0, 0.0, 30.0), 20.0), ("sun", None, 300.0)]


# Preetham: the sun given as a direction (the view 'sun' aims by elevation
# and rotation, which point the same way here).
PREETHAM = ("preetham", dict(sun_elevation=math.radians(25.0), sun_rotation=math.radians(60.0), turbidity=3.0,
                             sun_direction=(math.cos(math.radians(25.0)) * math.sin(math.radians(60.0)),
                                            math.cos(math.radians(25.0)) * math.cos(math.radians(60.0)),
                                            math.sin(math.radians(25.0)))))


def sun_props(elevation, rotation, **props):
    """Properties with the sun both as elevation / rotation (aimed at by the
    view 'sun') and as the direction the analytic models read."""
    e, r = math.radians(elevation), math.radians(rotation)
    return dict(props, sun_elevation=e, sun_rotation=r,
                sun_direction=(math.cos(e) * math.sin(r), math.cos(e) * math.cos(r), math.sin(e)))


# Hosek-Wilkie: turbidities between and at the fits (3.4, 7.6, 10), albedos
# 0.3 - 1, the sun high and 4 degrees up; then a sun direction that is not
# unit (Blender's sync normalizes it) and one with a NaN (Cycles' NaN angles
# clamp: the sun at the zenith, every angle to it pi).
HOSEK = [("hosek", sun_props(25.0, 60.0, turbidity=3.4, ground_albedo=0.3)),
         ("hosek_low", sun_props(4.0, -100.0, turbidity=7.6, ground_albedo=0.85)),
         ("hosek_hazy", sun_props(70.0, 200.0, turbidity=10.0, ground_albedo=1.0)),
         ("hosek_long", dict(sun_props(30.0, 20.0, turbidity=2.0, ground_albedo=0.1),
                             sun_direction=(0.2, 0.1, 3.0))),
         ("hosek_nan", dict(sun_props(30.0, 20.0, turbidity=5.0, ground_albedo=0.5),
                            sun_direction=(float('nan'), 0.3, 0.9)))]


def cases():
    """(name, sky type, properties): the version's Nishita model (in 5.0
    Single and Multiple Scattering), Preetham and Hosek-Wilkie."""
    analytic = ([(PREETHAM[0], 'PREETHAM', PREETHAM[1])]
                + [(name, 'HOSEK_WILKIE', props) for name, props in HOSEK])
    if bpy.app.version < (5, 0, 0):
        return [(name, 'NISHITA', props) for name, props in CASES] + analytic
    return ([(name, 'SINGLE_SCATTERING', props) for name, props in CASES]
            + [(name + '_ms', 'MULTIPLE_SCATTERING', props) for name, props in CASES] + analytic)


def sky_world(scene, props, sky_type):
    world, sky = bs.world_background(scene, "sky", 'ShaderNodeTexSky')
    sky.sky_type = sky_type
    for key, value in props.items():
        if key == 'density':   # dust (3.x / 4.x) or aerosol (5.0)
            setattr(sky, 'aerosol_density' if hasattr(sky, 'aerosol_density') else 'dust_density', value)
        else:
            setattr(sky, key, value)
    return world


def aim(camera, view, props):
    name, rotation, lens = view
    camera.location = (0.0, 0.0, 0.0)
    camera.data.lens = lens
    if rotation is None:
        # Blender's sun: elevation e, rotation r -> (-cos e sin r', cos e cos r', sin e), r' = 2 pi - r.
        e, r = props['sun_elevation'], 2.0 * math.pi - props['sun_rotation']
        d = np.array([-math.cos(e) * math.sin(r), math.cos(e) * math.cos(r), math.sin(e)])
        from mathutils import Vector
        camera.rotation_euler = Vector(d).to_track_quat('-Z', 'Y').to_euler()
    else:
        camera.rotation_euler = [math.radians(a) for a in rotation]


def first_sample_offset(resolution=1024):
    """Where Cycles' first sample sits from the pixel centre, in pixels, with
    a box filter of width 1 (x right, y up): half an entry of its inverted
    filter CDF (about 5e-4 pixel; tests/addon/test_node_parity.py derives it)."""
    cdf = np.arange(resolution + 1) / resolution
    half = (resolution - 1) // 2
    x = 1.0 / half
    index = int(np.searchsorted(cdf, x, side='right'))
    t = (x - cdf[index]) / (cdf[index + 1] - cdf[index])
    y = ((index + t) / (resolution - 1)) * (2.0 * 0.5)
    return 0.5 * (0.5 + 0.5 * (1.0 + y)) - 0.5


def pixel_directions(scene, camera):
    """World directions through Cycles' first sample of each pixel (its
    centre shifted by ``first_sample_offset``), rows from the top."""
    w, h = SIZE
    frame = [np.array(v) for v in camera.data.view_frame(scene=scene)]   # tr, br, bl, tl
    tr, br, bl, tl = frame
    shift = first_sample_offset()
    xs = (np.arange(w) + 0.5 + shift) / w
    ys = (np.arange(h) + 0.5 - shift) / h
    top = tl[None] + xs[:, None] * (tr - tl)[None]
    bottom = bl[None] + xs[:, None] * (br - bl)[None]
    local = top[None] + ys[:, None, None] * (bottom - top)[None]          # (h, w, 3)
    rot = np.array(camera.matrix_world.to_3x3())
    d = local.reshape(-1, 3) @ rot.T
    return d / np.linalg.norm(d, axis=1)[:, None]


def render(scene, folder):
    scene.render.engine = 'CYCLES'
    scene.cycles.device = 'CPU'
    scene.cycles.samples = 1
    scene.cycles.seed = 0
    scene.cycles.use_denoising = False
    if hasattr(scene.cycles, 'use_adaptive_sampling'):
        scene.cycles.use_adaptive_sampling = False
    scene.cycles.max_bounces = 0
    scene.cycles.pixel_filter_type = 'BOX'
    scene.cycles.filter_width = 1.0
    scene.render.resolution_x, scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = 'OPEN_EXR'
    scene.render.image_settings.color_depth = '32'
    scene.view_settings.view_transform = 'Standard'
    bpy.ops.render.render()
    path = os.path.join(folder, 'sky.exr')
    bpy.data.images['Render Result'].save_render(path)
    image = bpy.data.images.load(path)
    px = np.array(image.pixels[:], np.float32).reshape(SIZE[1], SIZE[0], 4)[::-1, :, :3]   # rows from the top
    bpy.data.images.remove(image)
    return px.reshape(-1, 3)


def exported_props(world):
    from addon.export import world as world_export
    result, warning = world_export.world_from_blender(world)
    assert warning is None, warning
    calls = world_export._sky_calls(result.texture.shader)
    assert len(calls) == 1
    return {k: v for k, v in calls[0].props.items() if not k.startswith('_outputs')}


def main():
    import tempfile
    bpy.ops.wm.read_factory_settings(use_empty=False)
    scene = bpy.context.scene
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    camera = scene.camera
    out = {}
    meta = {'version': list(bpy.app.version), 'size': list(SIZE), 'cases': {}}
    with tempfile.TemporaryDirectory() as folder:
        # The first render of a session saw the factory camera's orientation
        # (measured: the horizon a few pixels off); render once to settle it.
        sky_world(scene, CASES[0][1], cases()[0][1])
        render(scene, folder)
        for name, sky_type, props in cases():
            world = sky_world(scene, props, sky_type)
            meta['cases'][name] = exported_props(world)
            for view in VIEWS:
                aim(camera, view, props)
                bpy.context.view_layer.update()
                out[f"{name}/{view[0]}/dirs"] = pixel_directions(scene, camera).astype(np.float32)
                out[f"{name}/{view[0]}/rgb"] = render(scene, folder)
    major, minor = bpy.app.version[:2]
    path = os.path.join(ROOT, 'tests', 'data', f'sky_{major}{minor}.npz')
    np.savez_compressed(path, meta=np.array(json.dumps(meta)), **out)
    print("wrote", path, os.path.getsize(path), "bytes")


if __name__ == '__main__':
    main()
