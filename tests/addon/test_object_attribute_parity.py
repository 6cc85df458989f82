"""Attribute nodes of type Object, Instancer and View Layer, per pixel
against a one-sample Cycles render (the pattern of test_node_parity.py).

Quads seen from above, each an object whose Emission colour is an
Attribute node's output: custom properties of the object (a colour, a
float, an int, a bool), of its mesh, RNA paths ('color', 'location'), a
name nothing has (zero), an Instancer attribute on quads of a collection
instanced by two empties with their own properties (and on a quad that is
no instance: the object's own), and View Layer attributes found on the view
layer, the scene and the world.
"""
import bpy
import numpy as np

from test_node_parity import ATOL, RTOL, emission_material
from test_geometry_attr_parity import _interior, emission_against_cycles
from ember_testlib import small_resolution

COLUMNS, ROWS, TILE = 8, 4, 8


def _material(kind, name, output='Color'):
    mat, tree, emission = emission_material(f"{kind} {name} {output}")
    attr = tree.nodes.new('ShaderNodeAttribute')
    attr.attribute_type, attr.attribute_name = kind, name
    tree.links.new(attr.outputs[output], emission.inputs['Color'])
    return mat


def _quad(name, material, cell, collection=None, **props):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(-0.45, -0.45, 0), (0.45, -0.45, 0), (0.45, 0.45, 0), (-0.45, 0.45, 0)], [], [(0, 1, 2, 3)])
    mesh.materials.append(material)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = (cell[0] + 0.5, cell[1] + 0.5, 0.0)
    for key, value in props.items():
        if key == 'mesh':
            for k, v in value.items():
                mesh[k] = v
        elif key == 'color':
            obj.color = value
        else:
            obj[key] = value
    (collection or bpy.context.scene.collection).objects.link(obj)
    return obj


def build_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type, cam_data.ortho_scale = 'ORTHO', COLUMNS
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (COLUMNS / 2 + 0.011, ROWS / 2 + 0.017, 5.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    world = bpy.data.worlds.new("world")
    world.color = (0.0, 0.0, 0.0)
    world["glow_world"] = 0.45
    scene.world = world
    scene["glow"] = (0.7, 0.2, 0.1)
    scene["layer_tint"] = 0.05          # the view layer's own value wins
    bpy.context.view_layer["layer_tint"] = (0.3, 0.6, 0.9, 0.5)
    small_resolution(scene, COLUMNS * TILE, ROWS * TILE)
    tint = _material('OBJECT', 'tint')
    quads = [
        ('colour prop', tint, dict(tint=(0.2, 0.5, 0.8))),
        ('float prop', tint, dict(tint=0.35)),
        ('int prop', tint, dict(tint=2)),
        ('bool prop', tint, dict(tint=True)),
        ('mesh prop', tint, dict(mesh={'tint': (0.9, 0.1, 0.4)})),
        ('nothing', _material('OBJECT', 'tint', 'Alpha'), dict()),
        ('alpha', _material('OBJECT', 'tint', 'Alpha'), dict(tint=(0.1, 0.2, 0.3, 0.6))),
        ('fac', _material('OBJECT', 'tint', 'Fac'), dict(tint=(0.2, 0.5, 0.8))),
        ('rna color', _material('OBJECT', 'color'), dict(color=(0.8, 0.3, 0.6, 1.0))),
        ('rna location', _material('OBJECT', 'location', 'Vector'), dict()),
        ('string prop', tint, dict(tint="red")),
        ('rna path', _material('OBJECT', 'scale', 'Fac'), dict()),
        ('not an instance', _material('INSTANCER', 'tint'), dict(tint=(0.6, 0.6, 0.1))),
        ('layer', _material('VIEW_LAYER', 'layer_tint'), dict()),
        ('layer alpha', _material('VIEW_LAYER', 'layer_tint', 'Alpha'), dict()),
        ('scene', _material('VIEW_LAYER', 'glow'), dict()),
        ('world', _material('VIEW_LAYER', 'glow_world'), dict()),
        ('layer nothing', _material('VIEW_LAYER', 'missing', 'Alpha'), dict()),
    ]
    for k, (name, mat, props) in enumerate(quads):
        obj = _quad(name, mat, (k % COLUMNS, ROWS - 1 - k // COLUMNS), **props)
        obj.scale = (1.0, 1.0, 1.0 + 0.5 * k)
    # Instancer: two empties instance a collection of two quads.
    group = bpy.data.collections.new("instanced")
    _quad('instanced a', _material('INSTANCER', 'tint'), (0, 0), group, tint=(0.9, 0.9, 0.9))
    _quad('instanced b', _material('OBJECT', 'tint'), (1, 0), group, tint=(0.15, 0.25, 0.35))
    for k, value in enumerate([(0.8, 0.2, 0.3), 0.55]):
        empty = bpy.data.objects.new(f"instancer {k}", None)
        empty.instance_type, empty.instance_collection = 'COLLECTION', group
        empty.location = (2 + 2 * k, 0.0, 0.0)
        empty["tint"] = value
        scene.collection.objects.link(empty)
    return scene


def test_object_instancer_view_layer_attributes_match_cycles(registered_addon, tmp_path):
    scene = build_scene()
    exported, ember, material, cycles = emission_against_cycles(scene, tmp_path)
    keep = _interior(material)
    assert keep.sum() > 22 * 20, int(keep.sum())
    bad = ~np.isclose(ember, cycles, atol=ATOL, rtol=RTOL) & keep[..., None]
    names = [m.name for m in exported.scene.materials]
    wrong = sorted({names[m] for m in material[bad.any(axis=2)]})
    assert not wrong, f"{int(bad.any(axis=2).sum())} pixels off in {wrong}, max {np.abs(ember - cycles)[bad].max():.3g}"
    # The scene exercises found and missing values: many distinct colours.
    assert len(np.unique(np.round(cycles[keep], 4), axis=0)) >= 14
