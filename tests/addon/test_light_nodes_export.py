"""Export of light node trees (addon/export/light.py): a tree that varies
over the light becomes the engine light's ``shader`` (evaluated per light
point, engine/lights/shader.py) with the light's own power; a constant tree
keeps the fast path (the power scaled, no shader); suns get theirs too
(evaluated per direction) with their object matrix; Object Info reads the
light object (a tree of Object Info alone is constant: the fast path); nodes
Ember evaluates otherwise than Cycles on a light are named in the light's
warning."""
import bpy
import numpy as np
import pytest

from addon.export import scene as scene_export


def export():
    return scene_export.export_scene(bpy.context.evaluated_depsgraph_get())


def textured_light(scene, kind, source=('ShaderNodeTexCoord', 'UV'), **settings):
    data = bpy.data.lights.new(kind, kind)
    for key, value in settings.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(kind, data)
    obj.location = (0.5, -0.3, 2.0)
    scene.collection.objects.link(obj)
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    if source is not None:
        node = tree.nodes.new(source[0])
        checker = tree.nodes.new('ShaderNodeTexChecker')
        tree.links.new(node.outputs[source[1]], checker.inputs['Vector'])
        tree.links.new(checker.outputs['Color'], emission.inputs['Color'])
    bpy.context.view_layer.update()
    return obj, tree, emission


@pytest.mark.parametrize("kind", ['POINT', 'SPOT', 'AREA'])
def test_varying_tree_becomes_the_light_shader(empty_scene, kind):
    obj, _, _ = textured_light(empty_scene, kind, energy=50.0, color=(1.0, 0.5, 0.25))
    exported = export()
    (light,) = exported.scene.lights
    assert light.shader is not None
    assert light.power == pytest.approx((50.0, 25.0, 12.5))        # the tree is not folded in
    assert not [w for w in exported.warnings if 'Light' in w], exported.warnings
    if kind != 'AREA':
        np.testing.assert_allclose(light.matrix, np.array(obj.matrix_world))


def test_constant_tree_keeps_the_fast_path(empty_scene):
    _, tree, emission = textured_light(empty_scene, 'POINT', source=None, energy=10.0)
    blackbody = tree.nodes.new('ShaderNodeBlackbody')
    blackbody.inputs['Temperature'].default_value = 2000.0
    tree.links.new(blackbody.outputs['Color'], emission.inputs['Color'])
    emission.inputs['Strength'].default_value = 2.0
    (light,) = export().scene.lights
    assert light.shader is None
    assert light.power[0] > 2 * light.power[2] > 0      # 2000 K, folded into the power


def test_sun_tree_becomes_the_sun_shader(empty_scene):
    obj, _, _ = textured_light(empty_scene, 'SUN', energy=3.0, angle=0.5)
    exported = export()
    (sun,) = exported.scene.lights
    assert sun.shader is not None and sun.strength == pytest.approx((3.0, 3.0, 3.0))
    np.testing.assert_allclose(sun.matrix, np.array(obj.matrix_world))
    assert not [w for w in exported.warnings if 'Light' in w], exported.warnings


def test_object_info_reads_the_light_object(empty_scene):
    """Object Info's Color and Alpha on a light are its object's: constant
    over the light, so folded into the power (no shader, no warning)."""
    obj, tree, emission = textured_light(empty_scene, 'POINT', source=None, energy=10.0)
    obj.color = (0.5, 0.25, 1.0, 0.8)
    info = tree.nodes.new('ShaderNodeObjectInfo')
    tree.links.new(info.outputs['Color'], emission.inputs['Color'])
    bpy.context.view_layer.update()
    exported = export()
    (light,) = exported.scene.lights
    assert light.shader is None
    assert light.power == pytest.approx((5.0, 2.5, 10.0))
    assert not [w for w in exported.warnings if 'Light' in w], exported.warnings


def test_nodes_evaluated_otherwise_on_lights_are_named(empty_scene):
    """A node output Ember does not evaluate (Object Info's Material Index)
    is named with the light; Ray Depth, which it evaluates per light point
    as Cycles (test_light_tree_path_parity), and Is Volume Scatter Ray,
    read from the ray's kind as Is Diffuse Ray, are not."""
    _, tree, emission = textured_light(empty_scene, 'AREA', energy=10.0)
    path = tree.nodes.new('ShaderNodeLightPath')
    mix = tree.nodes.new('ShaderNodeMix')
    mix.data_type = 'RGBA'
    tree.links.new(emission.inputs['Color'].links[0].from_socket, mix.inputs[6])
    tree.links.new(path.outputs['Ray Depth'], mix.inputs[0])
    tree.links.new(mix.outputs[2], emission.inputs['Color'])
    exported = export()
    assert exported.scene.lights[0].shader is not None
    assert not [w for w in exported.warnings if "Ray Depth" in w], exported.warnings
    tree.links.new(path.outputs['Is Volume Scatter Ray'], mix.inputs[0])
    exported = export()
    assert exported.scene.lights[0].shader is not None
    assert not [w for w in exported.warnings if "Is Volume Scatter Ray" in w], exported.warnings
    tree.links.new(tree.nodes.new('ShaderNodeObjectInfo').outputs['Material Index'], mix.inputs[0])
    exported = export()
    assert exported.scene.lights[0].shader is not None
    assert [w for w in exported.warnings if "Light 'AREA'" in w and "Material Index" in w], exported.warnings
