"""Cycles parity of the Bump Map Correction per lobe (engine/bump_correction.py):
a Principled sphere whose normal a strong Noise bump turns away from the
view at many points (before, Ember shaded those with the unbent normal and
was 12.5% bright on such a sphere), glossy and diffuse lobes both, under
two small point lights and a dim world, against the converged Cycles
reference tests/data/cycles_bump_correction_sphere.exr
(tools/cycles_references.py): image and region means and blocks, power
printed and asserted."""
import bpy

from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference, small_resolution
from test_material_parity import _camera, _floor, _material, _object, _world

EMBER_SPP = 384   # 256 resolved 1.13 % of the image with the channels' covariance in its variance
BLOCK = 6
WIDTH, HEIGHT = 36, 27
BOUNCES = 3
IMAGE_POWER, BLOCK_POWER = 0.01, 0.06


def bumped_principled(name, strength, roughness, scale):
    def build(t):
        bsdf = t.nodes.new('ShaderNodeBsdfPrincipled')
        bsdf.inputs['Base Color'].default_value = (0.2, 0.5, 0.8, 1.0)
        bsdf.inputs['Roughness'].default_value = roughness
        noise = t.nodes.new('ShaderNodeTexNoise')
        noise.inputs['Scale'].default_value = scale
        bump = t.nodes.new('ShaderNodeBump')
        bump.inputs['Strength'].default_value = strength
        bump.inputs['Distance'].default_value = 1.0
        t.links.new(noise.outputs['Fac'], bump.inputs['Height'])
        t.links.new(bump.outputs['Normal'], bsdf.inputs['Normal'])
        return bsdf.outputs[0]
    return _material(name, build)


def plain(name, color):
    def build(t):
        bsdf = t.nodes.new('ShaderNodeBsdfDiffuse')
        bsdf.inputs['Color'].default_value = color + (1.0,)
        return bsdf.outputs[0]
    return _material(name, build)


def _point(location, energy, radius):
    data = bpy.data.lights.new('point', 'POINT')
    data.energy = energy
    data.shadow_soft_size = radius
    obj = bpy.data.objects.new('point', data)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)


def build(scene):
    _floor(plain("floor", (0.5, 0.5, 0.5)))
    _object(bpy.ops.mesh.primitive_uv_sphere_add, bumped_principled("bumped", 1.0, 0.25, 6.0),
            radius=0.8, location=(0.0, 0.0, 0.8), segments=48, ring_count=24)
    _point((-1.5, -2.0, 2.5), 300.0, 0.05)
    _point((2.0, -1.0, 1.5), 150.0, 0.02)
    _world(scene, (0.05, 0.05, 0.06))
    _camera(scene, (0.0, -3.6, 1.5), (0.0, 0.0, 0.7))


def reference_scene(name='sphere', folder=None):
    """The scene and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    build(scene)
    small_resolution(scene, WIDTH, HEIGHT)
    return scene, BOUNCES


def test_bump_turned_away_from_the_view_matches_cycles(tmp_path, tapped_engine):
    scene, bounces = reference_scene()
    image, var = render_for_reference(scene, tmp_path, "bump_correction", tapped_engine, EMBER_SPP, 1, bounces)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert not log.get('warnings'), log.get('warnings')
    check = check_against_reference('bump_correction_sphere', scene, bounces, image, var, EMBER_SPP, BLOCK)
    check.assert_agrees(IMAGE_POWER, BLOCK_POWER)
