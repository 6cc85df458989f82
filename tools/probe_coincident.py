"""Which of two coincident faces a ray meets, in Cycles and in Ember.

    .venv/bin/python -P tools/probe_coincident.py

A Transparent BSDF cube resting exactly on an emissive floor (black world),
seen from above by an orthographic camera that sees only the cube: a pixel
is lit when its ray, inside the cube, finds the floor at z = 0 before the
cube's bottom (else it leaves through the bottom and the floor, at distance
0 from there, is skipped).  Prints, per arrangement (floor size, height,
tilt, which object is created first, floor subdivision), the share of lit
pixels for each renderer (docs/real_scenes.md, coincident_faces).
"""
import math
import os
import sys
import tempfile

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path[:0] = [ROOT, os.path.join(ROOT, 'tests'), os.path.join(ROOT, 'tests', 'addon')]
os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-probe-'))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

import addon  # noqa: E402
from ember_testlib import render_array, setup_cycles, setup_ember  # noqa: E402

# (floor size, height, tilt in degrees, cube created first, floor subdivision cuts)
CASES = [(12, 0.0, 0, False, 0), (12, 0.0, 0, True, 0), (2, 0.0, 0, False, 0), (12, 0.37, 0, False, 0),
         (12, 0.0, 0, False, 5), (12, 0.0, 23, False, 0)]


def material(name, kind, color):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    out, node = tree.nodes.new('ShaderNodeOutputMaterial'), tree.nodes.new(kind)
    node.inputs['Color'].default_value = color
    tree.links.new(node.outputs[0], out.inputs['Surface'])
    return mat


def add_floor(size, z, cuts, mat):
    bpy.ops.mesh.primitive_plane_add(size=size, location=(0.1, 0.2, z))
    if cuts:
        bpy.ops.object.mode_set(mode='EDIT')
        bpy.ops.mesh.subdivide(number_cuts=cuts)
        bpy.ops.object.mode_set(mode='OBJECT')
    bpy.context.active_object.data.materials.append(mat)
    return bpy.context.active_object


def add_cube(z, mat):
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, z + 0.5))
    bpy.context.active_object.data.materials.append(mat)
    return bpy.context.active_object


def build(size, z, tilt, cube_first, cuts):
    bpy.ops.wm.read_factory_settings()
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    scene = bpy.context.scene
    scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)
    emissive = material('floor', 'ShaderNodeEmission', (1, 1, 1, 1))
    clear = material('clear', 'ShaderNodeBsdfTransparent', (1, 1, 1, 1))
    if cube_first:
        objects = [add_cube(z, clear), add_floor(size, z, cuts, emissive)]
    else:
        objects = [add_floor(size, z, cuts, emissive), add_cube(z, clear)]
    camera = scene.camera
    camera.data.type, camera.data.ortho_scale = 'ORTHO', 0.8
    camera.location, camera.rotation_euler = (0, 0, z + 5), (0, 0, 0)
    if tilt:
        pivot = bpy.data.objects.new('pivot', None)
        scene.collection.objects.link(pivot)
        for obj in objects + [camera]:
            obj.parent = pivot
        pivot.rotation_euler = (math.radians(tilt), math.radians(0.7 * tilt), 0.3)
    scene.render.resolution_x = scene.render.resolution_y = 24
    scene.render.resolution_percentage = 100
    return scene


def main():
    addon.register()
    folder = tempfile.mkdtemp(prefix='ember-probe-')
    print("floor size, height, tilt, cube first, cuts: share of pixels finding the floor")
    for case in CASES:
        shares = []
        for name, setup in (('Cycles', setup_cycles), ('Ember', setup_ember)):
            scene = build(*case)
            setup(scene, 4, 0, 8)
            image = render_array(scene, folder, name)[..., 0]
            shares.append(f"{name} {np.mean(image > 0.5):.2f}")
        print(case, ", ".join(shares), flush=True)


if __name__ == '__main__':
    main()
