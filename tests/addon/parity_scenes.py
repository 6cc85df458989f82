"""Small scenes built with bpy for the Cycles parity tests (a helper module:
test modules do not import each other)."""
import bpy

from ember_testlib import small_resolution

WIDTH, HEIGHT = 32, 24   # the light and transparency parity frames


def empty_material(name):
    """A node material holding only its output: (material, tree, output)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    return mat, tree, tree.nodes.new('ShaderNodeOutputMaterial')


def material(name, kind, color=(0.8, 0.8, 0.8), strength=1.0, roughness=0.3):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new('ShaderNodeOutputMaterial')
    if kind == 'emission':
        node = nodes.new('ShaderNodeEmission')
        node.inputs['Strength'].default_value = strength
    elif kind == 'glossy':
        node = nodes.new('ShaderNodeBsdfGlossy')
        node.distribution = 'GGX'
        node.inputs['Roughness'].default_value = roughness
    else:
        node = nodes.new('ShaderNodeBsdfDiffuse')
    node.inputs['Color'].default_value = (*color, 1.0)
    links.new(node.outputs[0], out.inputs['Surface'])
    return mat


def mesh_object(name, verts, faces, mat, location=(0, 0, 0)):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    mesh.materials.append(mat)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def plane(name, mat, half=3.0, z=0.0):
    h = half
    return mesh_object(name, [(-h, -h, z), (h, -h, z), (h, h, z), (-h, h, z)], [(0, 1, 2, 3)], mat)


def box(name, mat, center, size):
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=center)
    obj = bpy.context.active_object
    obj.name = name
    obj.scale = size
    obj.data.materials.append(mat)
    return obj


def light(kind, location, energy, rotation=(0.0, 0.0, 0.0), **props):
    data = bpy.data.lights.new(kind.lower(), kind)
    data.energy = energy
    for key, value in props.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(kind.lower(), data)
    obj.location = location
    obj.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(obj)
    return obj


def top_camera(scene, height=6.0, lens=35.0, location=(0.0, 0.0), tilt=0.0):
    cam = scene.camera
    cam.location = (location[0], location[1], height)
    cam.rotation_euler = (tilt, 0.0, 0.0)
    cam.data.lens = lens
    small_resolution(scene, WIDTH, HEIGHT)
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.use_nodes and 'Background' in scene.world.node_tree.nodes:
        scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)


# ----------------------------------------------------------------------------
# Scenes


def glass_material(name, roughness=0.0, ior=None):
    """A Glass BSDF material (Blender's default distribution; IOR left at
    the node's default when None)."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    node = nodes.new('ShaderNodeBsdfGlass')
    node.inputs['Roughness'].default_value = roughness
    if ior is not None:
        node.inputs['IOR'].default_value = ior
    mat.node_tree.links.new(node.outputs[0], nodes.new('ShaderNodeOutputMaterial').inputs['Surface'])
    return mat


def smooth_sphere(name, mat, location, radius=0.5, segments=32, rings=16):
    """A smooth-shaded UV sphere with the material."""
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=location, segments=segments, ring_count=rings)
    obj = bpy.context.active_object
    obj.name = name
    bpy.ops.object.shade_smooth()
    obj.data.materials.append(mat)
    return obj


def ortho_grid_scene(grid, rows, tile):
    """An empty factory scene seen from above by an orthographic camera
    over a grid x rows field of unit cells (tile pixels each), under one
    area light, with a black world."""
    from ember_testlib import small_resolution
    bpy.ops.wm.read_factory_settings()
    for obj in list(bpy.data.objects):
        bpy.data.objects.remove(obj)
    scene = bpy.context.scene
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = 'ORTHO'
    cam_data.ortho_scale = grid
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (grid / 2, rows / 2, 5.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    light_data = bpy.data.lights.new("area", 'AREA')
    light_data.size = 6.0
    light_data.energy = 400.0
    light = bpy.data.objects.new("area", light_data)
    light.location = (grid / 2 + 1.0, rows / 2 - 0.5, 3.0)
    scene.collection.objects.link(light)
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.node_tree is not None:
        scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)
    small_resolution(scene, grid * tile, rows * tile)
    return scene


def particle_hair(obj, count, hair_material_index=2, distribution=None, seed=1):
    """Particle hair on ``obj``: ``count`` strands 0.4 long, radius 0.02 x
    (1 at the root, 0.3 at the tip), in the object's material slot
    ``hair_material_index``; ``distribution`` None keeps Blender's default
    (Jittered)."""
    psys = obj.modifiers.new('hair', 'PARTICLE_SYSTEM').particle_system
    psys.seed = seed
    settings = psys.settings
    settings.type = 'HAIR'
    settings.count = count
    settings.hair_length = 0.4
    settings.radius_scale = 0.02
    settings.root_radius, settings.tip_radius = 1.0, 0.3
    settings.material = hair_material_index
    if distribution is not None:
        settings.distribution = distribution
    return psys


def hair_curves(scene, points, radii, keys, curves, color=(0.7, 0.45, 0.2)):
    """A Curves object of ``curves`` strands of ``keys`` points each
    (``points`` (curves, keys, 3), ``radii`` per point), diffuse ``color``."""
    import numpy as np
    data = bpy.data.hair_curves.new("strands")
    data.add_curves([keys] * curves)
    data.attributes['position'].data.foreach_set('vector', np.asarray(points, np.float32).reshape(-1))
    radius = data.attributes.new('radius', 'FLOAT', 'POINT')
    radius.data.foreach_set('value', np.asarray(radii, np.float32))
    data.materials.append(material("hair", 'diffuse', color=color))
    obj = bpy.data.objects.new("strands", data)
    scene.collection.objects.link(obj)
    return obj
