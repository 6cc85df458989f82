"""A seeded corpus of hostile Blender scenes rendered through the Ember add-on.

Every case starts from Blender's factory scene (cube, point light, camera),
breaks it in one way the issue lists (NaN vertices, zero scales, NaN light
strength, corrupt images, cyclic node groups, 10^6 instances, ...), renders it
with ``bpy.ops.render.render()`` and classifies the outcome:

* ``rendered``: no error, every pass the engine returned is finite and the
  add-on did not have to replace a non-finite pixel;
* ``refused``: the render stopped with one error that is a sentence for the
  user (no bare exception type) and names the object or material at fault;
* ``FAILED``: anything else (an exception type leaking out, an error that
  does not name the culprit, NaN or Inf in a pass, a crashed process).

Cases marked ``risky`` (huge counts, huge frames) run in a subprocess so that
a crash or a memory blow-up fails one case, not the test run.

    python -P tests/addon/fuzz_scenes.py                 # CI corpus, prints the tally
    python -P tests/addon/fuzz_scenes.py --random 200    # plus 200 random combinations
    python -P tests/addon/fuzz_scenes.py --full          # on-demand sizes (16k textures, 10^6 instances)
    python -P tests/addon/fuzz_scenes.py --case nan_vertices --seed 3

EMBER_FUZZ_RANDOM and EMBER_FUZZ_FULL=1 do the same for the pytest run.
"""
import json
import math
import os
import struct
import subprocess
import sys
import tempfile
import time
import zlib

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
NAN, INF = float('nan'), float('inf')
HOSTILE_FLOATS = (NAN, INF, -INF, 1e30, -1e30)


# ----------------------------------------------------------------------------
# building blocks

def _bpy():
    import bpy
    return bpy


def new_mesh_object(name, verts, faces):
    """An object `name` with mesh data `name + '_mesh'` (so messages can be
    checked for the object's name, not only its data's)."""
    bpy = _bpy()
    mesh = bpy.data.meshes.new(name + '_mesh')
    mesh.from_pydata([tuple(v) for v in verts], [], [tuple(f) for f in faces])
    obj = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(obj)
    return obj


CUBE_VERTS = [(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
CUBE_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def cube(scene):
    """The factory cube (made again if an earlier hazard removed it)."""
    if 'Cube' not in scene.objects:
        obj = new_mesh_object('Cube', CUBE_VERTS, CUBE_FACES)
        obj.data.name = 'Cube'
    return scene.objects['Cube']


def point_light(scene):
    return scene.objects['Light']


def set_vertices(obj, coords):
    obj.data.vertices.foreach_set('co', np.asarray(coords, np.float32).ravel())
    obj.data.update()


def material_on(obj, name):
    bpy = _bpy()
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    return mat


def principled(mat):
    return next(n for n in mat.node_tree.nodes if n.type == 'BSDF_PRINCIPLED')


def image_material(obj, image, name='FuzzImageMat'):
    mat = material_on(obj, name)
    tree = mat.node_tree
    node = tree.nodes.new('ShaderNodeTexImage')
    node.image = image
    tree.links.new(node.outputs['Color'], principled(mat).inputs['Base Color'])
    return mat


def file_image(path, name):
    """An image data block pointing at `path` without Blender loading it
    (a missing or corrupt file must reach the exporter as it is)."""
    bpy = _bpy()
    image = bpy.data.images.new(name, 4, 4)
    image.source = 'FILE'
    image.filepath = path
    return image


def write_png(path, width, height, rng):
    raw = b''.join(b'\x00' + rng.integers(0, 256, width * 3, dtype=np.uint8).tobytes()
                   for _ in range(height))

    def chunk(kind, data):
        return (struct.pack('>I', len(data)) + kind + data
                + struct.pack('>I', zlib.crc32(kind + data) & 0xffffffff))
    header = struct.pack('>IIBBBBB', width, height, 8, 2, 0, 0, 0)
    with open(path, 'wb') as f:
        f.write(b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', header) + chunk(b'IDAT', zlib.compress(raw, 1))
                + chunk(b'IEND', b''))


def write_with_blender(path, width, height, file_format, rng):
    """A valid JPEG/EXR/PNG written by Blender itself (random pixels)."""
    bpy = _bpy()
    image = bpy.data.images.new('fuzz_writer', width, height, float_buffer=file_format == 'OPEN_EXR')
    image.pixels.foreach_set(rng.random(width * height * 4).astype(np.float32))
    image.filepath_raw = path
    image.file_format = file_format
    image.save()
    bpy.data.images.remove(image)


def damage(path, how, rng):
    data = open(path, 'rb').read()
    if how == 'truncated':
        data = data[:max(8, len(data) // int(rng.integers(2, 6)))]
    elif how == 'corrupt':
        buf = bytearray(data)
        lo = min(len(buf) - 1, 16)
        for i in rng.integers(lo, len(buf), max(8, len(buf) // 20)):
            buf[i] = int(rng.integers(0, 256))
        data = bytes(buf)
    elif how == 'garbage':
        data = rng.integers(0, 256, 4096, dtype=np.uint8).tobytes()
    with open(path, 'wb') as f:
        f.write(data)


# ----------------------------------------------------------------------------
# the hazards: each takes (scene, rng, folder) and returns the names an error
# message may mention (the object, data block or material at fault)

def nan_vertices(scene, rng, folder):
    obj = new_mesh_object('FuzzNaN', [(0, 0, 2), (1, 0, 2), (0, 1, 2), (1, 1, 2)], [(0, 1, 3, 2)])
    coords = np.array([v.co for v in obj.data.vertices], np.float32)
    bad = rng.choice(len(coords), int(rng.integers(1, len(coords) + 1)), replace=False)
    coords[bad, rng.integers(0, 3, len(bad))] = rng.choice([NAN, INF, -INF], len(bad))
    set_vertices(obj, coords)
    return ['FuzzNaN']


def huge_vertices(scene, rng, folder):
    obj = cube(scene)
    coords = np.array([v.co for v in obj.data.vertices], np.float32)
    coords[rng.integers(0, len(coords))] = rng.choice([1e30, -1e30], 3)
    set_vertices(obj, coords)
    return ['Cube']


def hostile_displacement(scene, rng, folder):
    """True displacement (engine/displacement.py) whose scale is NaN,
    infinite or huge: finite geometry or a named refusal."""
    obj = cube(scene)
    mat = material_on(obj, 'FuzzDisplaceMat')
    mat.displacement_method = str(rng.choice(['DISPLACEMENT', 'BOTH']))
    tree = mat.node_tree
    noise = tree.nodes.new('ShaderNodeTexNoise')
    disp = tree.nodes.new('ShaderNodeDisplacement')
    disp.space = str(rng.choice(['OBJECT', 'WORLD']))
    disp.inputs['Scale'].default_value = float(rng.choice([NAN, INF, -INF, 1e30, -1e20, 1e10, 3.0]))
    tree.links.new(noise.outputs['Fac'], disp.inputs['Height'])
    out = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    tree.links.new(disp.outputs['Displacement'], out.inputs['Displacement'])
    return ['Cube', 'FuzzDisplaceMat']


def degenerate_triangles(scene, rng, folder):
    verts = [(0, 0, 1.5), (1, 0, 1.5), (0, 1, 1.5), (2, 0, 1.5), (0, 0, 1.5)]
    faces = [(0, 1, 2), (0, 1, 3), (0, 1, 2), (0, 4, 1), (1, 2, 0)]  # collinear, duplicate, repeated vertex
    new_mesh_object('FuzzDegenerate', verts, faces)
    tiny = new_mesh_object('FuzzTiny', [(0, 0, 0), (1e-30, 0, 0), (0, 1e-30, 0)], [(0, 1, 2)])
    tiny.location = (0.3, 0.2, 1.2)
    return ['FuzzDegenerate', 'FuzzTiny']


def empty_meshes(scene, rng, folder):
    new_mesh_object('FuzzEmpty', [], [])
    new_mesh_object('FuzzPoints', [(0, 0, 0), (1, 1, 1)], [])
    bpy = _bpy()
    mesh = bpy.data.meshes.new('FuzzEdges_mesh')
    mesh.from_pydata([(0, 0, 0), (1, 0, 0)], [(0, 1)], [])
    obj = bpy.data.objects.new('FuzzEdges', mesh)
    scene.collection.objects.link(obj)
    if rng.random() < 0.5:
        for o in list(scene.objects):
            if o.type == 'MESH' and o.name == 'Cube':
                bpy.data.objects.remove(o)
    return ['FuzzEmpty', 'FuzzPoints', 'FuzzEdges']


def nan_transform(scene, rng, folder):
    obj = cube(scene)
    what = int(rng.integers(0, 3))
    value = float(rng.choice([NAN, INF, -INF]))
    if what == 0:
        obj.location = (value, 0.0, 0.0)
    elif what == 1:
        obj.scale = (1.0, value, 1.0)
    else:
        obj.rotation_euler = (0.0, 0.0, value)
    light = point_light(scene)
    if rng.random() < 0.5:
        light.location = (0.0, value, 4.0)
    return ['Cube', 'Light']


def object_scales(scene, rng, folder):
    obj = cube(scene)
    scale = [float(rng.choice([0.0, -1.0, -0.5, 1.0, 1e-30])) for _ in range(3)]
    if rng.random() < 0.5:
        scale[int(rng.integers(0, 3))] = 0.0
    obj.scale = scale
    light = point_light(scene)
    light.scale = (float(rng.choice([0.0, -1.0, 1.0])),) * 3
    return ['Cube', 'Light']


def _light(scene, kind, name, location=(0, 0, 3)):
    bpy = _bpy()
    data = bpy.data.lights.new(name + '_data', kind)
    obj = bpy.data.objects.new(name, data)
    obj.location = location
    scene.collection.objects.link(obj)
    return obj


def light_values(scene, rng, folder):
    names = []
    for kind in ('POINT', 'SPOT', 'AREA', 'SUN'):
        obj = _light(scene, kind, 'Fuzz' + kind.title())
        data = obj.data
        data.energy = float(rng.choice([0.0, -10.0, NAN, INF, 1e30, 100.0]))
        if rng.random() < 0.5:
            data.color = tuple(float(rng.choice([NAN, 0.5, -1.0, INF])) for _ in range(3))
        if kind in ('POINT', 'SPOT'):
            data.shadow_soft_size = float(rng.choice([0.0, NAN, 1e30, 0.1]))
        if kind == 'AREA':
            data.shape = str(rng.choice(['SQUARE', 'RECTANGLE', 'DISK', 'ELLIPSE']))
            data.size = float(rng.choice([0.0, NAN, 1.0]))
            data.size_y = float(rng.choice([0.0, 1e-30, 1.0]))
        if kind == 'SUN':
            data.angle = float(rng.choice([0.0, math.pi, NAN]))
        names.append(obj.name)
    return names


def spot_angles(scene, rng, folder):
    names = []
    for k, size in enumerate((0.0, math.pi, float(rng.uniform(0, math.pi)))):
        obj = _light(scene, 'SPOT', f'FuzzSpot{k}', (0.5 * k, 0, 3))
        obj.data.spot_size = size
        obj.data.spot_blend = float(rng.choice([0.0, 1.0, 0.5]))
        obj.data.energy = 500.0
        names.append(obj.name)
    return names


def huge_emission(scene, rng, folder):
    mat = material_on(cube(scene), 'FuzzEmissive')
    node = principled(mat)
    node.inputs['Emission Color'].default_value = (1, 1, 1, 1)
    node.inputs['Emission Strength'].default_value = float(rng.choice([1e30, 3.4e38, INF, NAN]))
    return ['Cube', 'FuzzEmissive']


def camera_inside(scene, rng, folder):
    scene.camera.location = tuple(float(v) for v in rng.uniform(-0.5, 0.5, 3))
    return ['Camera']


def camera_values(scene, rng, folder):
    cam = scene.camera.data
    choice = int(rng.integers(0, 4))
    if choice == 0:
        cam.clip_start, cam.clip_end = 10.0, 1.0
    elif choice == 1:
        cam.sensor_width = 0.0
        cam.sensor_fit = str(rng.choice(['AUTO', 'HORIZONTAL']))
    elif choice == 2:
        cam.lens = float(rng.choice([0.0, 1e-6, 1e30]))
    else:
        cam.type = 'ORTHO'
        cam.ortho_scale = float(rng.choice([0.0, 1e-30, 1e30]))
    return ['Camera']


def tiny_resolution(scene, rng, folder):
    scene.render.resolution_x = scene.render.resolution_y = 1
    return []


def wide_resolution(scene, rng, folder):
    scene.render.resolution_x, scene.render.resolution_y = 16000, 16
    scene.ember.samples = 1
    return []


def bad_images(scene, rng, folder):
    """Missing, truncated, corrupt and garbage PNG / JPEG / EXR files."""
    fmt = str(rng.choice(['PNG', 'JPEG', 'OPEN_EXR']))
    how = str(rng.choice(['missing', 'truncated', 'corrupt', 'garbage', 'empty']))
    ext = {'PNG': '.png', 'JPEG': '.jpg', 'OPEN_EXR': '.exr'}[fmt]
    path = os.path.join(folder, f'fuzz_{how}{ext}')
    if how != 'missing':
        write_with_blender(path, 32, 32, fmt, rng)
        if how == 'empty':
            open(path, 'wb').close()
        else:
            damage(path, how, rng)
    image_material(cube(scene), file_image(path, f'FuzzImage_{how}{ext}'))
    return ['Cube', 'FuzzImageMat', f'FuzzImage_{how}{ext}']


def huge_texture(scene, rng, folder, size=16384):
    path = os.path.join(folder, f'fuzz_{size}.png')
    write_png(path, size, size, rng)
    image_material(cube(scene), file_image(path, 'FuzzHugeImage'))
    return ['Cube', 'FuzzImageMat']


def large_texture(scene, rng, folder):
    return huge_texture(scene, rng, folder, size=2048)


UNSUPPORTED_SHADER_NODES = ('ShaderNodeSubsurfaceScattering', 'ShaderNodeVolumeAbsorption',
                            'ShaderNodeVolumePrincipled', 'ShaderNodeBsdfHair', 'ShaderNodeHoldout',
                            'ShaderNodeTexVoronoi', 'ShaderNodeTexWave', 'ShaderNodeTexSky',
                            'ShaderNodeAttribute', 'ShaderNodeLightPath', 'ShaderNodeFresnel',
                            'ShaderNodeScript', 'ShaderNodeBevel', 'ShaderNodeAmbientOcclusion',
                            'ShaderNodeWireframe', 'ShaderNodeVertexColor', 'ShaderNodeBlackbody',
                            'ShaderNodeShaderToRGB', 'ShaderNodeBsdfToon', 'ShaderNodeVectorDisplacement')


def _link_somewhere(tree, node, target, rng):
    outputs = [s for s in node.outputs if s.enabled]
    inputs = [s for s in target.inputs if s.enabled]
    if outputs and inputs:
        tree.links.new(outputs[int(rng.integers(0, len(outputs)))], inputs[int(rng.integers(0, len(inputs)))])


def unsupported_nodes(scene, rng, folder):
    bpy = _bpy()
    mat = material_on(cube(scene), 'FuzzNodesMat')
    tree = mat.node_tree
    output = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    targets = [principled(mat), output]
    for _ in range(int(rng.integers(2, 6))):
        kind = str(rng.choice(UNSUPPORTED_SHADER_NODES))
        try:
            node = tree.nodes.new(kind)
        except RuntimeError:
            continue
        if kind == 'ShaderNodeScript':
            node.mode = 'EXTERNAL'
            node.filepath = '/nonexistent/$(touch /tmp/ember_pwned).osl'
        _link_somewhere(tree, node, targets[int(rng.integers(0, len(targets)))], rng)
    world = scene.world
    world.use_nodes = True
    wtree = world.node_tree
    background = next(n for n in wtree.nodes if n.type == 'BACKGROUND')
    for kind in ('ShaderNodeTexSky', 'ShaderNodeTexVoronoi', 'ShaderNodeLightPath'):
        _link_somewhere(wtree, wtree.nodes.new(kind), background, rng)
    light = point_light(scene).data
    if hasattr(light, 'use_nodes'):
        light.use_nodes = True
        if light.node_tree is not None:
            emission = next((n for n in light.node_tree.nodes if n.type == 'EMISSION'), None)
            if emission is not None:
                _link_somewhere(light.node_tree, light.node_tree.nodes.new('ShaderNodeTexVoronoi'), emission, rng)
    return ['Cube', 'FuzzNodesMat', 'World', 'Light']


def node_groups(scene, rng, folder):
    """A group node with no tree, a group used inside itself, two groups
    using each other (made with the API, which the UI forbids)."""
    bpy = _bpy()
    mat = material_on(cube(scene), 'FuzzGroupMat')
    tree = mat.node_tree
    bsdf = principled(mat)
    group_a = bpy.data.node_groups.new('FuzzGroupA', 'ShaderNodeTree')
    group_b = bpy.data.node_groups.new('FuzzGroupB', 'ShaderNodeTree')
    for group in (group_a, group_b):
        if hasattr(group, 'interface'):
            group.interface.new_socket('Color', in_out='OUTPUT', socket_type='NodeSocketColor')
        else:
            group.outputs.new('NodeSocketColor', 'Color')
        out = group.nodes.new('NodeGroupOutput')
        inner = group.nodes.new('ShaderNodeGroup')
        try:
            inner.node_tree = group_b if group is group_a else group_a
        except (TypeError, RuntimeError, ValueError):
            pass
        if inner.outputs:
            group.links.new(inner.outputs[0], out.inputs[0])
    missing = tree.nodes.new('ShaderNodeGroup')  # no node tree at all
    outer = tree.nodes.new('ShaderNodeGroup')
    outer.node_tree = group_a
    chosen = outer if rng.random() < 0.7 or not missing.outputs else missing
    if chosen.outputs:
        tree.links.new(chosen.outputs[0], bsdf.inputs['Base Color'])
    return ['Cube', 'FuzzGroupMat', 'FuzzGroupA', 'FuzzGroupB']


def many_instances(scene, rng, folder, count=10 ** 6):
    """`count` instances of one plane through geometry nodes."""
    bpy = _bpy()
    side = int(round(math.sqrt(count)))
    host = new_mesh_object('FuzzInstancer', [(0, 0, 0)], [])
    tree = bpy.data.node_groups.new('FuzzScatter', 'GeometryNodeTree')
    if hasattr(tree, 'interface'):
        tree.interface.new_socket('Geometry', in_out='OUTPUT', socket_type='NodeSocketGeometry')
    else:
        tree.outputs.new('NodeSocketGeometry', 'Geometry')
    grid = tree.nodes.new('GeometryNodeMeshGrid')
    grid.inputs['Vertices X'].default_value = side
    grid.inputs['Vertices Y'].default_value = side
    grid.inputs['Size X'].default_value = 4.0
    grid.inputs['Size Y'].default_value = 4.0
    plane = tree.nodes.new('GeometryNodeMeshGrid')
    plane.inputs['Size X'].default_value = plane.inputs['Size Y'].default_value = 4.0 / side
    plane.inputs['Vertices X'].default_value = plane.inputs['Vertices Y'].default_value = 2
    place = tree.nodes.new('GeometryNodeInstanceOnPoints')
    out = tree.nodes.new('NodeGroupOutput')
    tree.links.new(grid.outputs['Mesh'], place.inputs['Points'])
    tree.links.new(plane.outputs['Mesh'], place.inputs['Instance'])
    tree.links.new(place.outputs['Instances'], out.inputs[0])
    modifier = host.modifiers.new('Scatter', 'NODES')
    modifier.node_group = tree
    if 'Cube' in scene.objects:
        bpy.data.objects.remove(scene.objects['Cube'])
    scene.ember.samples = 1
    return ['FuzzInstancer']


def some_instances(scene, rng, folder):
    return many_instances(scene, rng, folder, count=2500)


def more_instances(scene, rng, folder):
    return many_instances(scene, rng, folder, count=10 ** 5)


def many_lights(scene, rng, folder, count=10_000):
    bpy = _bpy()
    data = bpy.data.lights.new('FuzzLamp', 'POINT')
    data.energy = 0.01
    collection = scene.collection
    positions = rng.uniform(-3, 3, (count, 3))
    positions[:, 2] = np.abs(positions[:, 2]) + 1.5
    for k in range(count):
        obj = bpy.data.objects.new(f'FuzzLamp{k}', data)
        obj.location = positions[k]
        collection.objects.link(obj)
    scene.ember.samples = 1
    scene.ember.light_selection = str(rng.choice(['AUTO', 'POWER', 'TREE', 'UNIFORM']))
    return []


# Every node type the exporter translates (engine.nodes.REGISTRY and the
# exporter's own readers), with each input fed a value of another shape.
SHADER_NODES = ('ShaderNodeBsdfDiffuse', 'ShaderNodeBsdfGlossy', 'ShaderNodeBsdfGlass',
                'ShaderNodeBsdfRefraction', 'ShaderNodeBsdfTranslucent', 'ShaderNodeBsdfTransparent',
                'ShaderNodeBsdfSheen', 'ShaderNodeEmission', 'ShaderNodeBsdfPrincipled')
VALUE_NODES = ('ShaderNodeTexImage', 'ShaderNodeMix', 'ShaderNodeMixRGB', 'ShaderNodeMath', 'ShaderNodeRGB',
               'ShaderNodeValue', 'ShaderNodeBump', 'ShaderNodeNormalMap', 'ShaderNodeDisplacement',
               'ShaderNodeVectorDisplacement')


def _exported_value_nodes():
    from engine.nodes import REGISTRY
    return sorted(set(REGISTRY) | set(VALUE_NODES))


def _wrong_shape_source(tree, rng, folder):
    """An output socket whose value has a shape the input may not expect: a
    colour or vector constant, a float, a missing image's magenta, a muted
    node's zero, a group's unlinked colour input, a shader."""
    bpy = _bpy()
    kind = int(rng.integers(0, 8))
    if kind == 0:
        node = tree.nodes.new('ShaderNodeRGB')
        node.outputs[0].default_value = tuple(float(v) for v in rng.choice([0.0, 0.5, 2.0, -1.0], 3)) + (1.0,)
        return node.outputs[0]
    if kind == 1:
        node = tree.nodes.new('ShaderNodeValue')
        node.outputs[0].default_value = float(rng.choice([0.0, 0.5, -3.0, 1e30]))
        return node.outputs[0]
    if kind == 2:
        node = tree.nodes.new('ShaderNodeCombineXYZ')
        for socket, value in zip(node.inputs, rng.uniform(-2, 2, 3)):
            socket.default_value = float(value)
        return node.outputs[0]
    if kind == 3:
        node = tree.nodes.new('ShaderNodeTexImage')
        node.image = file_image(os.path.join(folder, 'fuzz_missing_height.png'), 'FuzzMissingShape')
        return node.outputs[int(rng.integers(0, 2))]
    if kind == 4:
        node = tree.nodes.new('ShaderNodeMixRGB' if rng.random() < 0.5 else 'ShaderNodeMath')
        node.mute = True
        return node.outputs[0]
    if kind == 5:
        node = tree.nodes.new('ShaderNodeNewGeometry')
        return node.outputs[int(rng.integers(0, len(node.outputs)))]
    if kind == 6:
        group = bpy.data.node_groups.new('FuzzShapeGroup', 'ShaderNodeTree')
        if hasattr(group, 'interface'):
            group.interface.new_socket('In', in_out='INPUT', socket_type='NodeSocketColor')
            group.interface.new_socket('Out', in_out='OUTPUT', socket_type='NodeSocketColor')
        else:
            group.inputs.new('NodeSocketColor', 'In')
            group.outputs.new('NodeSocketColor', 'Out')
        inner_in, inner_out = group.nodes.new('NodeGroupInput'), group.nodes.new('NodeGroupOutput')
        group.links.new(inner_in.outputs[0], inner_out.inputs[0])
        node = tree.nodes.new('ShaderNodeGroup')
        node.node_tree = group
        node.inputs[0].default_value = (0.3, 0.6, 0.9, 1.0)
        return node.outputs[0]
    return tree.nodes.new('ShaderNodeBsdfDiffuse').outputs[0]


def _feed_inputs(tree, node, rng, folder):
    for socket in node.inputs:
        if getattr(socket, 'enabled', True) and rng.random() < 0.7:
            tree.links.new(_wrong_shape_source(tree, rng, folder), socket)


# Enum items left out: a 4D Smooth F1 Voronoi (625 cells a point) reached
# through bump differences costs 30-60 s at 16x16 pixels, a slow case, no hazard.
SLOW_ITEMS = {'voronoi_dimensions': ('4D',)}


def _randomize_enums(node, rng):
    """Each enum property of the node set to one of its items at random."""
    for prop in node.bl_rna.properties:
        if prop.type != 'ENUM' or prop.is_readonly or prop.is_enum_flag or prop.identifier in ('location',):
            continue
        items = [item.identifier for item in prop.enum_items
                 if item.identifier not in SLOW_ITEMS.get(prop.identifier, ())]
        if items:
            try:
                setattr(node, prop.identifier, str(rng.choice(items)))
            except (TypeError, ValueError, RuntimeError):
                pass


def wrong_shapes(scene, rng, folder):
    """Issue 23's class of input: every node type the exporter knows, each
    input linked to a value of another shape (a colour where a float is
    read, a vector, a missing image, a muted node, a shader), the nodes
    chained into the BSDF's inputs, its Normal and the Material Output's
    Displacement; a light and a world whose Emission / Background inputs
    are fed the same way."""
    mat = material_on(cube(scene), 'FuzzShapesMat')
    tree = mat.node_tree
    output = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    bsdf = principled(mat)
    chain = []
    for kind in rng.permutation(_exported_value_nodes()):
        try:
            node = tree.nodes.new(str(kind))
        except RuntimeError:
            continue
        _randomize_enums(node, rng)
        _feed_inputs(tree, node, rng, folder)
        chain.append(node)
    targets = [s for s in bsdf.inputs if s.enabled] + [output.inputs['Displacement']]
    for node, after in zip(chain, chain[1:] + [None]):
        outputs = [s for s in node.outputs if s.enabled]
        sink = targets if after is None else [s for s in after.inputs if s.enabled] or targets
        if outputs:
            tree.links.new(outputs[int(rng.integers(0, len(outputs)))], sink[int(rng.integers(0, len(sink)))])
        if rng.random() < 0.3 and outputs:   # some go straight to the BSDF or the displacement
            tree.links.new(outputs[int(rng.integers(0, len(outputs)))], targets[int(rng.integers(0, len(targets)))])
    surface = bsdf.outputs[0]
    for kind in rng.permutation(SHADER_NODES):
        shader = tree.nodes.new(str(kind))
        _randomize_enums(shader, rng)
        _feed_inputs(tree, shader, rng, folder)
        mix = tree.nodes.new('ShaderNodeMixShader' if rng.random() < 0.7 else 'ShaderNodeAddShader')
        tree.links.new(surface, mix.inputs[-2])
        tree.links.new(shader.outputs[0], mix.inputs[-1])
        if mix.type == 'MIX_SHADER':
            tree.links.new(_wrong_shape_source(tree, rng, folder), mix.inputs[0])
        surface = mix.outputs[0]
    tree.links.new(surface, output.inputs['Surface'])
    world = scene.world
    world.use_nodes = True
    background = next(n for n in world.node_tree.nodes if n.type == 'BACKGROUND')
    _feed_inputs(world.node_tree, background, rng, folder)
    light = point_light(scene).data
    if hasattr(light, 'use_nodes'):
        light.use_nodes = True
        emission = next((n for n in light.node_tree.nodes if n.type == 'EMISSION'), None) if light.node_tree else None
        if emission is not None:
            _feed_inputs(light.node_tree, emission, rng, folder)
    return ['Cube', 'FuzzShapesMat', 'World', 'Light']


# name -> (function, risky: run in a subprocess, full: only with --full)
HAZARDS = {
    'nan_vertices': (nan_vertices, False, False),
    'huge_vertices': (huge_vertices, False, False),
    'hostile_displacement': (hostile_displacement, False, False),
    'degenerate_triangles': (degenerate_triangles, False, False),
    'empty_meshes': (empty_meshes, False, False),
    'nan_transform': (nan_transform, False, False),
    'object_scales': (object_scales, False, False),
    'light_values': (light_values, False, False),
    'spot_angles': (spot_angles, False, False),
    'huge_emission': (huge_emission, False, False),
    'camera_inside': (camera_inside, False, False),
    'camera_values': (camera_values, False, False),
    'tiny_resolution': (tiny_resolution, False, False),
    'bad_images': (bad_images, False, False),
    'unsupported_nodes': (unsupported_nodes, False, False),
    'node_groups': (node_groups, False, False),
    'wrong_shapes': (wrong_shapes, False, False),
    'some_instances': (some_instances, False, False),
    'large_texture': (large_texture, True, False),
    'more_instances': (more_instances, True, True),
    'wide_resolution': (wide_resolution, True, False),
    'many_lights': (many_lights, True, False),
    'many_instances': (many_instances, True, True),
    'huge_texture': (huge_texture, True, True),
}
# Hazards cheap enough to combine at random in-process.
COMBINABLE = [name for name, (_, risky, _) in HAZARDS.items() if not risky]


# ----------------------------------------------------------------------------
# running one scene

def reset_scene():
    bpy = _bpy()
    bpy.ops.wm.read_factory_settings(use_empty=False)
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    scene.render.resolution_x = scene.render.resolution_y = 16
    scene.render.resolution_percentage = 100
    scene.ember.samples = 2
    scene.ember.max_bounces = 3
    scene.ember.threads = 2
    layer = scene.view_layers[0]
    layer.use_pass_z = True
    layer.use_pass_normal = True
    return scene


class PassCheck:
    """Wraps the engine's render function: records whether every array it
    returns (combined, depth, normal, albedo, variance) is finite."""

    def __init__(self):
        self.nonfinite = []

    def wrap(self, real):
        def render(scene, settings, progress=None):
            result = real(scene, settings, progress)
            for name in ('image', 'depth', 'normal', 'albedo', 'variance'):
                data = getattr(result, name, None)
                if data is not None and not np.isfinite(data).all():
                    self.nonfinite.append(name)
            for name, data in (getattr(result, 'passes', None) or {}).items():
                if data is not None and not np.isfinite(data).all():
                    self.nonfinite.append(name)
            return result
        return render


def classify(log, names, nonfinite):
    """(outcome, detail) for one render's log entry."""
    if log is None:
        return 'FAILED', 'render() was never called'
    if nonfinite:
        return 'FAILED', f"non-finite values in passes {sorted(set(nonfinite))}"
    replaced = [w for w in log['warnings'] if 'non-finite' in w]
    if replaced:
        return 'FAILED', replaced[0]
    error = log['error']
    if error is None:
        return 'rendered', f"{log.get('samples')} samples, {len(log['warnings'])} warnings"
    head = error.split(':', 1)[0]
    if head.endswith('Error') or head.endswith('Exception') or 'Traceback' in error:
        return 'FAILED', 'unhandled exception: ' + error
    if names and not any(name in error for name in names):
        return 'FAILED', f"error names none of {names}: {error}"
    return 'refused', error


def run_case(hazards, seed, folder):
    """Build and render one scene in this process; returns a result dict."""
    bpy = _bpy()
    from addon import backend
    from addon import engine as ember_engine
    rng = np.random.default_rng([seed, *[sorted(HAZARDS).index(h) for h in hazards]])
    scene = reset_scene()
    names = []
    for hazard in hazards:
        names += HAZARDS[hazard][0](scene, rng, folder)
    check = PassCheck()
    renderer = backend.engine()
    real = renderer.render
    renderer.render = check.wrap(real)
    before = len(ember_engine.RENDER_LOG) and ember_engine.RENDER_LOG[-1]
    start = time.perf_counter()
    try:
        bpy.ops.render.render()
    except RuntimeError:
        pass  # self.report({'ERROR'}) makes the operator raise: the log has the message
    finally:
        renderer.render = real
    log = ember_engine.RENDER_LOG[-1] if ember_engine.RENDER_LOG and ember_engine.RENDER_LOG[-1] is not before else None
    outcome, detail = classify(log, names, check.nonfinite)
    if log is not None and 'export_seconds' in log:
        detail += f" (export {log['export_seconds']:.2f} s)"
    return {'case': '+'.join(hazards), 'seed': seed, 'outcome': outcome, 'detail': detail,
            'seconds': round(time.perf_counter() - start, 2)}


def run_in_subprocess(hazards, seed, folder, timeout=300):
    """The same in a fresh bpy process: a crash or a hang is one FAILED case."""
    cmd = [sys.executable, '-P', os.path.abspath(__file__), '--case', '+'.join(hazards),
           '--seed', str(seed), '--folder', folder, '--json']
    env = dict(os.environ, PYTHONPATH=ROOT)
    start = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {'case': '+'.join(hazards), 'seed': seed, 'outcome': 'FAILED',
                'detail': f'no answer within {timeout} s', 'seconds': timeout}
    lines = [line for line in proc.stdout.splitlines() if line.startswith('{"case"')]
    if proc.returncode != 0 or not lines:
        return {'case': '+'.join(hazards), 'seed': seed, 'outcome': 'FAILED',
                'detail': f'process exited with {proc.returncode}: {(proc.stdout + proc.stderr)[-800:]}',
                'seconds': round(time.perf_counter() - start, 2)}
    return json.loads(lines[-1])


def corpus(random_count=0, full=False, seed=0):
    """[(hazards, seed, risky)]: every hazard once, then random combinations."""
    cases = [((name,), seed, risky) for name, (_, risky, only_full) in HAZARDS.items()
             if full or not only_full]
    rng = np.random.default_rng(seed)
    for k in range(random_count):
        picked = rng.choice(COMBINABLE, int(rng.integers(1, 4)), replace=False)
        cases.append((tuple(sorted(picked)), seed * 100003 + k + 1, False))
    return cases


def run_corpus(cases, folder, log=print):
    results = []
    for hazards, seed, risky in cases:
        result = (run_in_subprocess if risky else run_case)(hazards, seed, folder)
        results.append(result)
        log(f"{result['outcome']:9s} {result['case']} (seed {seed}, {result['seconds']} s): {result['detail']}")
    return results


def tally(results):
    counts = {'tried': len(results)}
    for outcome in ('rendered', 'refused', 'FAILED'):
        counts[outcome] = sum(r['outcome'] == outcome for r in results)
    return counts


def _register():
    sys.path.insert(0, ROOT)
    os.environ.setdefault('BLENDER_USER_RESOURCES', tempfile.mkdtemp(prefix='ember-fuzz-user-'))
    import addon
    addon.register()


def main(argv=None):
    import argparse
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--case', help="hazards joined by '+', e.g. nan_vertices+bad_images")
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--random', type=int, default=0, help="random combinations to add")
    parser.add_argument('--full', action='store_true', help="add the on-demand sizes (16k textures)")
    parser.add_argument('--folder', default=None)
    parser.add_argument('--json', action='store_true')
    args = parser.parse_args(argv)
    _register()
    folder = args.folder or tempfile.mkdtemp(prefix='ember-fuzz-')
    if args.case:
        result = run_case(tuple(args.case.split('+')), args.seed, folder)
        print(json.dumps(result) if args.json else result, flush=True)
        return 0 if result['outcome'] != 'FAILED' else 1
    results = run_corpus(corpus(args.random, args.full, args.seed), folder)
    counts = tally(results)
    print("Fuzz tally: {tried} scenes tried, {rendered} rendered, {refused} refused with a message, "
          "{FAILED} failed".format(**counts))
    return 0 if counts['FAILED'] == 0 else 1


if __name__ == '__main__':
    sys.exit(main())
