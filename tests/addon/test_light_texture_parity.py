"""Cycles parity of light node trees that vary over the light (issue 23;
engine/lights/shader.py, read by addon/export/light.py): one scene, one
converged reference (tools/cycles_references.py light_textures), with

* an area light (rectangle, seen by the camera) whose Emission Color is a
  Checker Texture on its Texture Coordinate UV: the camera sees the checker
  on the light (BSDF-ray hits) and the floor is lit by it (light samples);
* a point light (soft falloff, Blender's default) whose colour is a
  Checker on the Geometry node's Incoming: it projects the pattern onto the
  floor;
* a sphere light (soft falloff off, seen by the camera) whose colour is a
  Checker on the Texture Coordinate Normal at Emission Strength 1.5,
* a spot light whose colour is a Checker on its UV (Cycles' spot_light_uv):
  a gobo projecting the checker onto the floor,

over a diffuse floor: the whole image, its quadrants and every block
against Cycles (two statistical families), power printed and asserted.
Beside it Ember's image must differ from the same lights with their mean
colours (the texture has its effect, not only its average)."""
import math

from parity_scenes import box, light, material, plane
from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference, small_resolution

WIDTH, HEIGHT = 48, 32
BLOCK = 8
SPP = 3072
COLOURS = ((1.0, 0.25, 0.05, 1.0), (0.05, 0.3, 1.0, 1.0))


def _checker(obj, node_type, output, scale, strength=1.0):
    """The light's Emission Color from a Checker on node_type's output."""
    data = obj.data
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    emission.inputs['Strength'].default_value = strength
    source = tree.nodes.new(node_type)
    checker = tree.nodes.new('ShaderNodeTexChecker')
    checker.inputs['Scale'].default_value = scale
    checker.inputs['Color1'].default_value = COLOURS[0]
    checker.inputs['Color2'].default_value = COLOURS[1]
    tree.links.new(source.outputs[output], checker.inputs['Vector'])
    tree.links.new(checker.outputs['Color'], emission.inputs['Color'])


def _view(scene, location, rotation, lens):
    """The camera, the small resolution and a black world; returns the bounces (2)."""
    cam = scene.camera
    cam.location = location
    cam.rotation_euler = rotation
    cam.data.lens = lens
    small_resolution(scene, WIDTH, HEIGHT)
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.node_tree is not None and 'Background' in scene.world.node_tree.nodes:
        scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)
    return 2


def light_textures(scene, textured=True):
    plane("floor", material("floor", 'diffuse'))
    area = light('AREA', (-0.9, 0.4, 0.9), 30.0, rotation=(-1.0, 0.0, 0.3), shape='RECTANGLE', size=1.2,
                 size_y=0.8)
    area.visible_camera = True
    point = light('POINT', (1.1, 0.6, 0.7), 60.0, shadow_soft_size=0.25)
    sphere = light('POINT', (0.6, -0.9, 0.5), 25.0, shadow_soft_size=0.2, use_soft_falloff=False)
    sphere.visible_camera = True
    spot = light('SPOT', (-0.6, -0.8, 1.4), 80.0, rotation=(0.25, -0.2, 0.4), shadow_soft_size=0.05,
                 spot_size=0.9, spot_blend=0.1)
    if textured:
        _checker(area, 'ShaderNodeTexCoord', 'UV', 3.0)
        _checker(point, 'ShaderNodeNewGeometry', 'Incoming', 2.5)
        _checker(sphere, 'ShaderNodeTexCoord', 'Normal', 2.0, strength=1.5)
        _checker(spot, 'ShaderNodeTexCoord', 'UV', 4.0)          # a gobo: the checker projected
    else:
        mean = tuple(0.5 * (a + b) for a, b in zip(*COLOURS))[:3]
        for obj, strength in ((area, 1.0), (point, 1.0), (sphere, 1.5), (spot, 1.0)):
            obj.data.color = mean
            obj.data.energy *= strength
    return _view(scene, (0.0, -3.2, 2.6), (math.atan2(3.4, 2.3), 0.0, 0.0), 30.0)


def _light_inputs(obj, output_of, strength=1.0):
    """The light's Emission Color from output_of(tree): the node output."""
    data = obj.data
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    emission.inputs['Strength'].default_value = strength
    tree.links.new(output_of(tree), emission.inputs['Color'])


def _vector_math(tree, operation, socket, value=None):
    node = tree.nodes.new('ShaderNodeVectorMath')
    node.operation = operation
    tree.links.new(socket, node.inputs[0])
    if value is not None:
        node.inputs[1].default_value = value
    return node.outputs['Vector']


def _window(tree):
    return tree.nodes.new('ShaderNodeTexCoord').outputs['Window']


def _camera_abs(tree):
    return _vector_math(tree, 'ABSOLUTE', tree.nodes.new('ShaderNodeTexCoord').outputs['Camera'])


def _ray_length(tree):
    """Colour (1, 0.5, 0.2) x Ray Length: a 1/d falloff instead of 1/d^2."""
    node = tree.nodes.new('ShaderNodeMath')
    node.operation = 'MULTIPLY'
    tree.links.new(tree.nodes.new('ShaderNodeLightPath').outputs['Ray Length'], node.inputs[0])
    node.inputs[1].default_value = 1.0
    mix = tree.nodes.new('ShaderNodeMix')
    mix.data_type = 'RGBA'
    mix.blend_type = 'MULTIPLY'
    mix.inputs[0].default_value = 1.0
    tree.links.new(node.outputs[0], mix.inputs[6])
    mix.inputs[7].default_value = (1.0, 0.5, 0.2, 1.0)
    return mix.outputs[2]


def _sun_uv_checker(tree):
    coord = tree.nodes.new('ShaderNodeTexCoord')
    checker = tree.nodes.new('ShaderNodeTexChecker')
    checker.inputs['Scale'].default_value = 3.0
    checker.inputs['Color1'].default_value = COLOURS[0]
    checker.inputs['Color2'].default_value = COLOURS[1]
    tree.links.new(coord.outputs['UV'], checker.inputs['Vector'])
    return checker.outputs['Color']


def _sun_incoming(tree):
    """|Incoming| + 0.1 per channel: Incoming is the direction the sun's light travels."""
    incoming = tree.nodes.new('ShaderNodeNewGeometry').outputs['Incoming']
    return _vector_math(tree, 'ADD', _vector_math(tree, 'ABSOLUTE', incoming), (0.1, 0.1, 0.1))


def light_inputs(scene, textured=True):
    """Suns evaluated per direction and the light-point inputs of issue 23:
    a wide sun seen by the camera (Checker on its UV) over a floor with a
    box casting its penumbra, a second sun (|Incoming| + 0.1) from the
    side, an area light seen by the camera coloured by its Window
    coordinates, a point light by |Camera| and a sphere light whose colour
    is scaled by Light Path's Ray Length."""
    plane("floor", material("floor", 'diffuse'))
    box("box", material("box", 'diffuse', color=(0.6, 0.6, 0.6)), (0.0, 1.2, 0.35), (0.7, 0.7, 0.7))
    sun = light('SUN', (0.0, 0.0, 3.0), 2.0, rotation=(-math.radians(70.0), 0.0, 0.3), angle=0.6)
    sun.visible_camera = True
    side = light('SUN', (1.0, 0.0, 3.0), 1.0, rotation=(0.0, math.radians(55.0), 0.4), angle=0.3)
    area = light('AREA', (-1.4, 0.8, 0.9), 20.0, rotation=(-1.2, 0.0, -0.4), size=0.8)
    area.visible_camera = True
    point = light('POINT', (1.2, -0.4, 0.8), 30.0, shadow_soft_size=0.2)
    sphere = light('POINT', (-0.6, -0.8, 0.6), 15.0, shadow_soft_size=0.15, use_soft_falloff=False)
    if textured:
        _light_inputs(sun, _sun_uv_checker)
        _light_inputs(side, _sun_incoming)
        _light_inputs(area, _window)
        _light_inputs(point, _camera_abs)
        _light_inputs(sphere, _ray_length)
    return _view(scene, (0.0, -2.6, 1.1), (math.radians(97.0), 0.0, 0.0), 20.0)


SCENES = {'light_textures': light_textures, 'light_inputs': light_inputs}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def _check_scene(name, seed, tmp_path, taps):
    """Scene ``name`` by Ember against its Cycles reference (no light
    warning allowed), and against the same scene with untextured lights,
    which must differ by over 10 % per pixel (the trees have their effect)."""
    scene, bounces = reference_scene(name)
    image, var = render_for_reference(scene, tmp_path, name, taps, SPP, seed, bounces)
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1].get('warnings', ())
    assert not [w for w in warnings if 'Light' in w], warnings
    check = check_against_reference(name, scene, bounces, image, var, SPP, BLOCK)
    plain = empty_factory_scene()
    SCENES[name](plain, textured=False)
    mean, _ = render_for_reference(plain, tmp_path, name + '_plain', taps, 32, seed, bounces)
    diff = abs(image[..., :3] - mean[..., :3]).mean() / mean[..., :3].mean()
    print(f"{name}: mean |textured - untextured| / mean {diff:.3f}")
    assert diff > 0.1, f"{name}: the light trees change little ({diff:.3f})"
    check.assert_agrees(0.005, 0.02)


def test_light_textures_match_cycles(tmp_path, tapped_engine):
    _check_scene('light_textures', 2, tmp_path, tapped_engine)


def test_light_inputs_match_cycles(tmp_path, tapped_engine):
    """Suns per direction (UV checker, |Incoming|), Window and Camera
    coordinates and Ray Length on lights against Cycles."""
    _check_scene('light_inputs', 3, tmp_path, tapped_engine)
