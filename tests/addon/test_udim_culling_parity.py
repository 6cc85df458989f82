"""UDIM tiles as Cycles' final renders load them: only the tiles holding a
UV corner of some mesh of the material (ImageTextureNode::cull_tiles,
Attribute::get_uv_tiles), per pixel against a one-sample Cycles render
through an Emission shader (Closest float tiles: exact values).

A quad whose UVs run from tile 1001 across 1002 into 1003 with corners in
1001 and 1003 only: Cycles shows its missing-tile magenta over 1002 (the
image has the tile), and so must Ember.  The same image in a second
material shared by a quad with a corner in 1002 keeps that tile; a UV Map
node reads its own map's corners; a Mapping on the vector keeps all tiles.
"""
import os

import bpy
import numpy as np

from test_node_parity import ATOL, RTOL, SHIFT_Y_SIGN, cycles_first_sample_offset, emission_material, render_cycles
from test_geometry_attr_parity import _interior
from test_image_parity import checker, tiled_image
from ember_testlib import small_resolution


def _quad(name, material, location, uv, second_uv=None):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(-0.9, -0.4, 0), (0.9, -0.4, 0), (0.9, 0.4, 0), (-0.9, 0.4, 0)], [], [(0, 1, 2, 3)])
    for layer_name, corners in (("UVMap", uv), ("Second", second_uv)):
        if corners is None:
            continue
        layer = mesh.uv_layers.new(name=layer_name)
        for k, loop in enumerate(mesh.polygons[0].loop_indices):
            layer.data[loop].uv = corners[k]
    mesh.uv_layers.active_index = 0
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _material(name, image, vector=None):
    mat, tree, emission = emission_material(name)
    node = tree.nodes.new('ShaderNodeTexImage')
    node.image, node.interpolation = image, 'Closest'
    if vector == 'mapping':
        coords = tree.nodes.new('ShaderNodeTexCoord')
        mapping = tree.nodes.new('ShaderNodeMapping')
        mapping.inputs['Location'].default_value = (0.05, 0.0, 0.0)   # not the identity (Cycles folds that away)
        tree.links.new(coords.outputs['UV'], mapping.inputs['Vector'])
        tree.links.new(mapping.outputs['Vector'], node.inputs['Vector'])
    elif vector is not None:
        uvmap = tree.nodes.new('ShaderNodeUVMap')
        uvmap.uv_map = vector
        tree.links.new(uvmap.outputs['UV'], node.inputs['Vector'])
    tree.links.new(node.outputs['Color'], emission.inputs['Color'])
    return mat


def build_scene(folder):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type, cam_data.ortho_scale = 'ORTHO', 8.0
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (0.011, 0.017, 5.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    small_resolution(scene, 64, 48)
    image = tiled_image(folder, "cull.<UDIM>.exr", {
        '1001': (checker(4, (0.2, 0.7, 0.3), (0.6, 0.1, 0.5)), False),
        '1002': (checker(2, (0.9, 0.8, 0.1), (0.1, 0.2, 0.9)), False),
        '1003': (checker(4, (0.5, 0.5, 0.5), (0.3, 0.9, 0.9)), False)}, colorspace='Non-Color')
    assert sorted(t.number for t in image.tiles) == [1001, 1002, 1003]
    span = [(0.3, 0.2), (2.7, 0.2), (2.7, 0.8), (0.3, 0.8)]      # corners in 1001 and 1003 only
    alone = _material("alone", image)
    _quad("spanning", alone, (-1.8, 2.3, 0), span)
    shared = _material("shared", image)
    _quad("spanning shared", shared, (1.8, 2.3, 0), span)
    _quad("corner in 1002", shared, (1.8, 1.1, 0), [(1.2, 0.3), (1.6, 0.3), (1.6, 0.7), (1.2, 0.7)])
    by_name = _material("uv map node", image, "Second")
    _quad("second map", by_name, (-1.8, -0.4, 0), [(1.2, 0.3), (1.6, 0.3), (1.6, 0.7), (1.2, 0.7)], span)
    mapped = _material("mapped", image, 'mapping')
    _quad("mapped", mapped, (1.8, -0.4, 0), span)
    return scene


def test_udim_tiles_are_culled_as_in_cycles(registered_addon, tmp_path):
    from addon.export.scene import export_scene
    from engine.nodes import probe
    scene = build_scene(str(tmp_path))
    exported = export_scene(bpy.context.evaluated_depsgraph_get())
    shift = cycles_first_sample_offset()
    ember, material = probe.emission_at_pixel_centres(exported.scene, offset=(shift, SHIFT_Y_SIGN * shift))
    cycles = render_cycles(scene, tmp_path)
    keep = _interior(material)
    names = [m.name for m in exported.scene.materials]
    magenta = np.all(np.isclose(cycles, (1.0, 0.0, 1.0), atol=1e-4), axis=2) & keep
    # Cycles culled tile 1002 for 'alone' and for the UV Map node reading
    # the map whose corners miss 1002 (the active map's are all in 1002).
    culled = {names[m] for m in material[magenta]}
    assert culled == {"alone", "uv map node"}, culled
    bad = ~np.isclose(ember, cycles, atol=ATOL, rtol=RTOL) & keep[..., None]
    wrong = sorted({names[m] for m in material[bad.any(axis=2)]})
    assert not wrong, f"{int(bad.any(axis=2).sum())} pixels off in {wrong}"
