"""Materials against Cycles (issue 4): small scenes built here with bpy,
rendered by Ember and compared with converged Cycles references (CPU,
caustics on, same bounces and filter; tests/data/cycles_material_<scene>.exr
rendered by tools/cycles_references.py) by the totals of the image and its
quadrants and block by block, at the suite's family level
(ember_testlib.check_against_reference); results and power are printed.  The
furnace's halves (multiscatter left, single scatter right) are within those
quadrant tests.

Scenes (features grouped to keep the runtime small):
* glass: a smooth Glass BSDF sphere and a rough Multiscatter glass slab over
  a diffuse floor under an area light (refraction, total internal
  reflection, caustics found by BSDF sampling);
* principled: Principled BSDF spheres: rough metal with F82 tint
  (Multiscatter GGX), coat + sheen over a red base with a tinted coat,
  rough transmission, and specular level / tint, plus alpha;
* mix: Mix and Add shaders with factors over Translucent, Transparent,
  Refraction, Sheen and single-scatter GGX Glossy BSDFs;
* furnace: white rough metals (Multiscatter and single-scatter GGX) under a
  uniform white world: Multiscatter keeps what Cycles keeps.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import built_reference_scene, check_against_reference, render_for_reference

EMBER_SPP = 256
# 256 resolved 0.84 % (glass) and 0.69 % (principled) of the image, not 0.5 %,
# with the channel sum's variance.
SAMPLES = {'glass': 1024, 'principled': 768}
BLOCK = 12
WIDTH, HEIGHT = 48, 36
IMAGE_POWER, BLOCK_POWER = 0.005, 0.02   # issue 12's targets, asserted except in WEAK (docs/testing.md)
WEAK = {}
# Scenes with lights have a black world: chosen when Ember's BSDF rays stopped
# at lights and Cycles' pass them (kernel/integrator/shade_light.h); both
# pass them now (docs/testing.md, "What the references found"), and
# test_light_parity's light_over_lit_world covers a world behind a light.
DARK_WORLD = (0.0, 0.0, 0.0)


def _material(name, build):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new('ShaderNodeOutputMaterial')
    tree.links.new(build(tree), out.inputs['Surface'])
    return mat


def _bsdf(tree, kind, **inputs):
    node = tree.nodes.new(kind)
    distribution = inputs.pop('distribution', None)
    if distribution:
        node.distribution = distribution
    for name, value in inputs.items():
        socket = node.inputs[name]
        socket.default_value = value if not isinstance(value, tuple) or len(value) == 4 else value + (1.0,)
    return node.outputs[0]


def _mix(tree, fac, a, b):
    node = tree.nodes.new('ShaderNodeMixShader')
    node.inputs['Fac'].default_value = fac
    tree.links.new(a, node.inputs[1])
    tree.links.new(b, node.inputs[2])
    return node.outputs[0]


def _add(tree, a, b):
    node = tree.nodes.new('ShaderNodeAddShader')
    tree.links.new(a, node.inputs[0])
    tree.links.new(b, node.inputs[1])
    return node.outputs[0]


def _object(mesh_op, material, smooth=True, **kwargs):
    mesh_op(**kwargs)
    obj = bpy.context.active_object
    obj.data.materials.append(material)
    if smooth:
        for poly in obj.data.polygons:
            poly.use_smooth = True
    return obj


def _sphere(material, location, radius=0.5):
    return _object(bpy.ops.mesh.primitive_uv_sphere_add, material, radius=radius, location=location,
                   segments=48, ring_count=24)


def _floor(material):
    return _object(bpy.ops.mesh.primitive_plane_add, material, smooth=False, size=12.0, location=(0, 0, 0))


def _world(scene, color, strength=1.0):
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    bg = world.node_tree.nodes['Background']
    bg.inputs['Color'].default_value = tuple(color) + (1.0,)
    bg.inputs['Strength'].default_value = strength
    scene.world = world


def _area_light(power=400.0, size=2.0, location=(0.0, -1.0, 4.0)):
    light = bpy.data.lights.new("Area", 'AREA')
    light.energy = power
    light.size = size
    obj = bpy.data.objects.new("Area", light)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)


def _camera(scene, location, target):
    """Aim the camera.  The scenes show no pure background: constant blocks
    that Cycles' float32 colour conversion moves by an ulp cannot be judged
    by a t-test."""
    cam = scene.camera
    cam.location = location
    direction = np.subtract(target, location)
    cam.rotation_euler = _look(direction)
    cam.data.lens = 40


def _look(direction):
    from mathutils import Vector
    return Vector(direction).to_track_quat('-Z', 'Y').to_euler()


def _diffuse(name, color):
    return _material(name, lambda t: _bsdf(t, 'ShaderNodeBsdfDiffuse', Color=color))


def _three_lit_spheres(scene, materials, spacing):
    """Three spheres in a row (``spacing`` apart) under the area light, dark
    world, seen from the front and above."""
    for k, material in enumerate(materials):
        _sphere(material, ((k - 1) * spacing, 0.0, 0.5))
    _area_light(power=300.0)
    _world(scene, DARK_WORLD)
    _camera(scene, (0.0, -3.6, 3.4), (0.0, 0.0, 0.3))


# ----------------------------------------------------------------------------
# Scenes

def scene_glass(scene):
    _floor(_diffuse("Floor", (0.7, 0.7, 0.7)))
    glass = _material("Glass", lambda t: _bsdf(t, 'ShaderNodeBsdfGlass', Color=(1, 1, 1), Roughness=0.0,
                                               IOR=1.5, distribution='MULTI_GGX'))
    _sphere(glass, (-0.7, 0.0, 0.6), 0.6)
    rough = _material("RoughGlass", lambda t: _bsdf(t, 'ShaderNodeBsdfGlass', Color=(0.9, 0.95, 1.0),
                                                    Roughness=0.3, IOR=1.45, distribution='MULTI_GGX'))
    _object(bpy.ops.mesh.primitive_cube_add, rough, smooth=False, size=1.0, location=(0.8, 0.2, 0.35),
            scale=(0.6, 0.9, 0.35))
    _area_light()
    _world(scene, DARK_WORLD)
    _camera(scene, (0.0, -4.2, 2.6), (0.0, 0.0, 0.4))
    return 8


def scene_principled(scene):
    _floor(_diffuse("Floor", (0.5, 0.5, 0.5)))

    def metal(t):
        return _bsdf(t, 'ShaderNodeBsdfPrincipled', **{
            'Base Color': (0.95, 0.64, 0.54), 'Metallic': 1.0, 'Roughness': 0.6,
            'Specular Tint': (0.7, 0.9, 1.0), 'distribution': 'MULTI_GGX'})

    def coated(t):
        return _bsdf(t, 'ShaderNodeBsdfPrincipled', **{
            'Base Color': (0.8, 0.1, 0.1), 'Roughness': 0.4, 'Coat Weight': 1.0, 'Coat Roughness': 0.1,
            'Coat Tint': (0.8, 0.9, 0.6), 'Sheen Weight': 0.8, 'Sheen Roughness': 0.3,
            'Sheen Tint': (0.6, 0.8, 1.0), 'Specular IOR Level': 0.8, 'distribution': 'GGX'})

    def clear(t):
        return _bsdf(t, 'ShaderNodeBsdfPrincipled', **{
            'Base Color': (0.7, 0.9, 0.8), 'Roughness': 0.25, 'Transmission Weight': 1.0, 'IOR': 1.4,
            'Alpha': 0.8, 'distribution': 'MULTI_GGX'})

    _three_lit_spheres(scene, (_material("Metal", metal), _material("Coated", coated), _material("Clear", clear)),
                       1.25)
    return 6


def scene_mix(scene):
    _floor(_diffuse("Floor", (0.6, 0.55, 0.5)))

    def leaf(t):
        translucent = _bsdf(t, 'ShaderNodeBsdfTranslucent', Color=(0.3, 0.8, 0.2))
        glossy = _bsdf(t, 'ShaderNodeBsdfGlossy', Color=(0.9, 0.9, 0.9), Roughness=0.5, distribution='GGX')
        return _mix(t, 0.3, translucent, glossy)

    def veil(t):
        transparent = _bsdf(t, 'ShaderNodeBsdfTransparent', Color=(0.9, 0.7, 0.5))
        sheen = _bsdf(t, 'ShaderNodeBsdfSheen', Color=(0.8, 0.8, 1.0), Roughness=0.4)
        diffuse = _bsdf(t, 'ShaderNodeBsdfDiffuse', Color=(0.2, 0.3, 0.6))
        return _add(t, _mix(t, 0.6, diffuse, transparent), sheen)

    def lens(t):
        return _bsdf(t, 'ShaderNodeBsdfRefraction', Color=(1.0, 0.9, 0.8), Roughness=0.2, IOR=1.3,
                     distribution='GGX')

    _three_lit_spheres(scene, (_material("Leaf", leaf), _material("Veil", veil), _material("Lens", lens)), 1.2)
    return 8


def scene_furnace(scene):
    def metal(distribution):
        return lambda t: _bsdf(t, 'ShaderNodeBsdfPrincipled', **{
            'Base Color': (1.0, 1.0, 1.0), 'Metallic': 1.0, 'Roughness': 0.8, 'distribution': distribution})
    _sphere(_material("Multi", metal('MULTI_GGX')), (-0.6, 0.0, 0.0))
    _sphere(_material("Single", metal('GGX')), (0.6, 0.0, 0.0))
    _world(scene, (1.0, 1.0, 1.0))
    _camera(scene, (0.0, -4.0, 0.0), (0.0, 0.0, 0.0))
    return 16


SCENES = {'glass': scene_glass, 'principled': scene_principled, 'mix': scene_mix, 'furnace': scene_furnace}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    return built_reference_scene(SCENES[name], WIDTH, HEIGHT)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_material_parity_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name)
    spp = SAMPLES.get(name, EMBER_SPP)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 1, bounces)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert not [w for w in log.get('warnings', ()) if 'Material' in w], log.get('warnings')
    check = check_against_reference('material_' + name, scene, bounces, image, var, spp, BLOCK)
    if name == 'furnace':
        print(f"furnace: Ember multiscatter half {image[:, :WIDTH // 2, :3].mean():.4f}, single-scatter half "
              f"{image[:, WIDTH // 2:, :3].mean():.4f}")
    check.assert_agrees(*WEAK.get(name, (IMAGE_POWER, BLOCK_POWER)))
