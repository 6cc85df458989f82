"""Small scenes built with bpy for the Cycles parity tests (a helper module:
test modules do not import each other)."""
import bpy

from ember_testlib import small_resolution

WIDTH, HEIGHT = 32, 24   # the light and transparency parity frames


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
