"""Subsurface scattering against Cycles (issue 22): the Principled BSDF's
Subsurface (Random Walk) and the Subsurface Scattering node (Random Walk
(Skin)) exported to Ember's random walk (engine/integrator/subsurface.py),
compared with converged Cycles references (tests/data/cycles_subsurface_<scene>.exr,
tools/cycles_references.py) by the totals of the image and its quadrants
and block by block (ember_testlib.check_against_reference), power printed.

Scenes:
* spheres: a Principled sphere (Subsurface Weight 1, Random Walk, a red
  radius a third of the sphere) and a Subsurface Scattering node sphere
  (Random Walk (Skin)) on a grey floor under an area light;
* backlit: a thin subsurface slab between the camera and an area light
  behind it: the light that comes through is the walk's transmission.

Also the export (the lobes Cycles' closure setup gives, no warning for what
is rendered now) and hostile inputs through Blender: radius 0 and 1e30 and a
subsurface single triangle render finite pixels, the open mesh named with its
material.
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
BOUNCES = 6


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
    left = _object(bpy.ops.mesh.primitive_uv_sphere_add, principled("Wax"), radius=0.5, segments=32, ring_count=16,
                   location=(-0.6, 0.0, 0.52))
    right = _object(bpy.ops.mesh.primitive_uv_sphere_add, sss_node("Skin"), radius=0.5, segments=32, ring_count=16,
                    location=(0.6, 0.0, 0.52))
    for obj in (left, right):
        obj.select_set(True)
        bpy.context.view_layer.objects.active = obj
        bpy.ops.object.shade_smooth()
    _area((1.0, -1.5, 2.5), (math.radians(40), 0.0, math.radians(30)), 120.0, 1.0)
    _world(scene, 0.05)
    _camera(scene, (0.0, -3.6, 1.4), (0.0, 0.0, 0.45))
    return BOUNCES


def scene_backlit(scene):
    slab = _object(bpy.ops.mesh.primitive_cube_add, principled("Jade", base=(0.3, 0.8, 0.4), radius=(0.6, 1.0, 0.6),
                                                                scale=0.1), size=1.0, location=(0.0, 0.0, 0.6))
    slab.scale = (1.2, 0.08, 0.8)
    _area((0.0, 1.0, 0.6), (math.radians(90), 0.0, math.radians(180)), 60.0, 0.8)
    _world(scene, 0.0)
    _camera(scene, (0.0, -3.0, 0.6), (0.0, 0.0, 0.6))
    return BOUNCES


SCENES = {'spheres': scene_spheres, 'backlit': scene_backlit}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    return built_reference_scene(SCENES[name], WIDTH, HEIGHT)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_subsurface_parity_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name)
    check = render_against_reference('subsurface_' + name, scene, bounces, tmp_path, tapped_engine, EMBER_SPP, BLOCK)
    check.assert_agrees(0.01, 0.05)


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


@pytest.mark.parametrize("case", ["zero", "huge", "nan_scale", "triangle"])
def test_hostile_subsurface_renders_finite(case, tmp_path, tapped_engine):
    """Radius 0 and 1e30, a NaN scale, and subsurface on a single triangle:
    finite pixels; the open mesh and the unusable inputs named with the
    material."""
    scene = empty_factory_scene()
    radius, scale = {'zero': ((0.0,) * 3, 1.0), 'huge': ((1e30,) * 3, 1.0), 'nan_scale': ((1.0,) * 3, float('nan')),
                     'triangle': ((1.0, 0.5, 0.2), 0.1)}[case]
    mat = principled("Hostile", radius=radius, scale=scale)
    if case == 'triangle':
        mesh = bpy.data.meshes.new("tri")
        mesh.from_pydata([(-1, 0, 0), (1, 0, 0), (0, 0, 1.5)], [], [(0, 1, 2)])
        obj = bpy.data.objects.new("Tri", mesh)
        scene.collection.objects.link(obj)
        obj.data.materials.append(mat)
    else:
        _object(bpy.ops.mesh.primitive_uv_sphere_add, mat, radius=0.5, segments=16, ring_count=8,
                location=(0.0, 0.0, 0.5))
    _area((0.0, -2.0, 2.0), (math.radians(45), 0.0, 0.0), 50.0, 1.0)
    _camera(scene, (0.0, -3.0, 0.6), (0.0, 0.0, 0.5))
    small_resolution(scene, 12, 9)
    image, _ = render_for_reference(scene, tmp_path, case, tapped_engine, 4, 1, 4)
    assert np.isfinite(image).all()
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1].get('warnings', ())
    if case in ('zero', 'nan_scale', 'triangle', 'huge'):
        assert any("'Hostile'" in w for w in warnings), warnings
