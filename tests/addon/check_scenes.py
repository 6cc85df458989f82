"""Scenes of the kinds third-party files showed differing from Cycles
(issue 23's silent differences), built from scratch for side-by-side runs:

    .venv/bin/python -P tests/addon/check_scenes.py out/check [NAME ...]   # out/check/*.blend
    .venv/bin/python -P tools/compare_blends.py out/check --width 120 --jobs 2

Each builder makes a scene in the factory file with Cycles' default
settings (what a third-party file carries), so the comparison also covers
how Ember reads them.  Images are generated, written beside the .blend and
packed into it (each file stands alone).  Besides the issue's kinds there is
one scene per feature added since the table was first run (volumes,
subsurface, hair, points, motion blur, Hosek-Wilkie sky, UDIM, light node
trees, image alpha, displacement, Ray Portal).  ``SCENES`` maps names to
builders; each takes the folder for its images."""
import math
import os
import sys

import bpy
import numpy as np

sys.path[:0] = [os.path.dirname(os.path.abspath(__file__)), os.path.dirname(os.path.dirname(os.path.abspath(__file__)))]
from parity_scenes import particle_hair, smooth_sphere  # noqa: E402


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


def glossy_spheres_point_lights(folder=None):
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


def emissive_plane_room(folder=None):
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


def vertex_colour_cubes_sun(folder=None):
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


def flipped_glass(folder=None):
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



# ----------------------------------------------------------------------------
# Helpers for the scenes below

def _nodes_material(name):
    """A material with an empty tree but its output: (material, tree, output)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes['Principled BSDF'])
    return mat, tree, tree.nodes['Material Output']


def _shader(name, kind, **inputs):
    """A material whose surface is one ``kind`` node with ``inputs`` set."""
    mat, tree, out = _nodes_material(name)
    node = tree.nodes.new(kind)
    for key, value in inputs.items():
        node.inputs[key].default_value = value
    tree.links.new(node.outputs[0], out.inputs['Surface'])
    return mat, node


def _light(kind, location, energy, rotation=(0, 0, 0), **props):
    bpy.ops.object.light_add(type=kind, location=location, rotation=rotation)
    light = bpy.context.active_object
    light.data.energy = energy
    for key, value in props.items():
        setattr(light.data, key, value)
    return light


def _box(name, mat, location, size):
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=location)
    obj = bpy.context.active_object
    obj.name = name
    obj.scale = size
    obj.data.materials.append(mat)
    return obj


def _world(scene, colour, strength=1.0):
    world = scene.world or bpy.data.worlds.new('World')
    scene.world = world
    world.use_nodes = True
    background = world.node_tree.nodes['Background']
    background.inputs['Color'].default_value = (*colour, 1.0)
    background.inputs['Strength'].default_value = strength
    return world


def _sky(scene, sky_type, strength, **props):
    """The world's Background coloured by a Sky Texture of ``sky_type``."""
    world = _world(scene, (1, 1, 1), strength)
    tree = world.node_tree
    sky = tree.nodes.new('ShaderNodeTexSky')
    sky.sky_type = sky_type
    for key, value in props.items():
        setattr(sky, key, value)
    tree.links.new(sky.outputs['Color'], tree.nodes['Background'].inputs['Color'])
    return sky


def _packed_image(folder, name, pixels, colorspace='sRGB'):
    """``pixels`` (H, W, C in [0, 1], row 0 at the top) written as an 8-bit
    PNG into ``folder``, loaded and packed into the file."""
    from test_image_parity import write_image
    image = bpy.data.images.load(write_image(os.path.join(folder, name + '.png'), pixels))
    image.colorspace_settings.name = colorspace
    image.pack()
    return image


def _image_node(tree, image):
    node = tree.nodes.new('ShaderNodeTexImage')
    node.image = image
    return node


def _floor(size=12.0, colour=(0.5, 0.5, 0.5)):
    mat, _ = _material('floor', **{'Base Color': (*colour, 1), 'Roughness': 0.8})
    return _plane('floor', mat, size)


# ----------------------------------------------------------------------------
# Scenes of the other kinds

def _heightmap(n=256):
    """Ridged hills in [0, 1] with fine ripples (the Bump node's detail)."""
    y, x = np.mgrid[0:n, 0:n] * (2.0 * np.pi / n)
    hills = 0.5 + 0.25 * np.sin(2 * x) * np.cos(3 * y) + 0.15 * np.cos(5 * x + 2 * y)
    ripples = 0.05 * np.sin(40 * x) * np.sin(37 * y)
    return np.clip(hills + ripples, 0.0, 1.0)[..., None]


def terrain_heightmap(folder):
    """Issue 23's terrain: a grid subdivided at render to 2 million
    triangles (the file stays small), an image heightmap through a
    Displacement node (Displacement and Bump) and through a Bump node on the
    BSDF's Normal, a colour image, a sun and a Sky Texture world."""
    scene = _fresh()
    height = _packed_image(folder, 'terrain_height', _heightmap(), 'Non-Color')
    colour = np.concatenate([0.25 + 0.3 * _heightmap(), 0.35 + 0.2 * _heightmap(), 0.15 + 0 * _heightmap()], axis=2)
    base = _packed_image(folder, 'terrain_colour', colour)
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=64, y_subdivisions=64, size=10.0)
    grid = bpy.context.active_object
    grid.name = 'terrain'
    subsurf = grid.modifiers.new('subdivide', 'SUBSURF')
    subsurf.subdivision_type = 'SIMPLE'
    subsurf.levels, subsurf.render_levels = 1, 4        # 63 * 16 squared quads: 2.03 M triangles
    mat, bsdf = _material('terrain', **{'Roughness': 0.7})
    mat.displacement_method = 'BOTH'
    tree = mat.node_tree
    tree.links.new(_image_node(tree, base).outputs['Color'], bsdf.inputs['Base Color'])
    displacement = tree.nodes.new('ShaderNodeDisplacement')
    displacement.inputs['Scale'].default_value = 0.8
    tree.links.new(_image_node(tree, height).outputs['Color'], displacement.inputs['Height'])
    tree.links.new(displacement.outputs[0], tree.nodes['Material Output'].inputs['Displacement'])
    bump = tree.nodes.new('ShaderNodeBump')
    bump.inputs['Strength'].default_value = 0.5
    tree.links.new(_image_node(tree, height).outputs['Color'], bump.inputs['Height'])
    tree.links.new(bump.outputs['Normal'], bsdf.inputs['Normal'])
    grid.data.materials.append(mat)
    _light('SUN', (0, 0, 5), 3.0, (math.radians(60), 0, math.radians(-40)), angle=math.radians(1.0))
    _sky(scene, 'SINGLE_SCATTERING', 0.3, sun_elevation=math.radians(30), sun_rotation=math.radians(220))
    _camera((0, -7.5, 3.0), (0, 0, 0), lens=30.0)
    return scene


def office_interior(folder=None):
    """An office lit only through two windows by a sun and a sky colour:
    desks, a glossy floor, the camera facing along the window wall (most of
    what it sees is lit by bounced light)."""
    scene = _fresh()
    white, _ = _material('walls', **{'Base Color': (0.75, 0.75, 0.72, 1), 'Roughness': 0.9})
    floor, _ = _material('floor', **{'Base Color': (0.35, 0.3, 0.25, 1), 'Roughness': 0.35})
    wood, _ = _material('desk', **{'Base Color': (0.5, 0.32, 0.18, 1), 'Roughness': 0.5})
    hx, hy, hz = 4.0, 3.0, 2.8
    _box('floor', floor, (0, 0, -0.05), (2 * hx, 2 * hy, 0.1))
    _box('ceiling', white, (0, 0, hz + 0.05), (2 * hx, 2 * hy, 0.1))
    _box('back', white, (0, hy + 0.05, hz / 2), (2 * hx, 0.1, hz))
    _box('front', white, (0, -hy - 0.05, hz / 2), (2 * hx, 0.1, hz))
    _box('left', white, (-hx - 0.05, 0, hz / 2), (0.1, 2 * hy, hz))
    # The window wall at x = hx: two openings 1.4 m wide from 0.9 m to 2.2 m.
    x = hx + 0.05
    _box('sill', white, (x, 0, 0.45), (0.1, 2 * hy, 0.9))
    _box('lintel', white, (x, 0, (2.2 + hz) / 2), (0.1, 2 * hy, hz - 2.2))
    for name, y0, y1 in (('pier0', -hy, -2.0), ('pier1', -0.6, 0.6), ('pier2', 2.0, hy)):
        _box(name, white, (x, (y0 + y1) / 2, 1.55), (0.1, y1 - y0, 1.3))
    for k, (dx, dy) in enumerate(((-1.5, -1.2), (1.2, -1.2), (-1.5, 1.3), (1.2, 1.3))):
        _box(f'desk{k}', wood, (dx, dy, 0.72), (1.4, 0.8, 0.05))
        _box(f'desk{k}_base', wood, (dx, dy, 0.36), (0.1, 0.6, 0.7))
    _light('SUN', (8, 0, 6), 5.0, (0, math.radians(55), math.radians(15)), angle=math.radians(1.0))
    _world(scene, (0.45, 0.6, 0.9), 1.0)
    _camera((-3.4, -2.5, 1.6), (1.5, 1.0, 0.9), lens=22.0)
    return scene


# ----------------------------------------------------------------------------
# One scene per feature added since the table was first run

def hosek_sky(folder=None):
    """A Hosek-Wilkie sky (its sun low, out of view) over diffuse and
    glossy spheres on a floor, the sky seen above the horizon."""
    scene = _fresh()
    _floor(30.0)
    red, _ = _material('red', **{'Base Color': (0.8, 0.2, 0.1, 1), 'Roughness': 0.5})
    metal, _ = _material('metal', **{'Base Color': (0.9, 0.9, 0.9, 1), 'Metallic': 1.0, 'Roughness': 0.2})
    _sphere('red', red, (-0.7, 0, 0.5))
    _sphere('metal', metal, (0.7, 0.3, 0.5))
    from mathutils import Vector
    _sky(scene, 'HOSEK_WILKIE', 1.0, turbidity=3.0, ground_albedo=0.3,
         sun_direction=Vector((-0.5, 0.7, 0.35)).normalized())
    _camera((0, -4.0, 1.0), (0, 0, 0.7), lens=28.0)
    return scene


def udim_image(folder):
    """A plane unwrapped over four UDIM tiles (1001, 1002, 1011, 1012:
    8-bit tiles of different checkers, one grey), lit by an area light."""
    from test_image_parity import checker, tiled_image
    scene = _fresh()
    tiles = {'1001': (checker(4, (0.85, 0.3, 0.1), (0.1, 0.4, 0.8)), True),
             '1002': (checker(8, (0.9, 0.9, 0.2), (0.2, 0.2, 0.2)), True),
             '1011': (checker(2, (0.9,), (0.25,)), True),
             '1012': (checker(6, (0.2, 0.7, 0.3), (0.7, 0.2, 0.6)), True)}
    image = tiled_image(folder, 'udim.<UDIM>.png', tiles)
    image.pack()
    mat, bsdf = _material('udim', **{'Roughness': 0.6})
    mat.node_tree.links.new(_image_node(mat.node_tree, image).outputs['Color'], bsdf.inputs['Base Color'])
    plane = _plane('udim plane', mat, 4.0)
    uv = plane.data.uv_layers.active.data
    for loop in plane.data.loops:           # the unit square's UVs, doubled: four tiles
        u, v = uv[loop.index].uv
        uv[loop.index].uv = (2.0 * u, 2.0 * v)
    _light('AREA', (0.5, -1.0, 3.0), 300.0, size=2.0)
    _world(scene, (0.05, 0.05, 0.05))
    _camera((0, -3.2, 3.5), (0, 0, 0), lens=35.0)
    return scene


def point_light_falloff(folder=None):
    """Point lights whose Emission Strength comes through a Light Falloff
    node tree (Linear, and Quadratic with Smooth), over a floor and a wall."""
    scene = _fresh()
    floor = _floor(10.0, (0.6, 0.6, 0.6))
    _plane('wall', floor.data.materials[0], 10.0, (0, 2.0, 2.0), (math.pi / 2, 0, 0))
    for location, output, strength, smooth in (((-1.2, 0.5, 0.6), 'Linear', 0.6, 0.0),
                                               ((1.2, 0.5, 0.6), 'Quadratic', 1.0, 0.5)):
        light = _light('POINT', location, 100.0, shadow_soft_size=0.1)
        light.data.use_nodes = True
        tree = light.data.node_tree
        emission = next(n for n in tree.nodes if n.type == 'EMISSION')
        node = tree.nodes.new('ShaderNodeLightFalloff')
        node.inputs['Strength'].default_value = strength
        node.inputs['Smooth'].default_value = smooth
        tree.links.new(node.outputs[output], emission.inputs['Strength'])
    blue, _ = _material('ball', **{'Base Color': (0.2, 0.3, 0.8, 1), 'Roughness': 0.4})
    _sphere('ball', blue, (0, 0.2, 0.4), 0.4)
    _camera((0, -4.5, 2.0), (0, 0.5, 0.6))
    return scene


def _leaf(n=64):
    """RGBA: a green disc of leaves (alpha 1) with soft edges, alpha 0 outside."""
    y, x = (np.mgrid[0:n, 0:n] + 0.5) / n * 2.0 - 1.0
    r = np.hypot(x, y) * (1.0 + 0.25 * np.cos(6 * np.arctan2(y, x)))
    alpha = np.clip((1.0 - r) * 6.0, 0.0, 1.0)
    img = np.zeros((n, n, 4))
    img[..., 0], img[..., 1], img[..., 2] = 0.2 + 0.3 * (1 - r), 0.6, 0.1
    img[..., 3] = alpha
    return img


def image_alpha_plane(folder):
    """Planes textured by an RGBA image whose alpha drives the Principled
    BSDF's Alpha (cut-out leaves), one in front of the other, over a floor."""
    scene = _fresh()
    _floor(12.0)
    leaf = _packed_image(folder, 'leaf', _leaf())
    mat, bsdf = _material('leaf')
    node = _image_node(mat.node_tree, leaf)
    mat.node_tree.links.new(node.outputs['Color'], bsdf.inputs['Base Color'])
    mat.node_tree.links.new(node.outputs['Alpha'], bsdf.inputs['Alpha'])
    for k, (x, y) in enumerate(((-0.4, 0.0), (0.5, 0.8), (0.1, -0.8))):
        _plane(f'leaf{k}', mat, 1.6, (x, y, 0.9), (math.pi / 2, 0, 0.3 * k))
    _light('SUN', (0, 0, 5), 3.0, (math.radians(40), 0, math.radians(20)))
    _world(scene, (0.3, 0.35, 0.4))
    _camera((0.5, -4.0, 1.4), (0, 0, 0.8))
    return scene


def glass_absorption(folder=None):
    """A glass sphere filled with Volume Absorption (a tinted solid glass)
    and a glass cube, on a checker floor under an area light."""
    scene = _fresh()
    floor, bsdf = _material('checker floor')
    checker = floor.node_tree.nodes.new('ShaderNodeTexChecker')
    checker.inputs['Scale'].default_value = 10.0
    floor.node_tree.links.new(checker.outputs['Color'], bsdf.inputs['Base Color'])
    _plane('floor', floor, 10)
    mat, _ = _shader('tinted glass', 'ShaderNodeBsdfGlass', Roughness=0.0, IOR=1.5)
    tree = mat.node_tree
    absorb = tree.nodes.new('ShaderNodeVolumeAbsorption')
    absorb.inputs['Color'].default_value = (0.2, 0.6, 0.9, 1)
    absorb.inputs['Density'].default_value = 1.5
    tree.links.new(absorb.outputs[0], tree.nodes['Material Output'].inputs['Volume'])
    _sphere('tinted', mat, (-0.6, 0, 0.6), 0.6)
    clear, _ = _shader('clear glass', 'ShaderNodeBsdfGlass', Roughness=0.1, IOR=1.45)
    # 2 mm above the floor: resting on it exactly is coincident_faces' case.
    _box('glass cube', clear, (0.8, 0.3, 0.402), (0.8, 0.8, 0.8))
    _light('AREA', (1.0, -1.0, 3.0), 250.0, size=1.0)
    _world(scene, (0.05, 0.05, 0.05))
    _camera((0, -4.0, 2.0), (0, 0, 0.5))
    return scene


def _fog(location, size):
    fog, tree, out = _nodes_material('fog')
    volume = tree.nodes.new('ShaderNodeVolumePrincipled')
    volume.inputs['Density'].default_value = 0.15
    volume.inputs['Anisotropy'].default_value = 0.3
    tree.links.new(volume.outputs[0], out.inputs['Volume'])
    return _box('fog', fog, location, size)


def fog_spot(folder=None):
    """A spot light cone through a room-sized box of homogeneous fog
    (Principled Volume, no surface) with objects in it; the box reaches
    below the floor (coincident_faces has its bottom on the floor)."""
    scene = _fresh()
    _floor(12.0)
    _fog((0, 0, 1.4), (6, 6, 3.2))
    red, _ = _material('red', **{'Base Color': (0.8, 0.2, 0.1, 1), 'Roughness': 0.5})
    _sphere('ball', red, (0.3, 0.5, 0.5))
    _box('block', red, (-1.0, 0.8, 0.4), (0.6, 0.6, 0.8))
    _light('SPOT', (1.0, -0.5, 2.8), 600.0, (math.radians(20), math.radians(15), 0),
           spot_size=math.radians(40), spot_blend=0.2, shadow_soft_size=0.05)
    _world(scene, (0.0, 0.0, 0.0))
    _camera((0, -5.0, 1.6), (0, 0.5, 1.0))
    return scene


def coincident_faces(folder=None):
    """What scenes often do and Ember and Cycles resolve differently: a
    fog box's bottom face and a glass cube's lying exactly in the floor's
    plane.  Here Cycles renders the floor under both as if absent (black
    under the fog, dark under the cube) and Ember finds it; which face a
    ray meets there is rounding and BVH order in both (Cycles flips with
    the floor's size), so the export names the pairs: docs/real_scenes.md."""
    scene = fog_spot()
    fog = bpy.data.objects['fog']
    fog.location.z, fog.scale.z = 1.5, 3.0
    clear, _ = _shader('clear glass', 'ShaderNodeBsdfGlass', Roughness=0.1, IOR=1.45)
    _box('glass cube', clear, (1.1, -0.3, 0.3), (0.6, 0.6, 0.6))
    return scene


def world_volume(folder=None):
    """A world volume (Volume Scatter, density 0.05, a black background:
    a sun's light would not get through the unbounded medium) around
    spheres lit by a point and a spot light."""
    scene = _fresh()
    _floor(40.0)
    world = _world(scene, (0.0, 0.0, 0.0))
    tree = world.node_tree
    scatter = tree.nodes.new('ShaderNodeVolumeScatter')
    scatter.inputs['Density'].default_value = 0.05
    tree.links.new(scatter.outputs[0], tree.nodes['World Output'].inputs['Volume'])
    grey, _ = _material('grey', **{'Base Color': (0.7, 0.7, 0.7, 1)})
    for k in range(4):
        _sphere(f'ball{k}', grey, (-2.0 + 1.3 * k, 1.5 * k, 0.5))
    _point((-1.0, 1.0, 2.0), 400.0, 0.1)
    _light('SPOT', (1.5, 3.0, 3.0), 800.0, (math.radians(30), 0, math.radians(150)),
           spot_size=math.radians(35), shadow_soft_size=0.05)
    _camera((0, -5.0, 1.5), (0, 2.0, 0.5))
    return scene


def subsurface(folder=None):
    """Principled subsurface (random walk, skin-like radii) on a sphere and
    a Suzanne, lit from behind-left by an area light and a point light."""
    scene = _fresh()
    _floor(12.0)
    skin, _ = _material('skin', **{'Base Color': (0.8, 0.55, 0.45, 1), 'Subsurface Weight': 1.0,
                                   'Subsurface Radius': (1.0, 0.4, 0.2), 'Subsurface Scale': 0.2,
                                   'Roughness': 0.4})
    _sphere('ball', skin, (-0.8, 0, 0.5))
    bpy.ops.mesh.primitive_monkey_add(size=1.0, location=(0.7, 0, 0.55), rotation=(0, 0, math.radians(-20)))
    monkey = bpy.context.active_object
    monkey.modifiers.new('smooth', 'SUBSURF').render_levels = 2
    bpy.ops.object.shade_smooth()
    monkey.data.materials.append(skin)
    _light('AREA', (-1.5, 1.5, 2.5), 200.0, size=1.0)
    _point((1.5, -1.5, 1.5), 60.0, 0.1)
    _camera((0, -3.5, 1.2), (0, 0, 0.5))
    return scene


def hair(folder=None):
    """A sphere with 3,000 particle-hair strands (Principled Hair, Chiang,
    melanin) under an area light and Blender's grey world."""
    scene = _fresh()
    _floor(12.0)
    mat, node = _shader('hair', 'ShaderNodeBsdfHairPrincipled')
    node.parametrization = 'MELANIN'
    node.inputs['Melanin'].default_value = 0.5
    node.inputs['Roughness'].default_value = 0.3
    skin, _ = _material('scalp', **{'Base Color': (0.6, 0.5, 0.45, 1)})
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0, 0, 0.6), segments=32, ring_count=16)
    obj = bpy.context.active_object
    obj.data.materials.append(skin)
    obj.data.materials.append(mat)
    particle_hair(obj, 3000)
    _light('AREA', (1.0, -1.5, 2.5), 150.0, size=1.0)
    _camera((0, -3.0, 1.2), (0, 0, 0.6))
    return scene


def hair_3d_curves(folder=None):
    """``hair`` with Render > Curves > Shape at 3D Curves (the factory
    file's is Ribbons)."""
    scene = hair()
    scene.cycles_curves.shape = 'THICK'
    return scene


def point_cloud(folder=None):
    """20,000 points (geometry nodes' Points from a mesh's vertices) in a
    ball, radius 0.01-0.03, coloured by an attribute, under a sun."""
    scene = _fresh()
    _floor(12.0)
    rng = np.random.default_rng(7)
    n = 20_000
    dirs = rng.normal(size=(n, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    positions = dirs * (0.7 * rng.random(n) ** (1 / 3))[:, None] + (0, 0, 0.8)
    radii = 0.01 + 0.02 * rng.random(n)
    colours = np.column_stack([rng.random(n), 0.5 + 0.5 * rng.random(n), 0.3 * np.ones(n), np.ones(n)])
    from test_points_parity import point_object
    mat, tree, out = _nodes_material('points')
    bsdf = tree.nodes.new('ShaderNodeBsdfPrincipled')
    attr = tree.nodes.new('ShaderNodeAttribute')
    attr.attribute_name = 'col'
    tree.links.new(attr.outputs['Color'], bsdf.inputs['Base Color'])
    tree.links.new(bsdf.outputs[0], out.inputs['Surface'])
    point_object('points', positions, radii, colours, mat)
    _light('SUN', (0, 0, 5), 3.0, (math.radians(40), 0, math.radians(30)))
    _camera((0, -3.0, 1.3), (0, 0, 0.7))
    return scene


def _keys(obj, path, values, frames=(1, 2)):
    for frame, value in zip(frames, values):
        setattr(obj, path, value)
        obj.keyframe_insert(path, frame=frame)


def motion_blur(folder=None):
    """Motion blur on (shutter 0.5, centred): a cube sliding along x and a
    sphere spinning about z, at frame 1, under a sun."""
    scene = _fresh()
    _floor(12.0)
    red, _ = _material('red', **{'Base Color': (0.8, 0.2, 0.1, 1)})
    cube = _box('cube', red, (-1.0, 0, 0.4), (0.8, 0.8, 0.8))
    _keys(cube, 'location', [(-1.6, 0, 0.4), (-0.4, 0, 0.4)], frames=(0, 2))
    checker, bsdf = _material('checker')
    tex = checker.node_tree.nodes.new('ShaderNodeTexChecker')
    tex.inputs['Scale'].default_value = 6.0
    checker.node_tree.links.new(tex.outputs['Color'], bsdf.inputs['Base Color'])
    ball = _sphere('ball', checker, (1.0, 0, 0.6), 0.6)
    _keys(ball, 'rotation_euler', [(0, 0, 0), (0, 0, math.radians(40))], frames=(0, 2))
    scene.frame_set(1)
    scene.render.use_motion_blur = True
    _light('SUN', (0, 0, 5), 3.0, (math.radians(40), 0, math.radians(30)))
    _camera((0, -4.0, 1.5), (0, 0, 0.5))
    return scene


def ray_portal(folder=None):
    """A Ray Portal plane in a wall sending rays out of a far-away second
    room (a coloured box) while the wall around it is diffuse."""
    scene = _fresh()
    _floor(12.0)
    wall, _ = _material('wall', **{'Base Color': (0.7, 0.7, 0.7, 1)})
    _plane('wall', wall, 6.0, (0, 1.5, 3.0), (math.pi / 2, 0, 0))
    mat, node = _shader('portal', 'ShaderNodeBsdfRayPortal')
    tree = mat.node_tree
    position = tree.nodes.new('ShaderNodeNewGeometry')
    add = tree.nodes.new('ShaderNodeVectorMath')
    add.inputs[1].default_value = (0.0, 0.0, 20.0)
    tree.links.new(position.outputs['Position'], add.inputs[0])
    tree.links.new(add.outputs[0], node.inputs['Position'])
    _plane('portal', mat, 1.5, (0, 1.45, 1.2), (math.pi / 2, 0, 0))
    green, _ = _material('far room', **{'Base Color': (0.2, 0.7, 0.3, 1), 'Emission Color': (0.2, 0.7, 0.3, 1),
                                        'Emission Strength': 1.0})
    _box('far room', green, (0, 4.0, 21.0), (4, 4, 4))
    _point((0, -1.0, 2.5), 200.0, 0.1)
    _camera((0, -3.5, 1.4), (0, 1.5, 1.1))
    return scene


SCENES = {'glossy_spheres_point_lights': glossy_spheres_point_lights, 'emissive_plane_room': emissive_plane_room,
          'vertex_colour_cubes_sun': vertex_colour_cubes_sun, 'flipped_glass': flipped_glass,
          'terrain_heightmap': terrain_heightmap, 'office_interior': office_interior,
          'hosek_sky': hosek_sky, 'udim_image': udim_image, 'point_light_falloff': point_light_falloff,
          'image_alpha_plane': image_alpha_plane, 'glass_absorption': glass_absorption, 'fog_spot': fog_spot,
          'coincident_faces': coincident_faces,
          'world_volume': world_volume, 'subsurface': subsurface, 'hair': hair,
          'hair_3d_curves': hair_3d_curves, 'point_cloud': point_cloud,
          'motion_blur': motion_blur, 'ray_portal': ray_portal}


def main(folder, names=()):
    os.makedirs(folder, exist_ok=True)
    for name, build in SCENES.items():
        if names and name not in names:
            continue
        scene = build(os.path.abspath(folder))
        scene.render.resolution_x, scene.render.resolution_y = 320, 180
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(os.path.join(folder, name + '.blend')))
        print("wrote", name)


if __name__ == '__main__':
    main(sys.argv[1] if len(sys.argv) > 1 else 'out/check', sys.argv[2:])
