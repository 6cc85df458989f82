"""The IES Texture node on a light against Cycles, per pixel (engine/nodes/
ies.py; deterministic, no statistical family): a radius-0 point light,
rotated, whose Emission Strength is an IES Texture's Fac lights a diffuse
floor seen from above by an orthographic camera; Cycles renders one sample
at each pixel centre (box filter, direct light only), and Ember's light
sample at the same floor points (the exported scene's LightSet, a delta
light: no randomness) must give the same radiance.  IES files of the four
kinds Cycles processes, written here: type C over the full turn with uneven
angles (vertical angles beyond 90 degrees), type C with one quadrant
(mirrored twice), type A and type B (turned into type C's frame), one read
as an external file, the others from internal text blocks.  Measured on bpy
5.0.1: largest relative difference 1.5e-3 (float32 cubic interpolation),
every lit pixel lit in both."""
import math

import bpy
import numpy as np
import pytest

from ember_testlib import empty_factory_scene, render_array
from parity_scenes import material, plane

SIZE, SCALE, RHO, ENERGY = 32, 4.0, 0.8, 10.0
LIGHT = ((0.2, -0.1, 1.0), (0.3, -0.2, 0.4))
VARIANTS = {
    'type C, uneven angles': (1, [0, 10, 25, 45, 60, 80, 90, 120], [0, 30, 90, 150, 200, 260, 330, 360]),
    'type C, one quadrant': (1, [0, 15, 30, 45, 60, 75, 90], [0, 30, 60, 90]),
    'type A': (3, [-90, -60, -20, 0, 40, 90], [-90, -45, 0, 30, 90]),
    'type B': (2, [-90, -30, 0, 45, 90], [0, 20, 50, 90]),
}


def ies_text(kind, v, h):
    """An LM-63 file whose candela vary with both angles, asymmetrically."""
    rows = [[800 * (1 + 0.5 * math.cos(math.radians(b)) + 0.3 * math.sin(math.radians(b)))
             * (math.cos(math.radians(a)) ** 2 + 0.1) + 30 * math.sin(math.radians(2 * b)) ** 2 for a in v]
            for b in h]
    lines = ["IESNA:LM-63-2002", "[TEST] Ember parity", "TILT=NONE",
             f"1 1000 1.0 {len(v)} {len(h)} {kind} 2 0.1 0.1 0.0", "1.0 1.0 60",
             " ".join(f"{x:g}" for x in v), " ".join(f"{x:g}" for x in h)]
    return "\n".join(lines + [" ".join(f"{x:.3f}" for x in r) for r in rows]) + "\n"


def ies_scene(text, folder=None):
    scene = empty_factory_scene()
    plane("floor", material("floor", 'diffuse', color=(RHO,) * 3), half=4.0)
    data = bpy.data.lights.new("ies", 'POINT')
    data.energy, data.shadow_soft_size = ENERGY, 0.0
    obj = bpy.data.objects.new("ies", data)
    obj.location, obj.rotation_euler = LIGHT
    scene.collection.objects.link(obj)
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    node = tree.nodes.new('ShaderNodeTexIES')
    if folder is not None:
        path = str(folder / "light.ies")
        with open(path, "w") as f:
            f.write(text)
        node.mode, node.filepath = 'EXTERNAL', path
    else:
        block = bpy.data.texts.new("light.ies")
        block.from_string(text)
        node.mode, node.ies = 'INTERNAL', block
    tree.links.new(node.outputs['Fac'], emission.inputs['Strength'])
    cam = scene.camera
    cam.data.type, cam.data.ortho_scale = 'ORTHO', SCALE
    cam.location, cam.rotation_euler = (0.0, 0.0, 5.0), (0.0, 0.0, 0.0)
    scene.render.resolution_x = scene.render.resolution_y = SIZE
    scene.render.resolution_percentage = 100
    scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)
    return scene


def cycles_pixel_centres(scene, folder):
    scene.render.engine = 'CYCLES'
    c = scene.cycles
    c.device, c.samples, c.use_denoising, c.use_adaptive_sampling = 'CPU', 1, False, False
    c.pixel_filter_type, c.max_bounces = 'BOX', 0
    scene.view_settings.view_transform = 'Standard'
    return render_array(scene, folder, "ies")[..., :3].astype(np.float64)


def ember_pixel_centres():
    """Ember's direct light at the floor points under the pixel centres."""
    from addon.export.scene import export_scene
    from engine import bsdf, geometry, lights
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    assert not [w for w in exported.warnings if 'Light' in w], exported.warnings
    scene = exported.scene
    (light,) = scene.lights
    assert light.shader is not None
    ls = lights.LightSet(scene, geometry.flatten(scene), bsdf.MaterialTable(geometry.material_table(scene)))
    c = (np.arange(SIZE) + 0.5) / SIZE * SCALE - 0.5 * SCALE
    x, y = np.meshgrid(c, -c)
    p = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    half = np.full(len(p), 0.5)
    s = ls.sample(np.zeros(len(p), np.int64), p, half, half, half)
    return (RHO / np.pi * s.Le * np.maximum(s.wi[:, 2], 0.0)[:, None]).reshape(SIZE, SIZE, 3)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_ies_light_matches_cycles_per_pixel(registered_addon, tmp_path, variant):
    kind, v, h = VARIANTS[variant]
    external = variant == 'type C, uneven angles'
    scene = ies_scene(ies_text(kind, v, h), tmp_path if external else None)
    ember = ember_pixel_centres()
    cycles = cycles_pixel_centres(scene, tmp_path)
    lit = cycles[..., 0] > 1e-4
    assert lit.mean() > 0.3, f"{variant}: the scene is mostly dark ({lit.mean():.2f} lit)"
    assert ((ember[..., 0] > 1e-4) == lit).all(), f"{variant}: lit pixels differ"
    rel = np.abs(ember - cycles)[lit] / cycles[lit]
    print(f"IES {variant}: {lit.mean():.0%} lit, largest relative difference {rel.max():.2e}")
    assert rel.max() < 3e-3, f"{variant}: Ember differs from Cycles by up to {rel.max():.2%}"


def test_ies_on_a_seen_area_light_reads_incoming(registered_addon, tmp_path):
    """An area light seen by a perspective camera, its Emission Color an IES
    Texture's Fac: Cycles' IES reads the object-space Incoming (it varies
    across the light; the light's normal does not), and Ember's BSDF-ray
    hits (camera rays through the pixel centres) give Cycles' pixels."""
    from addon.export.scene import export_scene
    from engine.render import prepare
    from engine.scene import RenderSettings
    kind, v, h = VARIANTS['type C, uneven angles']
    scene = ies_scene(ies_text(kind, v, h))
    for name in ('ies', 'floor'):          # a light seen from below, nothing in between
        bpy.data.objects.remove(bpy.data.objects[name])
    data = bpy.data.lights.new("area", 'AREA')
    data.shape, data.size, data.size_y, data.normalize, data.energy = 'RECTANGLE', 2.0, 1.0, False, math.pi
    obj = bpy.data.objects.new("area", data)
    obj.location, obj.rotation_euler = (0.3, -0.2, 0.5), (0.2, 0.1, 0.5)
    obj.visible_camera = True
    scene.collection.objects.link(obj)
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    node = tree.nodes.new('ShaderNodeTexIES')
    node.mode, node.ies = 'INTERNAL', bpy.data.texts['light.ies']
    tree.links.new(node.outputs['Fac'], emission.inputs['Color'])
    cam = scene.camera
    cam.data.type, cam.data.lens = 'PERSP', 30.0
    cam.location, cam.rotation_euler = (0.1, 0.2, -5.0), (math.pi, 0.0, 0.0)   # below, looking up
    scene.render.resolution_x = scene.render.resolution_y = 24
    bpy.context.view_layer.update()
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    ctx = prepare(exported.scene, RenderSettings(samples=1, filter_type="BOX", filter_width=1.0, max_bounces=0))
    camera = ctx.camera
    n = camera.width * camera.height
    half = np.full(n, 0.5)
    o, d, _ = camera.generate(np.arange(n), half, half, half, half)
    _, _, Le, _ = ctx.lights.intersect(o, d, np.full(n, np.inf), camera=True)
    ember = Le.reshape(camera.height, camera.width, 3)
    cycles = cycles_pixel_centres(scene, tmp_path)
    lit = cycles[..., 0] > 1e-3
    assert lit.sum() >= 20 and ((ember[..., 0] > 0) == lit).all()
    values = cycles[..., 0][lit]
    assert values.max() > 1.5 * values.min(), "the IES does not vary over the light: the test cannot see Incoming"
    rel = np.abs(ember - cycles)[lit] / cycles[lit]
    print(f"IES on a seen area light: {int(lit.sum())} pixels, largest relative difference {rel.max():.2e}")
    assert rel.max() < 3e-3
