"""Render the converged Cycles references of the scene-level parity tests.

    .venv/bin/python -P tools/cycles_references.py            # every reference
    .venv/bin/python -P tools/cycles_references.py cornell    # one

Each reference is the mean of ``SEEDS`` independent Cycles renders (CPU, no
denoising, nothing clamped, the test's bounces and pixel filter) at a small
resolution, written to tests/data/cycles_<name>.exr with six float channels:
R, G, B (the mean) and var.R, var.G, var.B (the variance of that mean per
pixel, from the scatter of the seeds), so a test can account for Cycles'
residual noise.  The EXR header records the Blender/Cycles version, the
samples, seeds, bounces, filter and resolution (``ember:*`` attributes); the
tests refuse a reference whose settings differ from theirs.

The scenes are blend_scenes/cornell.blend and ``glossy_world`` (built here by
``build_glossy_world``: smooth GGX plates reflecting a constant world), all
rendered at the settings in ``REFERENCES``.  Re-run after changing a scene or
a setting; it takes a few minutes on two cores.
"""
import math
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, 'tests', 'data')

SEEDS = 8
# name: (width, height, max bounces, samples per seed)
REFERENCES = {
    'cornell': (48, 48, 4, 4096),
    'glossy_world': (48, 32, 4, 2048),
}
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
    """The scene of reference ``name`` at its resolution (engine not set)."""
    if name == 'glossy_world':
        scene = build_glossy_world(bpy)
    else:
        bpy.ops.wm.open_mainfile(filepath=os.path.join(ROOT, 'blend_scenes', name + '.blend'))
        scene = bpy.context.scene
    width, height = REFERENCES[name][:2]
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.use_border = False
    return scene


def metadata(name):
    import bpy
    width, height, bounces, samples = REFERENCES[name]
    return {'ember:scene': name, 'ember:renderer': 'Cycles CPU', 'ember:blender': bpy.app.version_string,
            'ember:samples': samples, 'ember:seeds': SEEDS, 'ember:max_bounces': bounces,
            'ember:filter': f'{FILTER[0]} {FILTER[1]}', 'ember:width': width, 'ember:height': height}


def render(name, folder):
    import bpy
    import numpy as np
    from ember_testlib import render_array, setup_cycles
    width, height, bounces, samples = REFERENCES[name]
    scene = open_reference_scene(bpy, name)
    images = []
    for seed in range(SEEDS):
        setup_cycles(scene, samples, seed, bounces, *FILTER)
        images.append(render_array(scene, folder, f'{name}_{seed}')[..., :3].astype(np.float64))
    images = np.array(images)
    mean = images.mean(axis=0)
    var_mean = images.var(axis=0, ddof=1) / SEEDS
    write_reference(reference_path(name), mean, var_mean, metadata(name))
    print(f"{name}: {width}x{height}, {SEEDS} x {samples} spp, mean {mean.mean(axis=(0, 1))}, "
          f"relative se of the image mean {math.sqrt(var_mean.sum()) / mean.sum():.2e}")


def write_reference(path, mean, var_mean, attributes):
    import numpy as np
    import OpenImageIO as oiio
    h, w, _ = mean.shape
    spec = oiio.ImageSpec(w, h, 6, oiio.FLOAT)
    spec.channelnames = ('R', 'G', 'B', 'var.R', 'var.G', 'var.B')
    spec.attribute('compression', 'zip')
    for key, value in attributes.items():
        spec.attribute(key, str(value))
    buf = oiio.ImageBuf(spec)
    buf.set_pixels(oiio.ROI(), np.ascontiguousarray(np.concatenate([mean, var_mean], axis=2), np.float32))
    if not buf.write(path):
        raise OSError(f"could not write {path}: {oiio.geterror()}")


def main(names):
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-refs-'))
    for path in (ROOT, os.path.join(ROOT, 'tests', 'addon')):
        if path not in sys.path:
            sys.path.insert(0, path)
    import bpy  # noqa: F401  (bpy before the add-on)
    os.makedirs(DATA, exist_ok=True)
    with tempfile.TemporaryDirectory() as folder:
        for name in names or sorted(REFERENCES):
            render(name, folder)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
