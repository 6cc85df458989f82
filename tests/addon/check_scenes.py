"""Scenes of the kinds third-party files showed differing from Cycles
(issue 23's silent differences), built from scratch for side-by-side runs:

    .venv/bin/python -P tests/addon/check_scenes.py out/check      # writes out/check/*.blend
    .venv/bin/python -P tools/compare_blends.py out/check

Each builder makes a scene in the factory file with Cycles' default
settings (what a third-party file carries), so the comparison also covers
how Ember reads them.  Tests import the builders (``SCENES``)."""
import math
import os
import sys

import bpy

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)), os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
from parity_scenes import smooth_sphere  # noqa: E402


def _material(name, **inputs):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes['Principled BSDF']
    for key, value in inputs.items():
        bsdf.inputs[key].default_value = value
    return mat, bsdf


def _sphere(name, mat, location, radius=0.5):
    return smooth_sphere(name, mat, location, radius, segments=48, rings=24)


def _plane(name, mat, size, location=(0, 0, 0), rotation=(0, 0, 0)):
    bpy.ops.mesh.primitive_plane_add(size=size, location=location, rotation=rotation)
    obj = bpy.context.active_object
    obj.name = name
    obj.data.materials.append(mat)
    return obj


def _point(location, energy, radius=0.1):
    bpy.ops.object.light_add(type='POINT', location=location)
    light = bpy.context.active_object
    light.data.energy = energy
    light.data.shadow_soft_size = radius
    return light


def _camera(location, target, lens=40.0):
    from mathutils import Vector
    cam = bpy.context.scene.camera
    cam.location = location
    cam.rotation_euler = (Vector(target) - Vector(location)).to_track_quat('-Z', 'Y').to_euler()
    cam.data.lens = lens


def _fresh():
    bpy.ops.wm.read_factory_settings()
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    return bpy.context.scene


def glossy_spheres_point_lights():
    """Glossy Principled spheres with a Noise roughness texture, a Bump
    node and a Normal Map (from a Noise colour) under two small point
    lights: fireflies 6-18x Cycles' in third-party files."""
    scene = _fresh()
    floor, _ = _material('floor', **{'Base Color': (0.5, 0.5, 0.5, 1), 'Roughness': 0.8})
    _plane('floor', floor, 12)
    rough, bsdf = _material('rough texture', **{'Base Color': (0.8, 0.2, 0.1, 1), 'Metallic': 1.0})
    noise = rough.node_tree.nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 6.0
    rough.node_tree.links.new(noise.outputs['Fac'], bsdf.inputs['Roughness'])
    _sphere('rough', rough, (-1.2, 0, 0.5))
    bumped, bsdf = _material('bump', **{'Base Color': (0.2, 0.6, 0.2, 1), 'Roughness': 0.15})
    nt = bumped.node_tree
    noise = nt.nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 12.0
    bump = nt.nodes.new('ShaderNodeBump')
    bump.inputs['Strength'].default_value = 0.6
    nt.links.new(noise.outputs['Fac'], bump.inputs['Height'])
    nt.links.new(bump.outputs['Normal'], bsdf.inputs['Normal'])
    _sphere('bumped', bumped, (0, 0, 0.5))
    mapped, bsdf = _material('normal map', **{'Base Color': (0.2, 0.3, 0.8, 1), 'Roughness': 0.1})
    nt = mapped.node_tree
    noise = nt.nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 8.0
    nmap = nt.nodes.new('ShaderNodeNormalMap')
    nmap.inputs['Strength'].default_value = 0.8
    nt.links.new(noise.outputs['Color'], nmap.inputs['Color'])
    nt.links.new(nmap.outputs['Normal'], bsdf.inputs['Normal'])
    _sphere('mapped', mapped, (1.2, 0, 0.5))
    _point((-1.5, -2.0, 2.5), 300.0, 0.05)
    _point((2.0, -1.0, 1.5), 150.0, 0.02)
    _camera((0, -4.5, 1.6), (0, 0, 0.5))
    return scene


def emissive_plane_room():
    """A wall and floor lit by an emissive plane and a point light: light
    spread differently over the floor (90th-percentile block error 46%)."""
    scene = _fresh()
    wall, _ = _material('wall', **{'Base Color': (0.7, 0.7, 0.65, 1), 'Roughness': 0.6})
    _plane('floor', wall, 8)
    _plane('wall', wall, 8, (0, 2.0, 2.0), (math.pi / 2, 0, 0))
    lamp = bpy.data.materials.new('panel')
    lamp.use_nodes = True
    nt = lamp.node_tree
    nt.nodes.remove(nt.nodes['Principled BSDF'])
    emission = nt.nodes.new('ShaderNodeEmission')
    emission.inputs['Strength'].default_value = 8.0
    nt.links.new(emission.outputs[0], nt.nodes['Material Output'].inputs['Surface'])
    _plane('panel', lamp, 1.0, (-1.0, 1.2, 2.5), (math.radians(200), 0, 0))
    _point((1.5, 0.0, 1.2), 100.0, 0.1)
    _camera((0, -5.0, 2.0), (0, 0.5, 0.8))
    return scene


def vertex_colour_cubes_sun():
    """Cubes with a colour attribute under a sun and Blender's grey world:
    13% bright on the shadowed side in a third-party file."""
    scene = _fresh()
    floor, _ = _material('ground', **{'Base Color': (0.6, 0.6, 0.6, 1)})
    _plane('ground', floor, 20)
    mat, bsdf = _material('vertex colour')
    attr = mat.node_tree.nodes.new('ShaderNodeVertexColor')
    attr.layer_name = 'Col'
    mat.node_tree.links.new(attr.outputs['Color'], bsdf.inputs['Base Color'])
    for k, x in enumerate((-1.5, 0.0, 1.5)):
        bpy.ops.mesh.primitive_cube_add(size=1.0, location=(x, 0, 0.5), rotation=(0, 0, 0.4 * k))
        cube = bpy.context.active_object
        layer = cube.data.color_attributes.new('Col', 'FLOAT_COLOR', 'CORNER')
        for i, item in enumerate(layer.data):
            item.color = ((i % 3) / 2.0, ((i // 3) % 3) / 2.0, 0.5, 1.0)
        cube.data.materials.append(mat)
    bpy.ops.object.light_add(type='SUN', rotation=(math.radians(50), 0, math.radians(30)))
    bpy.context.active_object.data.energy = 3.0
    _camera((3.5, -4.5, 2.5), (0, 0, 0.4))
    return scene


def flipped_glass():
    """A glass sphere whose faces all point inward, on a checker floor
    under an area light: Cycles treats back-facing glass by the ray's side."""
    scene = _fresh()
    floor, bsdf = _material('checker floor')
    checker = floor.node_tree.nodes.new('ShaderNodeTexChecker')
    checker.inputs['Scale'].default_value = 8.0
    floor.node_tree.links.new(checker.outputs['Color'], bsdf.inputs['Base Color'])
    _plane('floor', floor, 8)
    glass = bpy.data.materials.new('glass')
    glass.use_nodes = True
    nt = glass.node_tree
    nt.nodes.remove(nt.nodes['Principled BSDF'])
    node = nt.nodes.new('ShaderNodeBsdfGlass')
    node.inputs['Roughness'].default_value = 0.0
    nt.links.new(node.outputs[0], nt.nodes['Material Output'].inputs['Surface'])
    sphere = _sphere('flipped glass', glass, (0, 0, 0.8), 0.8)
    bpy.context.view_layer.objects.active = sphere
    bpy.ops.object.mode_set(mode='EDIT')
    bpy.ops.mesh.select_all(action='SELECT')
    bpy.ops.mesh.flip_normals()
    bpy.ops.object.mode_set(mode='OBJECT')
    bpy.ops.object.light_add(type='AREA', location=(1.0, -1.0, 3.0))
    bpy.context.active_object.data.energy = 200.0
    bpy.context.active_object.data.size = 1.0
    _camera((0, -4.0, 2.0), (0, 0, 0.6))
    return scene


SCENES = {'glossy_spheres_point_lights': glossy_spheres_point_lights, 'emissive_plane_room': emissive_plane_room,
          'vertex_colour_cubes_sun': vertex_colour_cubes_sun, 'flipped_glass': flipped_glass}


def main(folder):
    os.makedirs(folder, exist_ok=True)
    for name, build in SCENES.items():
        scene = build()
        scene.render.resolution_x, scene.render.resolution_y = 320, 180
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(os.path.join(folder, name + '.blend')))
        print("wrote", name)


if __name__ == '__main__':
    main(sys.argv[1] if len(sys.argv) > 1 else 'out/check')
