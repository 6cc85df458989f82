"""Cycles parity of the Light Falloff node on lights (engine/lights/common.py
Falloff; the add-on reads it in addon/export/light.py): a point light whose
Emission Strength comes through Light Falloff's Linear output and a disk
light through its Constant output with Smooth, over a diffuse floor, against
a converged Cycles reference (tools/cycles_references.py light_falloff), as
tests/addon/test_light_parity.py compares its scenes.  Beside the
comparison, Ember's own image must differ from the same lights without the
node (the falloff has its effect)."""
from parity_scenes import light, material, plane, top_camera
from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference

BLOCK = 8
SPP = 768   # 512 resolved 0.53 % of the image, not 0.5 % (the channel sum's variance)


def _falloff(obj, output, strength, smooth=0.0):
    """Feed the light's Emission Strength through a Light Falloff node."""
    data = obj.data
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    node = tree.nodes.new('ShaderNodeLightFalloff')
    node.inputs['Strength'].default_value = strength
    node.inputs['Smooth'].default_value = smooth
    tree.links.new(node.outputs[output], emission.inputs['Strength'])


def falloff(scene, with_nodes=True):
    """A point light (Linear) and a disk light (Constant, Smooth 0.5) low
    over a floor: their light falls off as 1/d and not at all."""
    plane("floor", material("floor", 'diffuse'))
    point = light('POINT', (-0.9, 0.0, 0.8), 60.0, shadow_soft_size=0.1)
    disk = light('AREA', (0.9, 0.0, 0.7), 40.0, shape='DISK', size=0.6)
    if with_nodes:
        _falloff(point, 'Linear', 1.5)
        _falloff(disk, 'Constant', 1.0, 0.5)
    top_camera(scene, 4.0)
    return 1


SCENES = {'falloff': falloff}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_light_falloff_parity_with_cycles(tmp_path, tapped_engine):
    scene, bounces = reference_scene('falloff')
    image, var = render_for_reference(scene, tmp_path, 'falloff', tapped_engine, SPP, 2, bounces)
    check = check_against_reference('light_falloff', scene, bounces, image, var, SPP, BLOCK)
    plain = empty_factory_scene()
    falloff(plain, with_nodes=False)
    without, _ = render_for_reference(plain, tmp_path, 'no_falloff', tapped_engine, 64, 2, bounces)
    ratio = image[..., :3].mean() / without[..., :3].mean()
    print(f"light_falloff: image mean with the nodes / without: {ratio:.3f}")
    assert abs(ratio - 1.0) > 0.1, f"the Light Falloff nodes change nothing (ratio {ratio:.3f})"
    check.assert_agrees(0.005, 0.02)
