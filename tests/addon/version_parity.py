"""One scene, rendered by Ember in every bpy version of the test matrix, must
give bpy 5.0's pixels.

The scene is built by script from the parts whose Python API moved between
Blender 4.2 and 5.3: a Principled BSDF with the 4.0 socket names (Coat,
Sheen, Specular IOR Level), Glossy (an Anisotropic node inside 5.0), Mix
Shader, Noise Texture into a Color Ramp, a generated image through a UV map,
a colour attribute, smooth shading under a Subdivision modifier, geometry-nodes
instances (the 4.0 node-group interface), the four light types (Blender 4.0+
light units), a node world and a camera with depth of field.

Ember's random numbers depend only on the seed, the pass and the pixel batch
(batches follow the thread count, fixed here), so the same export gives the
same pixels up to float rounding: any larger difference is an export (API)
difference between the versions.  bpy 5.0's Ember is held to converged
Cycles by the suite's parity tests, so a version that renders this scene as
5.0 does carries that parity for everything the scene uses.

Also: the inputs Blender added after 5.0 that Ember does not render (5.2:
Principled Thin Wall; 5.3: Principled Dispersion, Glass Anisotropy) are named
in warnings.

Not collected by itself (no test_ prefix): tests/addon/test_other_blenders.py
renders the expected image in bpy 5.0 (``render_scene``), then runs this file
in each other version's interpreter with ``EMBER_EXPECTED_RENDER`` naming the
expected .npz.
"""
import math
import os

import bpy
import numpy as np

from ember_testlib import render_array, require, setup_ember, small_resolution

WIDTH, HEIGHT = 48, 36
SAMPLES, SEED, BOUNCES, THREADS = 16, 7, 4, 2
# Largest pixel difference allowed, relative to the image's largest value, as
# for the Blender 3.4 binary (test_other_blenders).  Measured against bpy 5.0:
# 0 (4.5) and 2.7e-8 (5.1-5.3, numpy 2.2) with the compiled kernels, 5e-8 and
# 8e-8 with EMBER_JIT=0 on both sides; expected pixels scaled by 1.001 fail at
# 1.0e-3.
TOLERANCE = 1e-5


def _node_material(name):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.clear()
    return mat, nodes, mat.node_tree.links, nodes.new('ShaderNodeOutputMaterial')


def _principled():
    mat, nodes, links, out = _node_material('VP Principled')
    bsdf = nodes.new('ShaderNodeBsdfPrincipled')
    values = {'Base Color': (0.7, 0.25, 0.1, 1.0), 'Roughness': 0.35, 'Metallic': 0.0,
              'Coat Weight': 0.4, 'Coat Roughness': 0.1, 'Sheen Weight': 0.3,
              'Specular IOR Level': 0.6}
    for socket, value in values.items():
        bsdf.inputs[socket].default_value = value
    links.new(bsdf.outputs[0], out.inputs['Surface'])
    return mat


def _mixed():
    """Mix of a Diffuse coloured by Noise -> Color Ramp and a GGX Glossy."""
    mat, nodes, links, out = _node_material('VP Mixed')
    noise = nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 3.0
    ramp = nodes.new('ShaderNodeValToRGB')
    ramp.color_ramp.elements[0].color = (0.1, 0.3, 0.6, 1.0)
    ramp.color_ramp.elements[1].color = (0.9, 0.8, 0.3, 1.0)
    diffuse = nodes.new('ShaderNodeBsdfDiffuse')
    glossy = nodes.new('ShaderNodeBsdfGlossy')
    glossy.distribution = 'GGX'
    glossy.inputs['Roughness'].default_value = 0.3
    mix = nodes.new('ShaderNodeMixShader')
    mix.inputs['Fac'].default_value = 0.3
    links.new(noise.outputs['Fac'], ramp.inputs['Fac'])
    links.new(ramp.outputs['Color'], diffuse.inputs['Color'])
    links.new(diffuse.outputs[0], mix.inputs[1])
    links.new(glossy.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs['Surface'])
    return mat


def _image_floor():
    """Diffuse with a generated colour grid through the UV map."""
    mat, nodes, links, out = _node_material('VP Floor')
    image = bpy.data.images.new('VP Grid', 16, 16)
    image.generated_type = 'COLOR_GRID'
    tex = nodes.new('ShaderNodeTexImage')
    tex.image = image
    tex.interpolation = 'Closest'
    uv = nodes.new('ShaderNodeUVMap')
    diffuse = nodes.new('ShaderNodeBsdfDiffuse')
    links.new(uv.outputs['UV'], tex.inputs['Vector'])
    links.new(tex.outputs['Color'], diffuse.inputs['Color'])
    links.new(diffuse.outputs[0], out.inputs['Surface'])
    return mat


def _vertex_colours():
    """Diffuse coloured by a colour attribute."""
    mat, nodes, links, out = _node_material('VP Colours')
    attribute = nodes.new('ShaderNodeVertexColor')
    attribute.layer_name = 'VP Col'
    diffuse = nodes.new('ShaderNodeBsdfDiffuse')
    links.new(attribute.outputs['Color'], diffuse.inputs['Color'])
    links.new(diffuse.outputs[0], out.inputs['Surface'])
    return mat


def _emission(colour, strength):
    mat, nodes, links, out = _node_material('VP Emission')
    emission = nodes.new('ShaderNodeEmission')
    emission.inputs['Color'].default_value = (*colour, 1.0)
    emission.inputs['Strength'].default_value = strength
    links.new(emission.outputs[0], out.inputs['Surface'])
    return mat


def _instances(material):
    """A geometry-nodes object: small ico spheres on the points of a grid."""
    mesh = bpy.data.meshes.new('VP Instancer')
    obj = bpy.data.objects.new('VP Instancer', mesh)
    bpy.context.scene.collection.objects.link(obj)
    tree = bpy.data.node_groups.new('VP Instances', 'GeometryNodeTree')
    tree.interface.new_socket('Geometry', in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket('Geometry', in_out='OUTPUT', socket_type='NodeSocketGeometry')
    nodes, links = tree.nodes, tree.links
    nodes.new('NodeGroupInput')
    output = nodes.new('NodeGroupOutput')
    grid = nodes.new('GeometryNodeMeshGrid')
    grid.inputs['Size X'].default_value = 2.0
    grid.inputs['Size Y'].default_value = 0.6
    grid.inputs['Vertices X'].default_value = 3
    grid.inputs['Vertices Y'].default_value = 2
    ico = nodes.new('GeometryNodeMeshIcoSphere')
    ico.inputs['Radius'].default_value = 0.15
    ico.inputs['Subdivisions'].default_value = 2
    set_material = nodes.new('GeometryNodeSetMaterial')
    set_material.inputs['Material'].default_value = material
    instance = nodes.new('GeometryNodeInstanceOnPoints')
    links.new(ico.outputs['Mesh'], set_material.inputs['Geometry'])
    links.new(grid.outputs['Mesh'], instance.inputs['Points'])
    links.new(set_material.outputs['Geometry'], instance.inputs['Instance'])
    links.new(instance.outputs['Instances'], output.inputs[0])
    modifier = obj.modifiers.new('VP Nodes', 'NODES')
    modifier.node_group = tree
    obj.location = (0.2, 2.2, 0.2)
    return obj


def _light(kind, location, energy, rotation=(0.0, 0.0, 0.0), **props):
    data = bpy.data.lights.new('VP ' + kind.lower(), kind)
    data.energy = energy
    for key, value in props.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new('VP ' + kind.lower(), data)
    obj.location = location
    obj.rotation_euler = rotation
    bpy.context.scene.collection.objects.link(obj)
    return obj


def build_scene():
    """The scene above, in an empty factory scene; returns the Blender scene."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    bpy.ops.mesh.primitive_plane_add(size=6.0)
    bpy.context.active_object.data.materials.append(_image_floor())
    bpy.ops.mesh.primitive_uv_sphere_add(segments=24, ring_count=12, radius=0.6, location=(-0.9, 0.0, 0.6))
    sphere = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    sphere.data.materials.append(_principled())
    bpy.ops.mesh.primitive_cube_add(size=0.9, location=(0.8, -0.2, 0.45), rotation=(0.0, 0.0, 0.5))
    cube = bpy.context.active_object
    cube.modifiers.new('VP Subdivision', 'SUBSURF').levels = 1
    bpy.ops.object.shade_smooth()
    cube.data.materials.append(_mixed())
    bpy.ops.mesh.primitive_cube_add(size=0.5, location=(-0.2, -1.2, 0.25))
    coloured = bpy.context.active_object
    colours = coloured.data.color_attributes.new('VP Col', 'FLOAT_COLOR', 'POINT')
    for i, value in enumerate(colours.data):
        value.color = (0.2 + 0.6 * (i & 1), 0.2 + 0.3 * ((i >> 1) & 1), 0.2 + 0.6 * ((i >> 2) & 1), 1.0)
    coloured.data.materials.append(_vertex_colours())
    _instances(_emission((1.0, 0.6, 0.3), 2.0))
    _light('POINT', (2.0, -2.0, 3.0), 300.0, shadow_soft_size=0.3)
    _light('SPOT', (-2.5, -1.5, 3.5), 600.0, (math.radians(35), 0.0, math.radians(-60)),
           spot_size=math.radians(50), spot_blend=0.3, shadow_soft_size=0.2)
    _light('AREA', (0.0, 2.5, 2.5), 200.0, (math.radians(-45), 0.0, 0.0), shape='DISK', size=1.0)
    _light('SUN', (0.0, 0.0, 5.0), 1.5, (math.radians(40), 0.0, math.radians(30)), angle=math.radians(5))
    world = bpy.data.worlds.new('VP World')
    world.use_nodes = True
    background = next(n for n in world.node_tree.nodes if n.type == 'BACKGROUND')
    background.inputs['Color'].default_value = (0.05, 0.07, 0.1, 1.0)
    background.inputs['Strength'].default_value = 1.0
    scene.world = world
    camera_data = bpy.data.cameras.new('VP Camera')
    camera_data.lens = 35.0
    camera_data.dof.use_dof = True
    camera_data.dof.focus_distance = 5.5
    camera_data.dof.aperture_fstop = 4.0
    camera = bpy.data.objects.new('VP Camera', camera_data)
    camera.location = (0.0, -5.0, 2.6)
    camera.rotation_euler = (math.radians(64), 0.0, 0.0)
    scene.collection.objects.link(camera)
    scene.camera = camera
    small_resolution(scene, WIDTH, HEIGHT)
    setup_ember(scene, SAMPLES, SEED, BOUNCES)
    scene.ember.threads = THREADS
    return scene


def exported_summary(scene):
    """What the export made of the scene, as plain numbers."""
    from addon.export import scene as scene_export
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    return {'triangles': int(exported.triangles), 'lights': len(exported.scene.lights),
            'warnings': len(exported.warnings)}, exported.warnings


def render_scene(folder):
    """(RGBA image, export summary, export warnings) of the scene in this Blender."""
    scene = build_scene()
    summary, warnings = exported_summary(scene)
    image = render_array(scene, folder, 'version_parity')
    from addon import engine as ember_engine
    assert ember_engine.RENDER_LOG[-1]['error'] is None, ember_engine.RENDER_LOG[-1]['error']
    return image, summary, warnings


def save_expected(path, folder):
    image, summary, warnings = render_scene(folder)
    np.savez(path, image=image, version=np.array(bpy.app.version), **{k: np.array(v) for k, v in summary.items()})
    return image, summary, warnings


def test_renders_as_in_bpy_50(tmp_path, registered_addon, needs_engine):
    expected_path = os.environ.get('EMBER_EXPECTED_RENDER')
    require(bool(expected_path) and os.path.exists(expected_path),
            "EMBER_EXPECTED_RENDER must name bpy 5.0's render of this scene (tests/addon/test_other_blenders.py)")
    expected = np.load(expected_path)
    image, summary, warnings = render_scene(tmp_path)
    assert warnings == [], warnings
    for key, value in summary.items():
        assert value == int(expected[key]), (key, value, int(expected[key]))
    reference = expected['image']
    assert image.shape == reference.shape and np.isfinite(image).all()
    assert reference[..., :3].mean() > 0.02, "the expected image is black"
    difference = float(np.abs(image - reference).max() / max(float(np.abs(reference).max()), 1e-6))
    print(f"Blender {bpy.app.version_string} against bpy {tuple(int(v) for v in expected['version'])}: largest relative pixel "
          f"difference {difference:.2e} (allowed {TOLERANCE:.0e}); {summary}")
    assert difference < TOLERANCE


# Inputs Blender added after 5.0 that Ember does not render: set, they must be
# named in the export's warnings (node type, input, value set, word the warning
# carries, the first Blender that has it).
NEW_INPUTS = [('ShaderNodeBsdfPrincipled', 'Thin Wall', True, 'Thin Wall', (5, 2, 0)),
              ('ShaderNodeBsdfPrincipled', 'Transmission Dispersion Scale', 0.5, 'Dispersion', (5, 3, 0)),
              ('ShaderNodeBsdfGlass', 'Anisotropy', 0.5, 'Anisotropy', (5, 3, 0))]


def test_inputs_newer_than_50_are_named_when_used(registered_addon):
    from addon.export import scene as scene_export
    present = 0
    for node_type, name, value, word, _ in NEW_INPUTS:
        bpy.ops.wm.read_factory_settings()
        mat, nodes, links, out = _node_material('VP New Input')
        node = nodes.new(node_type)
        links.new(node.outputs[0], out.inputs['Surface'])
        bpy.data.objects['Cube'].data.materials.append(mat)
        if name not in node.inputs:
            continue
        present += 1
        clean = scene_export.export_scene(bpy.context.evaluated_depsgraph_get()).warnings
        node.inputs[name].default_value = value
        warned = scene_export.export_scene(bpy.context.evaluated_depsgraph_get()).warnings
        assert not any(word in w for w in clean), clean
        assert any('VP New Input' in w and word in w for w in warned), (node_type, name, warned)
    assert present == sum(bpy.app.version >= since for *_, since in NEW_INPUTS), present
