"""Render the converged Cycles references of the parity tests.

    .venv/bin/python -P tools/cycles_references.py                 # every reference
    .venv/bin/python -P tools/cycles_references.py cornell light_*  # some (shell-style patterns)

Each reference is the mean of ``SEEDS`` independent Cycles renders (CPU, no
denoising, nothing clamped, the test's bounces and pixel filter) at the
test's small resolution, written to tests/data/cycles_<name>.exr with seven
float channels: R, G, B (the mean), var.R, var.G, var.B (the variance of
that mean per pixel, from the scatter of the seeds) and var.sum (that of
R + G + B: the channels are correlated, so it is not the sum of the three;
references written before it have six channels and the tests bound it), so
a test can account for Cycles' residual noise.  The EXR header records the Blender/Cycles
version, the samples, seeds, bounces, filter, a key of the other Cycles
settings (tests/addon/ember_testlib.cycles_settings_key: the code of
setup_cycles), resolution and a fingerprint of the Blender scene
(``ember:*`` attributes, tests/addon/ember_testlib.scene_fingerprint:
colours and modifiers included); the tests refuse a reference
whose settings or scene differ from theirs.

The scenes: blend_scenes/cornell.blend and ``glossy_world`` (built here by
``build_glossy_world``: smooth GGX plates reflecting a constant world), held
by tests/addon/test_cycles_references.py, and the parity tests' scenes,
built by the ``reference_scene(name, folder)`` of the test module that owns
them (``REFERENCES``).  Re-run a reference after changing its scene or
setting; each takes one to a few minutes on two cores.
"""
import math
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, 'tests', 'data')

SEEDS = 8
# name: (module building the scene (None: here), its scene name, Cycles samples per seed)
REFERENCES = {
    'cornell': (None, 'cornell', 2048),
    'glossy_world': (None, 'glossy_world', 2048),
}
for _scene in ('veach_mis', 'instances_lights'):
    REFERENCES['scenes_' + _scene] = ('test_render_scenes', _scene, 2048)
for _scene in ('rect_close', 'light_over_lit_world', 'big_triangle', 'spot_blend', 'shadow_invisible',
               'glossy_invisible_light', 'diffuse_camera_invisible'):
    REFERENCES['light_' + _scene] = ('test_light_parity', _scene, 2048)
REFERENCES['light_falloff'] = ('test_light_falloff_parity', 'falloff', 2048)
REFERENCES['light_tree_path'] = ('test_light_tree_path_parity', 'light_tree_path', 4096)
REFERENCES['light_textures'] = ('test_light_texture_parity', 'light_textures', 1024)
REFERENCES['light_inputs'] = ('test_light_texture_parity', 'light_inputs', 1024)
for _scene in ('point_light', 'area_light'):
    REFERENCES['transparency_' + _scene] = ('test_transparency_parity', _scene, 2048)
for _scene in ('glass', 'principled', 'mix', 'furnace'):
    REFERENCES['material_' + _scene] = ('test_material_parity', _scene, 2048)
for _scene in ('images', 'nodes', 'normals', 'inputs'):
    REFERENCES['texture_' + _scene] = ('test_texture_parity', _scene, 1024)
for _scene in ('nodes', 'world'):
    REFERENCES['node_scene_' + _scene] = ('test_node_scene_parity', _scene, 2048)
for _scene in ('spheres', 'background'):
    REFERENCES['hdri_' + _scene] = ('test_world_hdri', _scene, 2048)
REFERENCES['ray_nodes_ao_bevel'] = ('test_ray_node_parity', 'ao_bevel', 2048)
REFERENCES['sky_plane'] = ('test_world_sky', 'plane', 2048)
REFERENCES['sky_hosek'] = ('test_world_sky', 'hosek', 2048)
for _scene in ('udim', 'alpha', 'terrain'):
    REFERENCES['image_' + _scene] = ('test_image_parity', _scene, 1024)
for _scene in ('coloured_glass', 'fog', 'emission'):
    REFERENCES['volume_' + _scene] = ('test_volume_parity', _scene, 1024)
for _scene in ('smoke_in_fog',):
    REFERENCES['volume_field_' + _scene] = ('test_volume_field_parity', _scene, 512)
REFERENCES['lobes_lobes'] = ('test_lobe_parity', 'lobes', 1024)
REFERENCES['thinfilm_films'] = ('test_thinfilm_parity', 'films', 1024)
REFERENCES['thinfilm_conductors'] = ('test_thinfilm_parity', 'conductors', 1024)
for _scene in ('round', 'elliptical'):
    REFERENCES['hair_huang_' + _scene] = ('test_hair_huang_parity', _scene, 1024)
for _scene in ('spheres', 'backlit'):
    REFERENCES['subsurface_' + _scene] = ('test_subsurface_parity', _scene, 1024)
REFERENCES['motion_objects'] = ('test_motion_parity', 'objects', 2048)
for _scene in ('late_shutter', 'rolling', 'moving_lamp', 'moving_emitter'):
    REFERENCES['motion_' + _scene] = ('test_motion_parity', _scene, 2048)
REFERENCES['points_heap'] = ('test_points_parity', 'heap', 1024)
REFERENCES['curves_strands'] = ('test_curves_parity', 'strands', 1024)
REFERENCES['bump_correction_sphere'] = ('test_bump_correction_parity', 'sphere', 512)
REFERENCES['hair_particles'] = ('test_hair_parity', 'particles', 1024)
REFERENCES['hair_bsdf_strands'] = ('test_hair_bsdf_parity', 'strands', 1024)
for _scene, _spp in (('sliding_curves', 1024), ('swaying_curves', 1024), ('sliding_points', 1024),
                     ('sliding_hair', 512)):
    REFERENCES['curve_motion_' + _scene] = ('test_curve_motion_parity', _scene, _spp)
REFERENCES['velocity_shapes'] = ('test_velocity_motion_parity', 'shapes', 1024)
for _scene in ('emissive', 'glossy_lights', 'hdri', 'interior', 'many_lights', 'principled', 'procedural'):
    REFERENCES['yardstick_' + _scene] = ('test_yardstick_parity', _scene, 1024)
# the scenes built here: (width, height, max bounces)
BUILT_HERE = {'cornell': (48, 48, 4), 'glossy_world': (48, 32, 4)}
HEADER = ('scene', 'blender', 'samples', 'seeds', 'max_bounces', 'filter', 'cycles', 'width', 'height', 'fingerprint')
FILTER = ('BLACKMAN_HARRIS', 1.5)


def reference_path(name):
    return os.path.join(DATA, f'cycles_{name}.exr')


def build_glossy_world(bpy):
    """Four GGX plates (roughness 0.02 - 0.08, single scattering) under a
    constant world, seen from above at an angle: each plate reflects the world
    only, so its radiance is world x the GGX directional albedo."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    for i, roughness in enumerate((0.02, 0.04, 0.06, 0.08)):
        material = bpy.data.materials.new(f"Glossy{i}")
        material.use_nodes = True
        tree = material.node_tree
        tree.nodes.clear()
        out = tree.nodes.new('ShaderNodeOutputMaterial')
        node = tree.nodes.new('ShaderNodeBsdfGlossy')
        node.distribution = 'GGX'
        node.inputs['Color'].default_value = (0.8, 0.8, 0.8, 1.0)
        node.inputs['Roughness'].default_value = roughness
        tree.links.new(node.outputs[0], out.inputs['Surface'])
        x0 = -2.0 + i
        mesh = bpy.data.meshes.new(f"Plate{i}")
        mesh.from_pydata([(x0 + 0.05, -1, 0), (x0 + 0.95, -1, 0), (x0 + 0.95, 1, 0), (x0 + 0.05, 1, 0)],
                         [], [(0, 1, 2, 3)])
        mesh.materials.append(material)
        obj = bpy.data.objects.new(f"Plate{i}", mesh)
        obj.rotation_euler = (math.radians(-20.0 + 10.0 * i), 0.0, 0.0)
        scene.collection.objects.link(obj)
    world = bpy.data.worlds.new("World")
    world.use_nodes = True
    background = next(n for n in world.node_tree.nodes if n.type == 'BACKGROUND')
    background.inputs['Color'].default_value = (0.9, 0.95, 1.0, 1.0)
    background.inputs['Strength'].default_value = 1.0
    scene.world = world
    cam = bpy.data.cameras.new("Camera")
    cam.lens = 30.0
    cam_obj = bpy.data.objects.new("Camera", cam)
    cam_obj.location = (0.0, -3.6, 2.7)
    cam_obj.rotation_euler = (math.radians(53.0), 0.0, 0.0)
    scene.collection.objects.link(cam_obj)
    scene.camera = cam_obj
    return scene


def open_reference_scene(bpy, name):
    """The scene of a reference built here, at its resolution (engine not set)."""
    if name == 'glossy_world':
        scene = build_glossy_world(bpy)
    else:
        bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, 'blend_scenes', name + '.blend'))
        scene = bpy.context.scene
    width, height = BUILT_HERE[name][:2]
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.use_border = False
    return scene


def build(name, folder):
    """(scene, max bounces) of reference ``name``, as its test builds it."""
    import importlib
    import bpy
    module, scene_name, _ = REFERENCES[name]
    if module is None:
        return open_reference_scene(bpy, scene_name), BUILT_HERE[scene_name][2]
    return importlib.import_module(module).reference_scene(scene_name, folder)


def expected_header(name):
    """The header entries that do not depend on the built scene."""
    from ember_testlib import cycles_settings_key
    _, scene_name, samples = REFERENCES[name]
    return {'scene': scene_name, 'samples': str(samples), 'seeds': str(SEEDS),
            'filter': f'{FILTER[0]} {FILTER[1]}', 'cycles': cycles_settings_key(*FILTER)}


def metadata(name, scene, bounces):
    import bpy
    from ember_testlib import scene_fingerprint
    return {'ember:' + key: value for key, value in dict(
        expected_header(name), renderer='Cycles CPU', blender=bpy.app.version_string, max_bounces=bounces,
        width=scene.render.resolution_x, height=scene.render.resolution_y,
        fingerprint=scene_fingerprint(scene)).items()}


def render(name, folder):
    import numpy as np
    from ember_testlib import render_array, seed_variance, setup_cycles
    samples = REFERENCES[name][2]
    scene, bounces = build(name, folder)
    attributes = metadata(name, scene, bounces)     # before Cycles' settings: the scene as the test sees it
    images = []
    for seed in range(SEEDS):
        setup_cycles(scene, samples, seed, bounces, *FILTER)
        images.append(render_array(scene, folder, f'{name}_{seed}')[..., :3].astype(np.float64))
    images = np.array(images)
    mean = images.mean(axis=0)
    var_mean = seed_variance(images)     # per channel, and the channel sum's last
    write_reference(reference_path(name), mean, var_mean, attributes)
    total = abs(mean.sum())
    print(f"{name}: {scene.render.resolution_x}x{scene.render.resolution_y}, {SEEDS} x {samples} spp, "
          f"mean {mean.mean(axis=(0, 1))}, relative se of the image mean "
          f"{math.sqrt(var_mean[..., 3].sum()) / total if total else 0.0:.2e}", flush=True)


def write_reference(path, mean, var_mean, attributes):
    import numpy as np
    import OpenImageIO as oiio
    h, w, _ = mean.shape
    spec = oiio.ImageSpec(w, h, 7, oiio.FLOAT)
    spec.channelnames = ('R', 'G', 'B', 'var.R', 'var.G', 'var.B', 'var.sum')
    spec.attribute('compression', 'zip')
    for key, value in attributes.items():
        spec.attribute(key, str(value))
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray(np.concatenate([mean, var_mean], axis=2), np.float32))
    if not buf.write(path):
        raise OSError(f"could not write {path}: {oiio.geterror()}")


def main(patterns):
    import fnmatch
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-refs-'))
    for path in (ROOT, os.path.join(ROOT, 'tests'), os.path.join(ROOT, 'tests', 'addon')):
        if path not in sys.path:
            sys.path.insert(0, path)
    import bpy  # noqa: F401  (bpy before the add-on)
    import addon
    addon.register()       # the tests' scenes are built with the add-on registered
    names = [n for n in REFERENCES if not patterns or any(fnmatch.fnmatch(n, p) for p in patterns)]
    if not names:
        print(f"no reference matches {patterns}; known: {', '.join(REFERENCES)}")
        return 2
    os.makedirs(DATA, exist_ok=True)
    for name in names:
        with tempfile.TemporaryDirectory() as folder:
            render(name, folder)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
