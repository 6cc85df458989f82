"""Subsurface scattering against Cycles (issue 22): the Principled BSDF's
Subsurface (Random Walk, Christensen-Burley) and the Subsurface Scattering
node (Random Walk (Skin)) exported to Ember's random walk (engine/integrator/subsurface.py),
compared with converged Cycles references (tests/data/cycles_subsurface_<scene>.exr,
tools/cycles_references.py) by the totals of the image and its quadrants
and block by block (ember_testlib.check_against_reference), power printed.

Scenes:
* spheres: a Principled sphere (Subsurface Weight 1, Random Walk, a red
  radius a third of the sphere), a Subsurface Scattering node sphere
  (Random Walk (Skin)) and a Principled Christensen-Burley sphere on a grey
  floor under an area light;
* backlit: a thin subsurface slab (10 cm, a few mean free paths) between
  the camera and an area light facing it from behind: what the camera sees
  of the slab is the walk's transmission (exits on the lit side).

Also the export (the lobes Cycles' closure setup gives, no warning for what
is rendered now) and hostile inputs through Blender: radius 0 and 1e30 and a
NaN scale named with the material, a subsurface single triangle rendered
finite with the open mesh named with its material.
"""
import math

import bpy
import numpy as np
import pytest

from ember_testlib import (built_reference_scene, empty_factory_scene, render_against_reference, render_for_reference,
                           small_resolution)

WIDTH, HEIGHT = 40, 30
BLOCK = 10
EMBER_SPP = 128
# the light through the slab is noisier per sample; spheres 128 -> 256, backlit 384 -> 576:
# with the channel sum's variance they resolved 1.30 % and 2.20 % of the image (asked 1 %, 2 %)
SPP = {'spheres': 256, 'backlit': 576}
BOUNCES = 6
# What the image mean and the median block must resolve (measured: spheres
# 0.92% and 6.6% at 128 spp, backlit 1.62% and 12.2% at 384).
POWER = {'spheres': (0.01, 0.07), 'backlit': (0.02, 0.14)}


def principled(name, base=(0.8, 0.5, 0.3), radius=(1.0, 0.3, 0.15), scale=0.15, method='RANDOM_WALK', **inputs):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    p = mat.node_tree.nodes['Principled BSDF']
    p.inputs['Base Color'].default_value = (*base, 1.0)
    p.inputs['Subsurface Weight'].default_value = 1.0
    p.inputs['Subsurface Radius'].default_value = radius
    p.inputs['Subsurface Scale'].default_value = scale
    p.subsurface_method = method
    for key, value in inputs.items():
        p.inputs[key].default_value = value
    return mat


def sss_node(name, color=(0.9, 0.6, 0.45), radius=(1.0, 0.4, 0.2), scale=0.2, method='RANDOM_WALK_SKIN'):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    node = tree.nodes.new('ShaderNodeSubsurfaceScattering')
    node.falloff = method
    node.inputs['Color'].default_value = (*color, 1.0)
    node.inputs['Radius'].default_value = radius
    node.inputs['Scale'].default_value = scale
    tree.links.new(node.outputs[0], tree.nodes.new('ShaderNodeOutputMaterial').inputs['Surface'])
    return mat


def _object(add, mat, **kwargs):
    add(**kwargs)
    obj = bpy.context.active_object
    obj.data.materials.append(mat)
    return obj


def _grey(name, value):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    mat.node_tree.nodes['Principled BSDF'].inputs['Base Color'].default_value = (value, value, value, 1.0)
    mat.node_tree.nodes['Principled BSDF'].inputs['Roughness'].default_value = 1.0
    return mat


def _area(location, rotation, energy, size):
    light = bpy.data.lights.new("Area", 'AREA')
    light.energy, light.size = energy, size
    obj = bpy.data.objects.new("Area", light)
    obj.location, obj.rotation_euler = location, rotation
    bpy.context.scene.collection.objects.link(obj)


def _camera(scene, location, target):
    cam = scene.camera
    cam.location = location
    direction = np.subtract(target, location)
    cam.rotation_euler = (math.atan2(math.hypot(direction[0], direction[1]), -direction[2]), 0.0,
                          math.atan2(direction[1], direction[0]) - math.pi / 2)
    cam.data.lens = 50.0


def _world(scene, value):
    background = scene.world.node_tree.nodes.get('Background')
    background.inputs['Color'].default_value = (value, value, value, 1.0)


def scene_spheres(scene):
    _object(bpy.ops.mesh.primitive_plane_add, _grey("Floor", 0.5), size=8.0)
    left = _object(bpy.ops.mesh.primitive_uv_sphere_add, principled("Wax"), radius=0.45, segments=32, ring_count=16,
                   location=(-1.0, 0.0, 0.47))
    middle = _object(bpy.ops.mesh.primitive_uv_sphere_add, sss_node("Skin"), radius=0.45, segments=32,
                     ring_count=16, location=(0.0, 0.0, 0.47))
    right = _object(bpy.ops.mesh.primitive_uv_sphere_add,
                    principled("Marble", base=(0.85, 0.8, 0.75), radius=(1.0, 0.6, 0.4), scale=0.2, method='BURLEY'),
                    radius=0.45, segments=32, ring_count=16, location=(1.0, 0.0, 0.47))
    for obj in (left, middle, right):
        obj.select_set(True)
        bpy.context.view_layer.objects.active = obj
        bpy.ops.object.shade_smooth()
    _area((1.0, -1.5, 2.5), (math.radians(40), 0.0, math.radians(30)), 120.0, 1.0)
    _world(scene, 0.05)
    _camera(scene, (0.0, -4.4, 1.5), (0.0, 0.0, 0.45))
    return BOUNCES


def scene_backlit(scene):
    slab = _object(bpy.ops.mesh.primitive_cube_add, principled("Jade", base=(0.7, 0.9, 0.6), radius=(0.6, 1.0, 0.5),
                                                                scale=0.5), size=1.0, location=(0.0, 0.0, 0.6))
    slab.scale = (1.2, 0.1, 0.8)
    _area((0.0, 0.8, 0.6), (math.radians(-90), 0.0, 0.0), 80.0, 1.5)
    _world(scene, 0.02)
    _camera(scene, (0.0, -3.0, 0.6), (0.0, 0.0, 0.6))
    return BOUNCES


SCENES = {'spheres': scene_spheres, 'backlit': scene_backlit}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    return built_reference_scene(SCENES[name], WIDTH, HEIGHT)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_subsurface_parity_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name)
    check = render_against_reference('subsurface_' + name, scene, bounces, tmp_path, tapped_engine,
                                     SPP.get(name, EMBER_SPP), BLOCK)
    check.assert_agrees(*POWER[name])


def test_subsurface_export(empty_scene):
    """Cycles' closure setup: the Principled BSDF's subsurface lobe under its
    specular layer, radius x scale, the Principled IOR (Random Walk) or the
    Subsurface IOR (Skin), Subsurface Weight splitting it from the diffuse;
    the Subsurface Scattering node; no warning for either."""
    from addon.export import material as export
    mat = principled("Wax", radius=(1.0, 0.5, 0.25), scale=0.2, IOR=1.6, **{'Subsurface Weight': 0.25,
                                                                           'Subsurface Anisotropy': 0.4})
    translated, warning = export.translate(mat)
    assert warning is None, warning
    spec, ss, diffuse = translated.lobes
    assert spec.kind == 'glossy' and spec.covers == 2
    assert ss.kind == 'subsurface' and ss.radius == pytest.approx((0.2, 0.1, 0.05))
    assert ss.ior == pytest.approx(1.6) and ss.phase_g == pytest.approx(0.4) and ss.weight == pytest.approx(0.25)
    assert diffuse.kind == 'diffuse' and diffuse.weight == pytest.approx(0.75)
    mat.node_tree.nodes['Principled BSDF'].subsurface_method = 'RANDOM_WALK_SKIN'
    mat.node_tree.nodes['Principled BSDF'].inputs['Subsurface IOR'].default_value = 1.33
    ss = export.translate(mat)[0].lobes[1]
    assert ss.kind == 'subsurface_skin' and ss.ior == pytest.approx(1.33)
    mat.node_tree.nodes['Principled BSDF'].subsurface_method = 'BURLEY'
    translated, warning = export.translate(mat)
    assert warning is None and translated.lobes[1].kind == 'subsurface_burley', warning
    node, warning = export.translate(sss_node("Skin"))
    assert warning is None, warning
    assert [lobe.kind for lobe in node.lobes] == ['subsurface_skin']
    assert node.lobes[0].radius == pytest.approx((0.2, 0.08, 0.04))


def test_small_radius_channels_are_diffuse(empty_scene):
    """Cycles' bssrdf_setup: a channel of radius below 1e-8 is a diffuse lobe
    of that channel; radius 0 everywhere, a diffuse closure."""
    from addon.export import material as export
    lobes = export.translate(principled("Part", radius=(1.0, 0.0, 1.0), scale=0.1))[0].lobes
    assert [lobe.kind for lobe in lobes] == ['glossy', 'subsurface', 'diffuse']   # Subsurface Weight 1
    assert lobes[1].color == pytest.approx((0.8, 0.0, 0.3)) and lobes[2].color == pytest.approx((0.0, 0.5, 0.0))
    lobes = export.translate(principled("None", radius=(0.0, 0.0, 0.0)))[0].lobes
    assert [lobe.kind for lobe in lobes] == ['glossy', 'diffuse'] and lobes[0].covers == 1


@pytest.mark.parametrize("case", ["zero", "huge", "nan_scale"])
def test_hostile_subsurface_inputs_are_named(case, empty_scene):
    """Radius 0 and 1e30 and a NaN scale: named with the material (the
    engine renders them finite: tests/engine/test_subsurface.py)."""
    from addon.export import material as export
    radius, scale = {'zero': ((0.0,) * 3, 1.0), 'huge': ((1e30,) * 3, 1.0), 'nan_scale': ((1.0,) * 3, float('nan'))}[case]
    translated, warning = export.translate(principled("Hostile", radius=radius, scale=scale))
    assert warning is not None and "'Hostile'" in warning and 'subsurface' in warning, warning
    for lobe in translated.lobes:
        assert all(math.isfinite(r) for r in lobe.radius)


def test_subsurface_triangle_renders_finite(tmp_path, tapped_engine):
    """Subsurface on a single triangle: finite pixels, the open mesh named
    with its material."""
    scene = empty_factory_scene()
    mesh = bpy.data.meshes.new("tri")
    mesh.from_pydata([(-1, 0, 0), (1, 0, 0), (0, 0, 1.5)], [], [(0, 1, 2)])
    obj = bpy.data.objects.new("Tri", mesh)
    scene.collection.objects.link(obj)
    obj.data.materials.append(principled("Hostile", radius=(1.0, 0.5, 0.2), scale=0.1))
    _area((0.0, -2.0, 2.0), (math.radians(45), 0.0, 0.0), 50.0, 1.0)
    _camera(scene, (0.0, -3.0, 0.6), (0.0, 0.0, 0.5))
    small_resolution(scene, 12, 9)
    image, _ = render_for_reference(scene, tmp_path, 'triangle', tapped_engine, 4, 1, 4)
    assert np.isfinite(image).all()
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1].get('warnings', ())
    assert any("'Hostile'" in w and "'Tri'" in w and 'not closed' in w for w in warnings), warnings
