"""Builds the example scenes in this folder: cornell.blend, veach_mis.blend and
instances_lights.blend.

The .blend files are committed as saved by Blender 3.4 (Debian's binary), the
oldest supported version: a file saved by 3.4 opens in 4.2 and 5.0, while a 5.0
file does not open in 3.4.  Rebuild them with

    blender -b --factory-startup --python blend_scenes/build_scenes.py -- blend_scenes

The same script also runs inside the bpy module (tests use ``build(name)`` to
check that the committed files match what the script makes).  It uses only
API that exists from 3.4 to 5.0 and sets every version-dependent default
explicitly (GGX, not multiscatter; 3.x light units, converted as Blender 4.0
converts old files) so that every version builds the same scene.

Every scene uses materials the engine translates exactly (Diffuse, Glossy,
Emission), so Ember can be compared with Cycles pixel block by pixel block.
"""
import math
import os
import sys

import bpy

SCENES = ('cornell', 'veach_mis', 'instances_lights')


# ----------------------------------------------------------------------------
# helpers

def reset():
    """An empty file with one scene, keeping nothing from the startup file."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.frame_start = scene.frame_end = scene.frame_current = 1
    return scene


def set_engine(scene):
    """Ember when it is registered, Cycles otherwise (the file still opens)."""
    try:
        scene.render.engine = 'EMBER'
    except TypeError:
        scene.render.engine = 'CYCLES'
    cycles = getattr(scene, 'cycles', None)
    if cycles is not None:
        cycles.samples = 64
        cycles.use_denoising = False
    ember = getattr(scene, 'ember', None)
    if ember is not None:
        ember.samples = 64


def link(scene, obj, collection=None):
    (collection or scene.collection).objects.link(obj)
    return obj


def mesh_object(scene, name, verts, faces, material=None, collection=None):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    obj = link(scene, bpy.data.objects.new(name, mesh), collection)
    if material is not None:
        mesh.materials.append(material)
    return obj


def box(scene, name, size, location, rotation_z=0.0, material=None, collection=None):
    sx, sy, sz = (s / 2 for s in size)
    verts = [(x * sx, y * sy, z * sz) for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)]
    faces = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    obj = mesh_object(scene, name, verts, faces, material, collection)
    obj.location = location
    obj.rotation_euler = (0.0, 0.0, rotation_z)
    return obj


def uv_sphere(scene, name, radius, location, material=None, segments=24, rings=12, collection=None):
    verts = [(0.0, 0.0, radius)]
    for ring in range(1, rings):
        theta = math.pi * ring / rings
        for seg in range(segments):
            phi = 2 * math.pi * seg / segments
            verts.append((radius * math.sin(theta) * math.cos(phi),
                          radius * math.sin(theta) * math.sin(phi), radius * math.cos(theta)))
    verts.append((0.0, 0.0, -radius))
    bottom = len(verts) - 1

    def ring_vertex(ring, seg):
        return 1 + (ring - 1) * segments + seg % segments

    faces = [(0, ring_vertex(1, s), ring_vertex(1, s + 1)) for s in range(segments)]
    for ring in range(1, rings - 1):
        faces += [(ring_vertex(ring, s), ring_vertex(ring + 1, s), ring_vertex(ring + 1, s + 1),
                   ring_vertex(ring, s + 1)) for s in range(segments)]
    faces += [(ring_vertex(rings - 1, s + 1), ring_vertex(rings - 1, s), bottom) for s in range(segments)]
    obj = mesh_object(scene, name, verts, faces, material, collection)
    for polygon in obj.data.polygons:
        polygon.use_smooth = True
    obj.location = location
    return obj


def node_material(name, kind, color=(0.8, 0.8, 0.8), roughness=0.0, strength=1.0):
    """A material whose surface is one Diffuse, Glossy or Emission node."""
    material = bpy.data.materials.new(name)
    material.use_nodes = True
    tree = material.node_tree
    tree.nodes.clear()
    output = tree.nodes.new('ShaderNodeOutputMaterial')
    node = tree.nodes.new({'diffuse': 'ShaderNodeBsdfDiffuse', 'glossy': 'ShaderNodeBsdfGlossy',
                           'emission': 'ShaderNodeEmission'}[kind])
    node.inputs['Color'].default_value = (*color, 1.0)
    if kind == 'glossy':
        node.distribution = 'GGX'  # 5.0 defaults to multiscatter GGX
        node.inputs['Roughness'].default_value = roughness
    if kind == 'emission':
        node.inputs['Strength'].default_value = strength
    tree.links.new(node.outputs[0], output.inputs['Surface'])
    material.diffuse_color = (*color, 1.0)
    return material


def world(scene, color, strength=1.0):
    w = bpy.data.worlds.new("World")
    w.use_nodes = True
    background = next(n for n in w.node_tree.nodes if n.type == 'BACKGROUND')
    background.inputs['Color'].default_value = (*color, 1.0)
    background.inputs['Strength'].default_value = strength
    w.color = color
    scene.world = w


def world_background(scene, name, texture_type):
    """A new world for ``scene`` whose Background colour comes from a new
    texture node of ``texture_type``; returns (world, texture node)."""
    w = bpy.data.worlds.new(name)
    scene.world = w
    if bpy.app.version < (5, 0, 0):
        w.use_nodes = True
    tree = w.node_tree
    tree.nodes.clear()
    out = tree.nodes.new('ShaderNodeOutputWorld')
    background = tree.nodes.new('ShaderNodeBackground')
    texture = tree.nodes.new(texture_type)
    tree.links.new(texture.outputs['Color'], background.inputs['Color'])
    tree.links.new(background.outputs[0], out.inputs['Surface'])
    return w, texture


def light(scene, name, kind, location, energy, color=(1.0, 1.0, 1.0), rotation=(0.0, 0.0, 0.0), **settings):
    """A light; ``energy`` in Blender 3.x units.

    Blender 4.0 changed area light units and converts 3.x files by pi/4 when it
    opens them; building in 4.0+ applies the same factor so that a scene built
    in any version is the scene 3.4 saved.
    """
    data = bpy.data.lights.new(name, kind)
    if kind == 'AREA' and bpy.app.version >= (4, 0, 0):
        energy *= math.pi / 4.0
    data.energy = energy
    data.color = color
    if hasattr(data, 'use_soft_falloff'):
        # What 4.0 sets when it opens a 3.x file (3.x point lights are disks
        # facing the shading point): every version sees the same light.
        data.use_soft_falloff = True
    for key, value in settings.items():
        setattr(data, key, value)
    obj = link(scene, bpy.data.objects.new(name, data))
    obj.location = location
    obj.rotation_euler = rotation
    return obj


def camera(scene, location, rotation, lens=50.0, resolution=(256, 256)):
    data = bpy.data.cameras.new("Camera")
    data.lens = lens
    data.sensor_fit = 'AUTO'
    obj = link(scene, bpy.data.objects.new("Camera", data))
    obj.location = location
    obj.rotation_euler = rotation
    scene.camera = obj
    scene.render.resolution_x, scene.render.resolution_y = resolution
    return obj


def look_at(obj, target):
    from mathutils import Vector
    direction = Vector(target) - obj.location
    obj.rotation_euler = direction.to_track_quat('-Z', 'Y').to_euler()


# ----------------------------------------------------------------------------
# scenes

def build_cornell():
    """The Cornell box: white, red and green diffuse walls, two boxes, an area light."""
    scene = reset()
    scene.name = "Cornell"
    white = node_material("White", 'diffuse', (0.73, 0.73, 0.73))
    red = node_material("Red", 'diffuse', (0.63, 0.065, 0.05))
    green = node_material("Green", 'diffuse', (0.14, 0.45, 0.091))
    c = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0), (-1, -1, 2), (1, -1, 2), (1, 1, 2), (-1, 1, 2)]
    mesh_object(scene, "Floor", [c[0], c[1], c[2], c[3]], [(0, 1, 2, 3)], white)
    mesh_object(scene, "Ceiling", [c[4], c[7], c[6], c[5]], [(0, 1, 2, 3)], white)
    mesh_object(scene, "Back", [c[3], c[2], c[6], c[7]], [(0, 1, 2, 3)], white)
    mesh_object(scene, "Left", [c[0], c[3], c[7], c[4]], [(0, 1, 2, 3)], red)
    mesh_object(scene, "Right", [c[1], c[5], c[6], c[2]], [(0, 1, 2, 3)], green)
    box(scene, "TallBox", (0.6, 0.6, 1.2), (-0.35, 0.3, 0.6), math.radians(20), white)
    box(scene, "ShortBox", (0.6, 0.6, 0.6), (0.35, -0.3, 0.3), math.radians(-18), white)
    light(scene, "AreaLight", 'AREA', (0.0, 0.0, 1.98), 40.0, (1.0, 0.85, 0.7), shape='SQUARE', size=0.5)
    camera(scene, (0.0, -3.9, 1.0), (math.pi / 2, 0.0, 0.0), lens=50.0)
    world(scene, (0.0, 0.0, 0.0))
    set_engine(scene)
    return scene


# Veach's MIS test (thesis fig. 9.2): four plates from smooth to rough, lit by
# four point lights of very different radii and equal power.
PLATE_ROUGHNESS = (0.08, 0.18, 0.3, 0.5)
LIGHT_RADII = (0.03, 0.1, 0.3, 0.8)


def build_veach_mis():
    scene = reset()
    scene.name = "VeachMIS"
    from mathutils import Vector
    eye = Vector((0.0, -7.0, 2.2))
    lights_at = [Vector((x, 3.0, 3.6)) for x in (-2.4, -0.8, 0.8, 2.4)]
    floor = node_material("Floor", 'diffuse', (0.3, 0.3, 0.3))
    mesh_object(scene, "Floor", [(-8, -8, -0.5), (8, -8, -0.5), (8, 8, -0.5), (-8, 8, -0.5)],
                [(0, 1, 2, 3)], floor)
    mesh_object(scene, "Backdrop", [(-8, 6, -0.5), (8, 6, -0.5), (8, 6, 8), (-8, 6, 8)],
                [(0, 1, 2, 3)], floor)
    target = Vector((0.0, 3.0, 3.6))
    for i, roughness in enumerate(PLATE_ROUGHNESS):
        center = Vector((0.0, -1.2 + 0.75 * i, 0.15 + 0.35 * i))
        normal = ((eye - center).normalized() + (target - center).normalized()).normalized()
        plate = box(scene, f"Plate{i}", (5.2, 0.65, 0.04), center,
                    material=node_material(f"Glossy{i}", 'glossy', (0.7, 0.7, 0.7), roughness))
        # Local X stays along the world X axis; local Z is the half vector.
        from mathutils import Matrix
        y_axis = normal.cross(Vector((1.0, 0.0, 0.0)))
        basis = Matrix(((1.0, y_axis.x, normal.x), (0.0, y_axis.y, normal.y), (0.0, y_axis.z, normal.z)))
        plate.rotation_euler = basis.to_euler()
    colors = ((1.0, 0.3, 0.2), (1.0, 0.9, 0.3), (0.3, 1.0, 0.4), (0.3, 0.5, 1.0))
    for i, (position, radius) in enumerate(zip(lights_at, LIGHT_RADII)):
        light(scene, f"Sphere{i}", 'POINT', position, 60.0, colors[i], shadow_soft_size=radius)
    cam = camera(scene, eye, (0.0, 0.0, 0.0), lens=35.0, resolution=(320, 240))
    look_at(cam, (0.0, 0.5, 1.2))
    world(scene, (0.01, 0.01, 0.01))
    set_engine(scene)
    return scene


def _geometry_nodes_instancer(scene, source):
    """A 3x3 grid whose geometry nodes put a copy of ``source`` on every point."""
    group = bpy.data.node_groups.new("InstanceOnGrid", 'GeometryNodeTree')
    if hasattr(group, 'interface'):  # 4.0+
        group.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
        group.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    else:
        group.inputs.new('NodeSocketGeometry', "Geometry")
        group.outputs.new('NodeSocketGeometry', "Geometry")
    nodes, links = group.nodes, group.links
    group_in = nodes.new('NodeGroupInput')
    group_out = nodes.new('NodeGroupOutput')
    points = nodes.new('GeometryNodeMeshToPoints')
    info = nodes.new('GeometryNodeObjectInfo')
    info.inputs['Object'].default_value = source
    on_points = nodes.new('GeometryNodeInstanceOnPoints')
    links.new(group_in.outputs[0], points.inputs['Mesh'])
    links.new(points.outputs['Points'], on_points.inputs['Points'])
    links.new(info.outputs['Geometry'], on_points.inputs['Instance'])
    links.new(on_points.outputs['Instances'], group_out.inputs[0])
    verts = [(x * 0.6, y * 0.6, 0.0) for y in (-1, 0, 1) for x in (-1, 0, 1)]
    grid = mesh_object(scene, "GNGrid", verts, [])
    grid.location = (1.6, 0.6, 0.25)
    modifier = grid.modifiers.new("Instances", 'NODES')
    modifier.node_group = group
    return grid


def _particle_instancer(scene, source, material):
    """A plane whose hair particles render as copies of ``source``."""
    emitter = mesh_object(scene, "ParticleEmitter",
                          [(-0.7, -0.7, 0), (0.7, -0.7, 0), (0.7, 0.7, 0), (-0.7, 0.7, 0)],
                          [(0, 1, 2, 3)], material)
    emitter.location = (-1.7, -0.6, 0.002)
    emitter.modifiers.new("Particles", 'PARTICLE_SYSTEM')
    settings = emitter.particle_systems[0].settings
    settings.type = 'HAIR'
    settings.count = 12
    settings.hair_length = 0.3
    settings.render_type = 'OBJECT'
    settings.instance_object = source
    settings.particle_size = 1.0
    settings.use_emit_random = False
    settings.use_even_distribution = True
    emitter.particle_systems[0].seed = 3
    emitter.show_instancer_for_render = True
    return emitter


def build_instances_lights():
    """Collection, geometry-node and particle instances lit by every light type."""
    scene = reset()
    scene.name = "InstancesLights"
    ground = node_material("Ground", 'diffuse', (0.6, 0.6, 0.6))
    orange = node_material("Orange", 'diffuse', (0.8, 0.35, 0.1))
    blue = node_material("Blue", 'diffuse', (0.15, 0.3, 0.8))
    metal = node_material("Metal", 'glossy', (0.9, 0.9, 0.9), 0.25)
    glow = node_material("Glow", 'emission', (1.0, 0.6, 0.2), strength=4.0)
    mesh_object(scene, "Ground", [(-4, -4, 0), (4, -4, 0), (4, 4, 0), (-4, 4, 0)], [(0, 1, 2, 3)], ground)
    mesh_object(scene, "Wall", [(-4, 3, 0), (4, 3, 0), (4, 3, 4), (-4, 3, 4)], [(0, 1, 2, 3)], ground)

    # Sources live in a collection excluded from the view layer: only their
    # instances render.
    sources = bpy.data.collections.new("Sources")
    scene.collection.children.link(sources)
    pillar = box(scene, "Pillar", (0.3, 0.3, 1.0), (0.0, 0.0, 0.5), material=orange, collection=sources)
    ball = uv_sphere(scene, "Ball", 0.18, (0.0, 0.0, 0.0), blue, collection=sources)
    chip = box(scene, "Chip", (0.14, 0.14, 0.3), (0.0, 0.0, 0.15), material=metal, collection=sources)
    scene.view_layers[0].layer_collection.children["Sources"].exclude = True
    pillars = bpy.data.collections.new("Pillars")
    pillars.objects.link(pillar)
    for i, (x, angle) in enumerate(((-0.6, 0.0), (0.0, 0.5), (0.6, 1.0))):
        empty = link(scene, bpy.data.objects.new(f"PillarInstance{i}", None))
        empty.instance_type = 'COLLECTION'
        empty.instance_collection = pillars
        empty.location = (x, 1.6, 0.0)
        empty.rotation_euler = (0.0, 0.0, angle)
        empty.scale = (1.0, 1.0, 0.6 + 0.4 * i)
    _geometry_nodes_instancer(scene, ball)
    _particle_instancer(scene, chip, ground)
    uv_sphere(scene, "GlowBall", 0.2, (0.0, -0.4, 0.2), glow)

    light(scene, "Point", 'POINT', (-1.5, -1.0, 2.0), 80.0, (1.0, 0.8, 0.6), shadow_soft_size=0.15)
    light(scene, "Spot", 'SPOT', (1.5, -1.5, 3.0), 250.0, (0.6, 0.8, 1.0),
          rotation=(math.radians(30), 0.0, math.radians(30)), shadow_soft_size=0.1,
          spot_size=math.radians(50), spot_blend=0.3)
    light(scene, "Sun", 'SUN', (0.0, 0.0, 5.0), 0.8, (1.0, 0.95, 0.9),
          rotation=(math.radians(40), 0.0, math.radians(-30)), angle=math.radians(3))
    light(scene, "AreaDisk", 'AREA', (0.0, 0.5, 3.0), 60.0, (1.0, 1.0, 1.0), shape='DISK', size=0.8)
    light(scene, "AreaRect", 'AREA', (-2.5, 1.0, 1.5), 80.0, (0.8, 1.0, 0.8),
          rotation=(0.0, math.radians(-70), 0.0), shape='RECTANGLE', size=1.0, size_y=0.4)
    cam = camera(scene, (0.0, -5.5, 2.6), (0.0, 0.0, 0.0), lens=32.0, resolution=(320, 240))
    look_at(cam, (0.0, 0.6, 0.6))
    world(scene, (0.03, 0.04, 0.06))
    set_engine(scene)
    return scene


BUILDERS = {'cornell': build_cornell, 'veach_mis': build_veach_mis,
            'instances_lights': build_instances_lights}


def build(name):
    """Build one scene in the current Blender session and return it."""
    scene = BUILDERS[name]()
    bpy.context.view_layer.update()  # evaluate transforms before anyone reads them
    return scene


def save_all(folder):
    os.makedirs(folder, exist_ok=True)
    for name in SCENES:
        build(name)
        path = os.path.join(os.path.abspath(folder), name + ".blend")
        bpy.ops.wm.save_as_mainfile(filepath=path, compress=True)
        print("saved", path)


def _register_ember():
    """Register the add-on from this repository so files are saved with Ember set."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if root not in sys.path:
        sys.path.insert(0, root)
    try:
        import addon
        addon.register()
    except (ImportError, ValueError) as err:  # ValueError: already registered
        print("Ember add-on not registered:", err)


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    _register_ember()
    save_all(args[0] if args else os.path.dirname(os.path.abspath(__file__)))
