"""Cycles parity of point clouds (engine/points.py, addon/export/instances.py
``_add_points``): 10k spheres made by geometry nodes (Mesh to Points) from a
mesh's vertices, each of its own radius (a named attribute) and colour (a
colour attribute the material reads through an Attribute node), heaped on a
diffuse floor under an area light, against a converged Cycles reference
(tools/cycles_references.py points_heap).  NaN radii render finite."""
import bpy
import numpy as np

from parity_scenes import light, material, plane, top_camera
from ember_testlib import (check_against_reference, empty_factory_scene, record_engine_scenes,
                           render_for_reference, small_resolution)

BLOCK = 8
SPP = 512   # the median block resolves 2.7% at 256
COUNT = 10_000


def _points_material():
    """A Diffuse BSDF coloured by the attribute 'col'."""
    mat = material("points", 'diffuse')
    tree = mat.node_tree
    attr = tree.nodes.new('ShaderNodeAttribute')
    attr.attribute_name = 'col'
    tree.links.new(attr.outputs['Color'], tree.nodes['Diffuse BSDF'].inputs['Color'])
    return mat


def point_object(name, positions, radii, colours, mat):
    """A mesh of loose vertices turned into points by geometry nodes, radius
    from the vertex attribute 'rad', colour attribute 'col' carried over."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([tuple(p) for p in positions], [], [])
    rad = mesh.attributes.new('rad', 'FLOAT', 'POINT')
    rad.data.foreach_set('value', np.asarray(radii, np.float32))
    col = mesh.attributes.new('col', 'FLOAT_COLOR', 'POINT')
    col.data.foreach_set('color', np.asarray(colours, np.float32).reshape(-1))
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    tree = bpy.data.node_groups.new(name + "_points", 'GeometryNodeTree')
    tree.interface.new_socket('Geometry', in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket('Geometry', in_out='OUTPUT', socket_type='NodeSocketGeometry')
    group_in = tree.nodes.new('NodeGroupInput')
    group_out = tree.nodes.new('NodeGroupOutput')
    to_points = tree.nodes.new('GeometryNodeMeshToPoints')
    named = tree.nodes.new('GeometryNodeInputNamedAttribute')
    named.data_type = 'FLOAT'
    named.inputs['Name'].default_value = 'rad'
    set_material = tree.nodes.new('GeometryNodeSetMaterial')
    set_material.inputs['Material'].default_value = mat
    tree.links.new(group_in.outputs[0], to_points.inputs['Mesh'])
    tree.links.new(named.outputs['Attribute'], to_points.inputs['Radius'])
    tree.links.new(to_points.outputs['Points'], set_material.inputs['Geometry'])
    tree.links.new(set_material.outputs['Geometry'], group_out.inputs[0])
    modifier = obj.modifiers.new("points", 'NODES')
    modifier.node_group = tree
    return obj


def heap(scene, count=COUNT, nan_radii=0):
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.5, -0.5, 4.0), 300.0, size=2.0)
    rng = np.random.default_rng(24)
    positions = np.c_[rng.uniform(-1.6, 1.6, (count, 2)), rng.uniform(0.05, 0.6, count)]
    radii = rng.uniform(0.02, 0.07, count)
    radii[:nan_radii] = np.nan
    colours = np.c_[rng.uniform(0.1, 0.9, (count, 3)), np.ones(count)]
    point_object("heap", positions, radii, colours, _points_material())
    top_camera(scene, 5.0)
    small_resolution(scene, 48, 32)
    return 2


SCENES = {'heap': heap}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_point_cloud_parity_with_cycles(tmp_path, tapped_engine):
    scene, bounces = reference_scene('heap')
    image, var = render_for_reference(scene, tmp_path, 'heap', tapped_engine, SPP, 2, bounces)
    check = check_against_reference('points_heap', scene, bounces, image, var, SPP, BLOCK)
    check.assert_agrees(0.005, 0.02)


def test_nan_radii_render_finite(tmp_path, tapped_engine, monkeypatch):
    """Blender's Mesh to Points turns a NaN radius into 0 (the export would
    skip a NaN it met, with a warning naming the object; engine-level NaN
    radii are a named error, tests/engine/test_points.py): finite pixels, no
    error, every point exported."""
    seen = record_engine_scenes(monkeypatch)
    scene = empty_factory_scene()
    bounces = heap(scene, count=500, nan_radii=7)
    image, _ = render_for_reference(scene, tmp_path, 'nan', tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()
    cloud = seen[-1].points[0]
    assert len(cloud.positions) == 500 and np.isfinite(cloud.radii).all() and (cloud.radii == 0).sum() == 7
