"""The Environment Texture node on objects' materials (issue 23), against
live Cycles.

Cycles' node (scene/shader_nodes.cpp EnvironmentTextureNode) declares its
Vector LINK_POSITION: unlinked, it reads the shading point's world position,
normalized into a direction (kernel/svm/image.h svm_node_tex_environment),
then the equirectangular or mirror-ball projection, REPEAT, the image's
interpolation.  The scene: a plane below the origin (unlinked Vector,
equirectangular: its points' directions from the origin), a sphere whose
Vector is Geometry > Normal (equirectangular) and one whose Vector is a
rotated Mapping of the Object coordinates (mirror ball, Closest), all
Emission, camera rays only, so the image is the texture's lookups blurred
by the pixel filter; a random float image (row 0 = the bottom, Blender's
order) makes a shifted or mirrored lookup read other values.
"""
import math

import bpy
import numpy as np

from ember_testlib import ReferenceCheck, live_cycles_reference, render_for_reference, small_resolution
from parity_scenes import empty_material

EMBER_SPP, CYCLES_SEEDS, CYCLES_SPP, BLOCK = 64, 4, 32, 8
IMAGE_SIZE = (32, 16)


def env_image():
    w, h = IMAGE_SIZE
    image = bpy.data.images.new("env_node", w, h, alpha=True, float_buffer=True)
    px = np.ones((h, w, 4), np.float32)
    px[..., :3] = 0.1 + np.random.default_rng(7).random((h, w, 3))
    image.pixels.foreach_set(px.ravel())
    return image, px


def env_material(name, image, projection='EQUIRECTANGULAR', interpolation='Linear', vector=None):
    """Emission of an Environment Texture; ``vector(tree)`` -> the output
    socket linked to its Vector (None: unlinked)."""
    mat, tree, out = empty_material(name)
    emission = tree.nodes.new('ShaderNodeEmission')
    env = tree.nodes.new('ShaderNodeTexEnvironment')
    env.image, env.projection, env.interpolation = image, projection, interpolation
    tree.links.new(env.outputs['Color'], emission.inputs['Color'])
    tree.links.new(emission.outputs[0], out.inputs['Surface'])
    if vector is not None:
        tree.links.new(vector(tree), env.inputs['Vector'])
    return mat


def geometry_normal(tree):
    return tree.nodes.new('ShaderNodeNewGeometry').outputs['Normal']


def rotated_object_coords(tree):
    coords = tree.nodes.new('ShaderNodeTexCoord')
    mapping = tree.nodes.new('ShaderNodeMapping')
    mapping.inputs['Rotation'].default_value = (0.3, -0.5, 1.1)
    tree.links.new(coords.outputs['Object'], mapping.inputs['Vector'])
    return mapping.outputs['Vector']


def build(scene):
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.node_tree is not None:
        scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0.0, 0.0, 0.0, 1.0)
    image, _ = env_image()
    bpy.ops.mesh.primitive_plane_add(size=12.0, location=(0.0, 1.0, -1.0))
    bpy.context.active_object.data.materials.append(env_material("env_unlinked", image))
    for location, mat in (((-1.2, 0.0, 0.2), env_material("env_normal", image, vector=geometry_normal)),
                          ((1.3, 0.5, 0.4), env_material("env_ball", image, 'MIRROR_BALL', 'Closest',
                                                         rotated_object_coords))):
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.9, location=location, segments=32, ring_count=16)
        bpy.ops.object.shade_smooth()
        bpy.context.active_object.data.materials.append(mat)
    camera = scene.camera
    camera.location = (0.0, -6.5, 3.0)
    camera.rotation_euler = (math.radians(66.0), 0.0, 0.0)
    camera.data.lens = 32.0
    small_resolution(scene, 48, 32)


def image_texture(expr):
    """The ImageTexture inside an emission (colour x strength)."""
    while type(expr).__name__ == 'MixColor':
        expr = expr.a if type(expr.a).__name__ in ('ImageTexture', 'MixColor') else expr.b
    return expr


def test_environment_node_exports_without_warnings(factory_scene, needs_engine):
    from addon.export import scene as scene_export
    build(factory_scene)
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    assert not [w for w in exported.warnings if 'Environment' in w or 'env' in w], exported.warnings
    textures = {m.name: image_texture(m.emission) for m in exported.scene.materials}
    plane, ball = textures['env_unlinked'], textures['env_ball']
    assert type(plane).__name__ == 'ImageTexture' and plane.projection == 'EQUIRECTANGULAR' and plane.uv is None
    assert ball.projection == 'MIRROR_BALL' and ball.uv is not None and ball.interpolation == 'Closest'
    _, px = env_image()
    np.testing.assert_allclose(plane.image.pixels[..., :3], px[::-1, :, :3], rtol=0, atol=0)


def test_environment_node_on_objects_matches_cycles(tmp_path, tapped_engine):
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    build(scene)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, "env_node", CYCLES_SEEDS, CYCLES_SPP, 0)
    image, var = render_for_reference(scene, tmp_path, "env_node", tapped_engine, EMBER_SPP, 3, 0)
    image, var = image[..., :3].astype(np.float64), var[..., :3]
    print(f"environment node: Ember mean {image.mean():.5g}, Cycles {ref.mean():.5g} "
          f"(ratio {image.mean() / ref.mean():.5f})")
    check = ReferenceCheck("environment_node", image, var, EMBER_SPP, ref, ref_var, header, BLOCK)
    check.assert_agrees(0.005, 0.03)
