"""Heterogeneous volumes against Cycles (issue 21, second part): small
scenes built here with bpy, rendered by Ember and compared with converged
Cycles references (tests/data/cycles_volume_field_<scene>.exr, rendered by
tools/cycles_references.py) by the totals of the image and its quadrants and
block by block at the suite's family level
(ember_testlib.check_against_reference); results and power are printed.

Scenes:
* smoke: a rotated cube of Principled Volume whose density is 3D noise in
  Object coordinates through a colour ramp, and whose emission strength is
  the same ramp's alpha (a glow where the smoke is dense), under a sun,
  on a floor: null-scattering tracking against the majorant grid, NEE
  through the textured medium, Object coordinates of a transformed object.
"""
import bpy
import pytest

from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference, small_resolution
from test_volume_parity import _camera, _floor, _material, _object, _volume_settings, _world

SPP = {'smoke': 128}
BLOCK = 6
WIDTH, HEIGHT = 24, 18
# What each scene resolves at its samples (the suite's time budget): asserted.
POWER = {'smoke': (0.005, 0.03)}   # measured: 0.36% and 2.5% at 128 spp


def _smoke_volume(tree):
    coords = tree.nodes.new('ShaderNodeTexCoord')
    noise = tree.nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 2.5
    noise.inputs['Detail'].default_value = 1.0
    tree.links.new(coords.outputs['Object'], noise.inputs['Vector'])
    ramp = tree.nodes.new('ShaderNodeValToRGB')
    ramp.color_ramp.elements[0].position = 0.42
    ramp.color_ramp.elements[0].color = (0.0, 0.0, 0.0, 0.0)
    ramp.color_ramp.elements[1].position = 0.62
    ramp.color_ramp.elements[1].color = (1.0, 1.0, 1.0, 1.0)
    tree.links.new(noise.outputs['Fac'], ramp.inputs['Fac'])
    scale = tree.nodes.new('ShaderNodeMath')
    scale.operation = 'MULTIPLY'
    scale.inputs[1].default_value = 6.0
    tree.links.new(ramp.outputs['Color'], scale.inputs[0])
    volume = tree.nodes.new('ShaderNodeVolumePrincipled')
    volume.inputs['Color'].default_value = (0.8, 0.75, 0.7, 1.0)
    volume.inputs['Anisotropy'].default_value = 0.2
    volume.inputs['Emission Color'].default_value = (1.0, 0.45, 0.15, 1.0)
    tree.links.new(scale.outputs[0], volume.inputs['Density'])
    tree.links.new(ramp.outputs['Alpha'], volume.inputs['Emission Strength'])
    return volume.outputs[0]


def scene_smoke(scene):
    _floor((0.6, 0.6, 0.6))
    smoke = _material("Smoke", volume=_smoke_volume)
    cube = _object(bpy.ops.mesh.primitive_cube_add, smoke, size=2.0, location=(0.0, 0.0, 1.1))
    cube.rotation_euler = (0.0, 0.0, 0.5)
    cube.scale = (1.0, 0.8, 1.0)
    sun = bpy.data.lights.new("Sun", 'SUN')
    sun.energy = 3.0
    sun.angle = 0.05
    obj = bpy.data.objects.new("Sun", sun)
    obj.rotation_euler = (0.6, 0.3, 0.4)
    scene.collection.objects.link(obj)
    _world(scene, (0.03, 0.035, 0.05))
    _camera(scene, (0.0, -5.5, 2.0), (0.0, 0.0, 1.0))
    _volume_settings(scene)
    return 4


SCENES = {'smoke': scene_smoke}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    bounces = SCENES[name](scene)
    small_resolution(scene, WIDTH, HEIGHT)
    return scene, bounces


@pytest.mark.parametrize("name", sorted(SCENES))
def test_volume_field_parity_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name)
    spp = SPP[name]
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 1, bounces)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert not [w for w in log.get('warnings', ()) if 'aterial' in w], log.get('warnings')
    check = check_against_reference('volume_field_' + name, scene, bounces, image, var, spp, BLOCK)
    check.assert_agrees(*POWER[name])
