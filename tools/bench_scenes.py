"""The yardstick scenes of ``tools/bench_cycles.py``, built in the running
bpy session.

Three come from blend_scenes/*.blend; the others are built here by script
with the helpers of blend_scenes/build_scenes.py (API common to Blender 3.4 -
5.0).  ``SCENES`` maps a name to (title, loader); ``scene_key(name)`` is a
string that changes whenever the scene would change (file bytes or builder
source), used to key cached references.
"""
import hashlib
import inspect
import math
import os
import sys

import bpy
import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BLEND_DIR = os.path.join(ROOT, 'blend_scenes')
if BLEND_DIR not in sys.path:
    sys.path.insert(0, BLEND_DIR)
import build_scenes as bs  # noqa: E402


def open_blend(name):
    bpy.ops.wm.open_mainfile(filepath=os.path.join(BLEND_DIR, name + '.blend'))
    return bpy.context.scene


def principled(name, color, metallic=0.0, roughness=0.5, coat=0.0):
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    tree = material.node_tree
    node = next(n for n in tree.nodes if n.type == 'BSDF_PRINCIPLED')
    node.inputs['Base Color'].default_value = (*color, 1.0)
    node.inputs['Metallic'].default_value = metallic
    node.inputs['Roughness'].default_value = roughness
    if hasattr(node, 'distribution'):
        node.distribution = 'GGX'  # 4.0+ defaults to multiscatter GGX
    for label in ('Coat Weight', 'Clearcoat'):  # 4.x / 3.x names
        if label in node.inputs:
            node.inputs[label].default_value = coat
            break
    material.diffuse_color = (*color, 1.0)
    return material


def finish(scene, cam, target):
    bs.look_at(cam, target)
    bs.set_engine(scene)
    bpy.context.view_layer.update()
    return scene


def floor(scene, material, half=6.0, z=0.0):
    return bs.mesh_object(scene, "Floor", [(-half, -half, z), (half, -half, z), (half, half, z), (-half, half, z)],
                          [(0, 1, 2, 3)], material)


def backdrop(scene, material, y=3.0, half=6.0, height=6.0):
    return bs.mesh_object(scene, "Backdrop", [(-half, y, 0), (half, y, 0), (half, y, height), (-half, y, height)],
                          [(0, 1, 2, 3)], material)


def build_principled_spheres():
    """Three Principled spheres (dielectric, metal, coated) on a plane under a disk light."""
    scene = bs.reset()
    grey = principled("Floor", (0.5, 0.5, 0.5), roughness=0.6)
    floor(scene, grey)
    backdrop(scene, grey)
    spheres = ((-1.1, principled("Plastic", (0.8, 0.1, 0.08), roughness=0.3)),
               (0.0, principled("Gold", (1.0, 0.71, 0.29), metallic=1.0, roughness=0.2)),
               (1.1, principled("Coated", (0.1, 0.3, 0.8), roughness=0.5, coat=1.0)))
    for x, material in spheres:
        bs.uv_sphere(scene, material.name, 0.5, (x, 0.0, 0.5), material, segments=48, rings=24)
    bs.light(scene, "Disk", 'AREA', (0.5, -1.0, 3.0), 300.0, shape='DISK', size=1.0,
             rotation=(math.radians(20), 0.0, 0.0))
    cam = bs.camera(scene, (0.0, -4.5, 1.6), (0, 0, 0), lens=40.0)
    bs.world(scene, (0.02, 0.02, 0.02))
    return finish(scene, cam, (0.0, 0.0, 0.5))


def build_many_lights():
    """64 small coloured point lights over a floor, a wall and a few boxes."""
    scene = bs.reset()
    white = bs.node_material("White", 'diffuse', (0.7, 0.7, 0.7))
    floor(scene, white)
    backdrop(scene, white)
    for i, (x, y) in enumerate(((-1.2, 0.5), (0.0, -0.3), (1.3, 0.8))):
        bs.box(scene, f"Box{i}", (0.5, 0.5, 0.4 + 0.4 * i), (x, y, 0.2 + 0.2 * i), 0.3 * i, white)
    for i in range(64):
        row, col = divmod(i, 8)
        hue = i / 64.0
        color = tuple(0.55 + 0.45 * math.cos(2 * math.pi * (hue + k / 3.0)) for k in range(3))
        bs.light(scene, f"Light{i}", 'POINT', (-2.8 + 0.8 * col, -1.5 + 0.6 * row, 1.2 + 0.3 * (i % 3)),
                 4.0, color, shadow_soft_size=0.04)
    cam = bs.camera(scene, (0.0, -5.0, 2.4), (0, 0, 0), lens=32.0)
    bs.world(scene, (0.0, 0.0, 0.0))
    return finish(scene, cam, (0.0, 0.5, 0.5))


def build_emissive_meshes():
    """Emissive spheres and bars light a diffuse room; no lamps."""
    scene = bs.reset()
    white = bs.node_material("White", 'diffuse', (0.7, 0.7, 0.7))
    floor(scene, white)
    backdrop(scene, white)
    bs.box(scene, "Block", (0.6, 0.6, 0.9), (0.2, 0.4, 0.45), 0.4, white)
    glows = ((1.0, 0.5, 0.2), (0.3, 0.6, 1.0), (0.5, 1.0, 0.4))
    for i, color in enumerate(glows):
        material = bs.node_material(f"Glow{i}", 'emission', color, strength=8.0)
        bs.uv_sphere(scene, f"Glow{i}", 0.15, (-1.5 + 1.5 * i, -0.6, 0.15 + 0.5 * i), material)
        bs.box(scene, f"Bar{i}", (1.2, 0.05, 0.05), (-1.2 + 1.2 * i, 1.5, 1.6), 0.2 * i, material)
    cam = bs.camera(scene, (0.0, -4.8, 2.0), (0, 0, 0), lens=32.0)
    bs.world(scene, (0.0, 0.0, 0.0))
    return finish(scene, cam, (0.0, 0.3, 0.6))


def build_instanced():
    """128 collection instances of a 16k-triangle sphere (2.1 M triangles), sun and sky colour."""
    scene = bs.reset()
    ground = bs.node_material("Ground", 'diffuse', (0.5, 0.5, 0.5))
    orange = bs.node_material("Orange", 'diffuse', (0.8, 0.35, 0.1))
    floor(scene, ground, half=20.0)
    sources = bpy.data.collections.new("Sources")
    scene.collection.children.link(sources)
    bs.uv_sphere(scene, "Ball", 0.35, (0.0, 0.0, 0.35), orange, segments=128, rings=64, collection=sources)
    scene.view_layers[0].layer_collection.children["Sources"].exclude = True
    for i in range(128):
        row, col = divmod(i, 16)
        empty = bs.link(scene, bpy.data.objects.new(f"Ball{i}", None))
        empty.instance_type = 'COLLECTION'
        empty.instance_collection = sources
        empty.location = (-6.0 + 0.8 * col + 0.4 * (row % 2), -1.0 + 0.9 * row, 0.0)
    bs.light(scene, "Sun", 'SUN', (0, 0, 5), 3.0, (1.0, 0.95, 0.85),
             rotation=(math.radians(45), 0.0, math.radians(-35)), angle=math.radians(2))
    cam = bs.camera(scene, (0.0, -7.0, 3.2), (0, 0, 0), lens=30.0)
    bs.world(scene, (0.35, 0.5, 0.8))
    return finish(scene, cam, (0.0, 2.0, 0.0))


def hdri_path():
    folder = bpy.utils.system_resource('DATAFILES', path=os.path.join('studiolights', 'world'))
    return os.path.join(folder or '', 'courtyard.exr')


def build_hdri():
    """A diffuse and a glossy sphere on a plane under bpy's courtyard.exr."""
    scene = bs.reset()
    grey = bs.node_material("Grey", 'diffuse', (0.6, 0.6, 0.6))
    floor(scene, grey)
    bs.uv_sphere(scene, "Diffuse", 0.5, (-0.6, 0.0, 0.5), bs.node_material("Red", 'diffuse', (0.7, 0.2, 0.15)),
                 segments=48, rings=24)
    bs.uv_sphere(scene, "Glossy", 0.5, (0.6, 0.0, 0.5),
                 bs.node_material("Metal", 'glossy', (0.9, 0.9, 0.9), roughness=0.25), segments=48, rings=24)
    cam = bs.camera(scene, (0.0, -4.0, 1.4), (0, 0, 0), lens=40.0)
    _, env = bs.world_background(scene, "World", 'ShaderNodeTexEnvironment')
    env.image = bpy.data.images.load(hdri_path(), check_existing=True)
    return finish(scene, cam, (0.0, 0.0, 0.5))


def _procedural_material(name, texture, ramp=None, scale=4.0, bump=False):
    """A Principled BSDF whose base colour (and roughness) come from ``texture``
    through a colour ramp, optionally a bump from the same texture."""
    material = principled(name, (0.8, 0.8, 0.8), roughness=0.5)
    tree = material.node_tree
    bsdf = next(n for n in tree.nodes if n.type == 'BSDF_PRINCIPLED')
    coords = tree.nodes.new('ShaderNodeTexCoord')
    tex = tree.nodes.new(texture)
    if 'Scale' in tex.inputs:
        tex.inputs['Scale'].default_value = scale
    tree.links.new(coords.outputs['Object'], tex.inputs['Vector'])
    value = tex.outputs['Fac'] if 'Fac' in tex.outputs else tex.outputs['Distance']
    color_ramp = tree.nodes.new('ShaderNodeValToRGB')
    stops = color_ramp.color_ramp.elements
    low, high = ramp or ((0.1, 0.1, 0.12, 1.0), (0.8, 0.5, 0.2, 1.0))
    stops[0].color, stops[1].color = low, high
    tree.links.new(value, color_ramp.inputs['Fac'])
    tree.links.new(color_ramp.outputs['Color'], bsdf.inputs['Base Color'])
    rough = tree.nodes.new('ShaderNodeMapRange')
    rough.inputs['To Min'].default_value, rough.inputs['To Max'].default_value = 0.2, 0.8
    tree.links.new(value, rough.inputs['Value'])
    tree.links.new(rough.outputs['Result'], bsdf.inputs['Roughness'])
    if bump:
        node = tree.nodes.new('ShaderNodeBump')
        node.inputs['Strength'].default_value = 0.3
        tree.links.new(value, node.inputs['Height'])
        tree.links.new(node.outputs['Normal'], bsdf.inputs['Normal'])
    return material


def _grouped_noise_material(name):
    """Noise through a node group (Multiply + Add of its factor) into a Diffuse BSDF."""
    group = bpy.data.node_groups.new(name + "Group", 'ShaderNodeTree')
    if hasattr(group, 'interface'):   # 4.0+
        group.interface.new_socket('Fac', in_out='INPUT', socket_type='NodeSocketFloat')
        group.interface.new_socket('Fac', in_out='OUTPUT', socket_type='NodeSocketFloat')
    else:
        group.inputs.new('NodeSocketFloat', 'Fac')
        group.outputs.new('NodeSocketFloat', 'Fac')
    group_in, group_out = group.nodes.new('NodeGroupInput'), group.nodes.new('NodeGroupOutput')
    mul = group.nodes.new('ShaderNodeMath')
    mul.operation, mul.inputs[1].default_value = 'MULTIPLY', 0.7
    add = group.nodes.new('ShaderNodeMath')
    add.operation, add.inputs[1].default_value = 'ADD', 0.15
    group.links.new(group_in.outputs[0], mul.inputs[0])
    group.links.new(mul.outputs[0], add.inputs[0])
    group.links.new(add.outputs[0], group_out.inputs[0])
    material = bs.node_material(name, 'diffuse', (0.7, 0.7, 0.7))
    tree = material.node_tree
    diffuse = next(n for n in tree.nodes if n.type == 'BSDF_DIFFUSE')
    noise = tree.nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 6.0
    node = tree.nodes.new('ShaderNodeGroup')
    node.node_tree = group
    tree.links.new(noise.outputs['Fac'], node.inputs[0])
    tree.links.new(node.outputs[0], diffuse.inputs['Color'])
    return material


def build_procedural():
    """Procedural shading everywhere: Noise, Voronoi, Brick and Wave through
    colour ramps into Principled BSDFs (roughness and bump from the same
    texture), and a node group; a disk light and a dim world."""
    scene = bs.reset()
    floor(scene, _procedural_material("NoiseFloor", 'ShaderNodeTexNoise', scale=2.0, bump=True))
    backdrop(scene, _procedural_material("BrickWall", 'ShaderNodeTexBrick', scale=3.0,
                                         ramp=((0.5, 0.15, 0.1, 1.0), (0.8, 0.8, 0.75, 1.0))))
    spheres = ((-1.1, _procedural_material("Voronoi", 'ShaderNodeTexVoronoi', scale=6.0, bump=True)),
               (0.0, _procedural_material("Wave", 'ShaderNodeTexWave', scale=3.0,
                                          ramp=((0.1, 0.3, 0.6, 1.0), (0.9, 0.9, 0.9, 1.0)))),
               (1.1, _grouped_noise_material("Grouped")))
    for x, material in spheres:
        bs.uv_sphere(scene, material.name, 0.5, (x, 0.0, 0.5), material, segments=48, rings=24)
    bs.light(scene, "Disk", 'AREA', (0.5, -1.0, 3.0), 300.0, shape='DISK', size=1.0,
             rotation=(math.radians(20), 0.0, 0.0))
    cam = bs.camera(scene, (0.0, -4.5, 1.6), (0, 0, 0), lens=40.0)
    bs.world(scene, (0.05, 0.05, 0.05))
    return finish(scene, cam, (0.0, 0.0, 0.5))


def empty_material(name):
    """A node material holding only its Material Output (for volumes)."""
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    tree = material.node_tree
    for node in list(tree.nodes):
        if node.type != 'OUTPUT_MATERIAL':
            tree.nodes.remove(node)
    return material, tree


def build_fog():
    """A fog room lit by a spot (its beam): a Principled Volume cube on a
    floor before a backdrop, Cycles' default single scattering (volume
    bounces 0)."""
    scene = bs.reset()
    white = bs.node_material("White", 'diffuse', (0.6, 0.6, 0.6))
    floor(scene, white)
    backdrop(scene, white)
    fog, tree = empty_material("Fog")
    volume = tree.nodes.new('ShaderNodeVolumePrincipled')
    volume.inputs['Color'].default_value = (0.85, 0.8, 0.7, 1.0)
    volume.inputs['Density'].default_value = 0.4
    volume.inputs['Anisotropy'].default_value = 0.3
    output = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    tree.links.new(volume.outputs[0], output.inputs['Volume'])
    bs.box(scene, "Fog", (4.0, 4.0, 3.0), (0.0, 0.0, 1.52), 0.0, fog)
    bs.light(scene, "Spot", 'SPOT', (0.3, 0.2, 2.8), 600.0, rotation=(0.15, 0.0, 0.0),
             spot_size=0.6, spot_blend=0.2, shadow_soft_size=0.1)
    bs.box(scene, "Block", (0.5, 0.5, 0.7), (0.4, 0.3, 0.35), 0.4, white)
    cam = bs.camera(scene, (0.0, -5.5, 1.6), (0, 0, 0), lens=35.0)
    bs.world(scene, (0.01, 0.01, 0.01))
    scene.cycles.volume_bounces = 0
    if hasattr(scene, 'ember'):
        scene.ember.volume_bounces = 0
    return finish(scene, cam, (0.0, 0.0, 0.9))


def build_smoke():
    """A smoke cube (Principled Volume whose density is 3D noise in Object
    coordinates through a colour ramp: a heterogeneous medium, tracked
    against its majorant grid) on a floor before a backdrop, under a sun and
    a sky colour; Cycles' default single scattering (volume bounces 0)."""
    scene = bs.reset()
    white = bs.node_material("White", 'diffuse', (0.6, 0.6, 0.6))
    floor(scene, white)
    backdrop(scene, white)
    smoke, tree = empty_material("Smoke")
    coords = tree.nodes.new('ShaderNodeTexCoord')
    noise = tree.nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 2.5
    noise.inputs['Detail'].default_value = 2.0
    tree.links.new(coords.outputs['Object'], noise.inputs['Vector'])
    ramp = tree.nodes.new('ShaderNodeValToRGB')
    ramp.color_ramp.elements[0].position = 0.4
    ramp.color_ramp.elements[0].color = (0.0, 0.0, 0.0, 1.0)
    ramp.color_ramp.elements[1].position = 0.65
    ramp.color_ramp.elements[1].color = (1.0, 1.0, 1.0, 1.0)
    tree.links.new(noise.outputs['Fac'], ramp.inputs['Fac'])
    scale = tree.nodes.new('ShaderNodeMath')
    scale.operation = 'MULTIPLY'
    scale.inputs[1].default_value = 4.0
    tree.links.new(ramp.outputs['Color'], scale.inputs[0])
    volume = tree.nodes.new('ShaderNodeVolumePrincipled')
    volume.inputs['Color'].default_value = (0.8, 0.78, 0.75, 1.0)
    volume.inputs['Anisotropy'].default_value = 0.2
    tree.links.new(scale.outputs[0], volume.inputs['Density'])
    output = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    tree.links.new(volume.outputs[0], output.inputs['Volume'])
    bs.box(scene, "Smoke", (2.0, 1.6, 2.0), (0.0, 0.0, 1.1), 0.5, smoke)
    bs.light(scene, "Sun", 'SUN', (0, 0, 5), 3.0, (1.0, 0.95, 0.85),
             rotation=(math.radians(40), 0.0, math.radians(-30)), angle=math.radians(2))
    cam = bs.camera(scene, (0.0, -5.5, 2.0), (0, 0, 0), lens=35.0)
    bs.world(scene, (0.2, 0.25, 0.3))
    scene.cycles.volume_bounces = 0
    if hasattr(scene, 'ember'):
        scene.ember.volume_bounces = 0
    return finish(scene, cam, (0.0, 0.0, 1.0))


def _subsurface_material(name, color, radius, scale, method='RANDOM_WALK'):
    material = principled(name, color, roughness=0.4)
    node = next(n for n in material.node_tree.nodes if n.type == 'BSDF_PRINCIPLED')
    node.inputs['Subsurface Weight'].default_value = 1.0
    node.inputs['Subsurface Radius'].default_value = radius
    node.inputs['Subsurface Scale'].default_value = scale
    node.subsurface_method = method
    return material


def build_subsurface():
    """A random-walk subsurface sphere and torus (wax, jade) on a grey floor,
    a disk light in front and a rim light behind (thin parts lit through)."""
    scene = bs.reset()
    grey = principled("Floor", (0.5, 0.5, 0.5), roughness=0.6)
    floor(scene, grey)
    backdrop(scene, grey)
    wax = _subsurface_material("Wax", (0.85, 0.55, 0.35), (1.0, 0.35, 0.15), 0.25)
    jade = _subsurface_material("Jade", (0.35, 0.75, 0.45), (0.3, 1.0, 0.5), 0.15)
    bs.uv_sphere(scene, "Wax", 0.55, (-0.75, 0.0, 0.55), wax, segments=48, rings=24)
    bpy.ops.mesh.primitive_torus_add(major_radius=0.5, minor_radius=0.14, major_segments=48, minor_segments=16,
                                     location=(0.8, 0.1, 0.62), rotation=(math.radians(70), 0.0, math.radians(-20)))
    torus = bpy.context.active_object
    torus.name = "Jade"
    torus.data.materials.append(jade)
    for polygon in torus.data.polygons:
        polygon.use_smooth = True
    bs.light(scene, "Disk", 'AREA', (0.5, -1.0, 3.0), 250.0, shape='DISK', size=1.0,
             rotation=(math.radians(20), 0.0, 0.0))
    bs.light(scene, "Rim", 'AREA', (0.6, 1.8, 1.0), 120.0, size=0.8, rotation=(math.radians(-100), 0.0, 0.0))
    cam = bs.camera(scene, (0.0, -4.5, 1.6), (0, 0, 0), lens=40.0)
    bs.world(scene, (0.02, 0.02, 0.02))
    return finish(scene, cam, (0.0, 0.0, 0.5))


def build_glossy_lights():
    """Seven lights of five kinds (points of two sizes, a spot, a rectangle,
    a disk, a big sphere, a sun) over three glossy plates of GGX roughness
    0.05, 0.15 and 0.35, a rough metal plate and a glossy Principled floor:
    a scene no light-selection rule was tuned on (issue 25)."""
    from mathutils import Vector
    scene = bs.reset()
    floor(scene, principled("Floor", (0.35, 0.35, 0.38), roughness=0.25))
    backdrop(scene, bs.node_material("Wall", 'diffuse', (0.5, 0.5, 0.5)), y=4.0)
    eye, target = Vector((0.0, -6.0, 2.6)), Vector((0.0, 2.5, 2.4))
    plates = ((-2.1, bs.node_material("Sharp", 'glossy', (0.8, 0.8, 0.8), 0.05)),
              (-0.7, bs.node_material("Medium", 'glossy', (0.8, 0.8, 0.8), 0.15)),
              (0.7, bs.node_material("Rough", 'glossy', (0.8, 0.8, 0.8), 0.35)),
              (2.1, principled("Metal", (0.9, 0.6, 0.4), metallic=1.0, roughness=0.2)))
    for x, material in plates:
        center = Vector((x, 0.6, 0.45))
        normal = ((eye - center).normalized() + (target - center).normalized()).normalized()
        plate = bs.box(scene, material.name, (1.2, 1.2, 0.04), center, material=material)
        plate.rotation_euler = normal.to_track_quat('Z', 'Y').to_euler()
    bs.light(scene, "PointSmall", 'POINT', (-2.6, 2.4, 2.6), 40.0, (1.0, 0.4, 0.3), shadow_soft_size=0.05)
    bs.light(scene, "PointLarge", 'POINT', (1.6, 2.8, 2.0), 60.0, (0.4, 0.6, 1.0), shadow_soft_size=0.4)
    bs.light(scene, "Spot", 'SPOT', (0.0, 2.0, 3.4), 300.0, (1.0, 0.9, 0.6), shadow_soft_size=0.1,
             spot_size=math.radians(70), spot_blend=0.3, rotation=(math.radians(-30), 0.0, 0.0))
    bs.light(scene, "Rect", 'AREA', (-1.2, 3.2, 1.6), 120.0, (0.5, 1.0, 0.5), size=0.6, size_y=0.2,
             shape='RECTANGLE', rotation=(math.radians(-80), 0.0, 0.0))
    bs.light(scene, "Disk", 'AREA', (2.8, 1.5, 3.0), 150.0, (1.0, 0.6, 0.9), size=0.5, shape='DISK',
             rotation=(math.radians(-20), math.radians(30), 0.0))
    bs.light(scene, "Sphere", 'POINT', (-0.4, 3.4, 3.2), 80.0, (0.9, 0.9, 1.0), shadow_soft_size=0.7)
    bs.light(scene, "Sun", 'SUN', (0, 0, 5), 0.5, (1.0, 0.95, 0.85),
             rotation=(math.radians(50), 0.0, math.radians(20)), angle=math.radians(3))
    cam = bs.camera(scene, tuple(eye), (0, 0, 0), lens=35.0)
    bs.world(scene, (0.01, 0.01, 0.01))
    return finish(scene, cam, (0.0, 0.8, 0.7))


def _wall_with_window(scene, material, x, y0, y1, z1, window):
    """The wall x = ``x`` from y0 to y1 and floor to z1, with the
    rectangular hole ``window`` = (ya, yb, za, zb) cut out: four quads
    (below, above, left and right of the hole), facing -x (into the room)."""
    ya, yb, za, zb = window
    quads = [(y0, y1, 0.0, za), (y0, y1, zb, z1), (y0, ya, za, zb), (yb, y1, za, zb)]
    verts, faces = [], []
    for a, b, lo, hi in quads:
        k = len(verts)
        verts += [(x, a, lo), (x, a, hi), (x, b, hi), (x, b, lo)]
        faces.append((k, k + 1, k + 2, k + 3))
    return bs.mesh_object(scene, "WindowWall", verts, faces, material)


def build_interior():
    """A closed room lit only through a window in one wall by a sun and a
    sky colour outside: the camera looks away from the window, so what it
    sees is lit mostly by light that bounced (issue 25's interior).  Built
    here, tuned on by nothing."""
    scene = bs.reset()
    white = bs.node_material("Walls", 'diffuse', (0.75, 0.75, 0.72))
    room_x, room_y, room_z = 3.0, 2.5, 2.8            # half-extents in x and y, height
    inward = [  # floor, ceiling, back, front, left walls as quads facing the room
        ("Floor", [(-room_x, -room_y, 0), (room_x, -room_y, 0), (room_x, room_y, 0), (-room_x, room_y, 0)],
         principled("Wood", (0.45, 0.28, 0.15), roughness=0.35)),
        ("Ceiling", [(-room_x, -room_y, room_z), (-room_x, room_y, room_z), (room_x, room_y, room_z),
                     (room_x, -room_y, room_z)], white),
        ("Back", [(-room_x, room_y, 0), (room_x, room_y, 0), (room_x, room_y, room_z), (-room_x, room_y, room_z)],
         white),
        ("Front", [(-room_x, -room_y, 0), (-room_x, -room_y, room_z), (room_x, -room_y, room_z),
                   (room_x, -room_y, 0)], white),
        ("Left", [(-room_x, -room_y, 0), (-room_x, room_y, 0), (-room_x, room_y, room_z),
                  (-room_x, -room_y, room_z)], bs.node_material("Blue", 'diffuse', (0.25, 0.35, 0.6))),
    ]
    for name, verts, material in inward:
        bs.mesh_object(scene, name, verts, [(0, 1, 2, 3)], material)
    _wall_with_window(scene, white, room_x, -room_y, room_y, room_z, (-0.9, 0.9, 0.9, 2.2))
    bs.box(scene, "Sofa", (1.0, 2.2, 0.8), (-2.3, 0.6, 0.4), material=bs.node_material("Red", 'diffuse', (0.6, 0.12, 0.1)))
    bs.box(scene, "Table", (1.0, 1.0, 0.5), (-0.6, 0.3, 0.25), material=principled("Lacquer", (0.1, 0.1, 0.1),
                                                                                     roughness=0.15, coat=1.0))
    ball = bs.uv_sphere(scene, "Vase", 0.3, (-0.6, 0.3, 0.8), principled("Brass", (0.9, 0.7, 0.4), metallic=1.0,
                                                                           roughness=0.25), segments=32, rings=16)
    for polygon in ball.data.polygons:
        polygon.use_smooth = True
    bs.light(scene, "Sun", 'SUN', (6, 0, 6), 6.0, (1.0, 0.93, 0.8),
             rotation=(0.0, math.radians(55), math.radians(10)), angle=math.radians(1.5))
    bs.world(scene, (0.45, 0.6, 0.9), 1.0)
    cam = bs.camera(scene, (2.4, -2.0, 1.5), (0, 0, 0), lens=24.0)
    return finish(scene, cam, (-2.0, 1.2, 0.9))


def _linear_keys(obj, path, values, frames=(1, 3)):
    """``obj.path`` keyframed to ``values`` at ``frames``, interpolated linearly."""
    for frame, value in zip(frames, values):
        setattr(obj, path, value)
        obj.keyframe_insert(path, frame=frame)
    action = obj.animation_data.action
    curves = list(getattr(action, 'fcurves', None) or [])
    for layer in getattr(action, 'layers', ()):   # Blender 5's layered actions
        for strip in layer.strips:
            for bag in strip.channelbags:
                curves.extend(bag.fcurves)
    for curve in curves:
        for key in curve.keyframe_points:
            key.interpolation = 'LINEAR'


def build_motion():
    """Motion blur (shutter 0.5, centre, frame 2): a sliding cube, a
    tumbling torus, a sliding Curves object and a moving camera."""
    scene = bs.reset()
    grey = principled("Floor", (0.5, 0.5, 0.5), roughness=0.6)
    floor(scene, grey)
    cube = bs.box(scene, "Cube", (0.8, 0.8, 0.8), (-1.2, 0.0, 0.4), 0.0, principled("Red", (0.8, 0.15, 0.1)))
    _linear_keys(cube, 'location', [(-3.2, 0.0, 0.4), (0.8, 0.0, 0.4)])
    torus = bs.uv_sphere(scene, "Ball", 0.5, (1.0, 0.0, 1.0), principled("Green", (0.2, 0.7, 0.2)))
    torus.scale = (1.0, 0.5, 1.0)
    _linear_keys(torus, 'rotation_euler', [(math.radians(-60.0), 0.0, 0.0), (math.radians(180.0), 0.0, 0.0)])
    rng = np.random.default_rng(3)
    count, keys = 2000, 5
    base = np.c_[rng.uniform(-1.5, 1.5, (count, 2)) + [0.0, -1.2], np.zeros(count)]
    points = base[:, None, :] + np.arange(keys)[None, :, None] * [0.02, 0.0, 0.12]
    data = bpy.data.hair_curves.new("Grass")
    data.add_curves([keys] * count)
    data.attributes['position'].data.foreach_set('vector', points.reshape(-1).astype(np.float32))
    data.attributes.new('radius', 'FLOAT', 'POINT').data.foreach_set(
        'value', np.tile(np.linspace(0.015, 0.004, keys), count).astype(np.float32))
    data.materials.append(principled("Grass", (0.3, 0.6, 0.1)))
    grass = bpy.data.objects.new("Grass", data)
    bs.link(scene, grass)
    _linear_keys(grass, 'location', [(-0.5, 0.0, 0.0), (0.5, 0.0, 0.0)])
    bs.light(scene, "Area", 'AREA', (0.5, -0.5, 4.0), 500.0, size=2.0)
    cam = bs.camera(scene, (0.0, -5.0, 3.0), (0, 0, 0), lens=32.0)
    _linear_keys(cam, 'location', [(-0.3, -5.0, 3.0), (0.3, -5.0, 3.0)])
    bs.world(scene, (0.05, 0.05, 0.05))
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 0.5
    scene.render.motion_blur_position = 'CENTER'
    if hasattr(scene, 'cycles_curves'):
        scene.cycles_curves.shape = 'THICK'
    scene.frame_set(2)
    return finish(scene, cam, (0.0, 0.0, 0.4))


def build_hair():
    """Particle hair (2000 strands, Principled Hair Chiang, melanin 0.6) on a sphere."""
    scene = bs.reset()
    floor(scene, principled("Floor", (0.5, 0.5, 0.5), roughness=0.6))
    head = bs.uv_sphere(scene, "Head", 0.6, (0.0, 0.0, 0.7), principled("Skin", (0.6, 0.5, 0.45)),
                        segments=48, rings=24)
    hair = bpy.data.materials.new("Hair")
    hair.use_nodes = True
    nodes = hair.node_tree.nodes
    nodes.clear()
    node = nodes.new('ShaderNodeBsdfHairPrincipled')
    if hasattr(node, 'model'):
        node.model = 'CHIANG'
    node.parametrization = 'MELANIN'
    node.inputs['Melanin'].default_value = 0.6
    hair.node_tree.links.new(node.outputs[0], nodes.new('ShaderNodeOutputMaterial').inputs['Surface'])
    head.data.materials.append(hair)
    settings = head.modifiers.new("Hair", 'PARTICLE_SYSTEM').particle_system.settings
    settings.type = 'HAIR'
    settings.count = 2000
    settings.hair_length = 0.4
    settings.radius_scale = 0.01
    settings.material = 2
    bs.light(scene, "Area", 'AREA', (0.8, -1.0, 3.0), 300.0, size=1.5)
    cam = bs.camera(scene, (0.0, -3.0, 1.4), (0, 0, 0), lens=40.0)
    bs.world(scene, (0.1, 0.1, 0.12))
    if hasattr(scene, 'cycles_curves'):
        scene.cycles_curves.shape = 'THICK'
    return finish(scene, cam, (0.0, 0.0, 0.7))


SCENES = {
    'cornell': ("Cornell box, one rectangle light", lambda: open_blend('cornell')),
    'veach_mis': ("Veach MIS (4 GGX plates, 4 sphere lights)", lambda: open_blend('veach_mis')),
    'principled': ("three Principled spheres, disk light", build_principled_spheres),
    'many_lights': ("64 small lights", build_many_lights),
    'emissive': ("emissive mesh lights", build_emissive_meshes),
    'instanced': ("2.1 M instanced triangles, sun + sky colour", build_instanced),
    'hdri': ("spheres under an HDRI (courtyard.exr)", build_hdri),
    'procedural': ("procedural nodes (Noise, Voronoi, Brick, Wave, ramps, a group)", build_procedural),
    'fog': ("a fog room lit by a spot (homogeneous volume, single scattering)", build_fog),
    'smoke': ("a noise-textured smoke cube under a sun (heterogeneous volume, single scattering)", build_smoke),
    'subsurface': ("random-walk subsurface sphere and torus, front and rim light", build_subsurface),
    'glossy_lights': ("7 lights of 5 kinds over glossy plates", build_glossy_lights),
    'interior': ("a room lit through a window by sun and sky (indirect light)", build_interior),
    'motion': ("motion blur: sliding cube, tumbling ball, sliding curves, moving camera", build_motion),
    'hair': ("particle hair (2000 strands, Principled Hair Chiang) on a sphere", build_hair),
}
BLEND_FILES = {'cornell', 'veach_mis'}


def scene_key(name):
    """Changes whenever the scene would: the .blend's bytes or the builder's source."""
    digest = hashlib.sha256()
    if name in BLEND_FILES:
        with open(os.path.join(BLEND_DIR, name + '.blend'), 'rb') as handle:
            digest.update(handle.read())
    else:
        builder = SCENES[name][1]
        digest.update(inspect.getsource(builder).encode())
        digest.update(inspect.getsource(sys.modules[__name__]).encode())
        digest.update(inspect.getsource(bs).encode())
    return digest.hexdigest()[:16]
