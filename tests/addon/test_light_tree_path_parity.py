"""Cycles parity of the Light Path node in light node trees (issue 23;
engine/lights/shader.py emission_path, read by addon/export/light.py; the
emissive-surface side is tests/addon/test_light_path_parity.py): one scene,
one converged reference (tools/cycles_references.py light_tree_path), a
diffuse floor and cube before a mirror wall at 3 bounces, with

* a point light of no size (light samples only) whose Emission Strength is
  1 + 9 (Ray Depth == 2): Cycles evaluates a light sample at a vertex of
  bounce b with Ray Depth b + 1, so the light reaching the camera's first
  hits directly is 1x and the light they get through one diffuse bounce
  10x;
* a second point light of no size at 1 + 9 (Diffuse Depth == 1): the
  per-kind depths are the path's counts, with no + 1 (the first hits' light
  samples read 0, 1x; after one diffuse bounce 1, 10x);
* a sphere light seen by the camera and by glossy rays only (no diffuse
  visibility: no light sample takes it) whose Strength is
  1 + 9 (Ray Depth == 1): a camera ray that hits it reads 1 (10x), the
  mirror's singular ray that hits it reads b + 2 = 2 (1x), with MIS weight
  1 both (a light sample could take neither);
* an area light whose Strength is 1 + 3 (Is Camera Ray + Is Shadow Ray +
  Is Diffuse Ray): every ray kind reads 0 on lights in Cycles
  (PATH_RAY_EMISSION), so it is a plain light of Strength 1 (its light
  samples and BSDF hits agree, so MIS weights do not enter);

the whole image, its quadrants and every block against Cycles (two
statistical families), power printed and asserted.  Beside it Ember's image
must differ from the same lights without trees (the trees have their
effect)."""
import math

from parity_scenes import box, light, material, plane
from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference, small_resolution

WIDTH, HEIGHT = 48, 32
BLOCK = 8
SPP = 10240
BOUNCES = 3


def _math(tree, operation, a, b=None, c=None):
    """A Math node on a (a socket or a number) and b, c (numbers); its output."""
    node = tree.nodes.new('ShaderNodeMath')
    node.operation = operation
    for k, value in enumerate((a, b, c)):
        if value is None:
            continue
        if isinstance(value, (int, float)):
            node.inputs[k].default_value = value
        else:
            tree.links.new(value, node.inputs[k])
    return node.outputs[0]


def _strength_from(obj, build):
    """The light's Emission Strength from build(tree, Light Path node)."""
    data = obj.data
    data.use_nodes = True
    tree = data.node_tree
    emission = next(n for n in tree.nodes if n.type == 'EMISSION')
    path = tree.nodes.new('ShaderNodeLightPath')
    tree.links.new(build(tree, path), emission.inputs['Strength'])


def _bounced_tenfold(tree, path):
    """1 + 9 (Ray Depth == 2)."""
    return _math(tree, 'MULTIPLY_ADD', _math(tree, 'COMPARE', path.outputs['Ray Depth'], 2.0, 0.5), 9.0, 1.0)


def _diffuse_bounced_tenfold(tree, path):
    """1 + 9 (Diffuse Depth == 1)."""
    return _math(tree, 'MULTIPLY_ADD', _math(tree, 'COMPARE', path.outputs['Diffuse Depth'], 1.0, 0.5), 9.0, 1.0)


def _direct_tenfold(tree, path):
    """1 + 9 (Ray Depth == 1)."""
    return _math(tree, 'MULTIPLY_ADD', _math(tree, 'COMPARE', path.outputs['Ray Depth'], 1.0, 0.5), 9.0, 1.0)


def _ray_kinds(tree, path):
    """1 + 3 (Is Camera Ray + Is Shadow Ray + Is Diffuse Ray)."""
    kinds = _math(tree, 'ADD', path.outputs['Is Camera Ray'], path.outputs['Is Shadow Ray'])
    kinds = _math(tree, 'ADD', kinds, path.outputs['Is Diffuse Ray'])
    return _math(tree, 'MULTIPLY_ADD', kinds, 3.0, 1.0)


def light_tree_path(scene, with_trees=True):
    plane("floor", material("floor", 'diffuse'))
    box("cube", material("cube", 'diffuse', color=(0.8, 0.8, 0.8)), (-0.5, -0.1, 0.35), (0.7, 0.7, 0.7))
    box("mirror", material("mirror", 'glossy', color=(0.9, 0.9, 0.9), roughness=0.0), (0.0, 1.3, 0.9),
        (4.0, 0.1, 1.8))
    point = light('POINT', (-0.3, -0.9, 1.1), 40.0, shadow_soft_size=0.0)
    diffuse = light('POINT', (1.3, 0.4, 1.2), 30.0, shadow_soft_size=0.0)
    sphere = light('POINT', (0.8, -0.3, 0.45), 20.0, shadow_soft_size=0.3, use_soft_falloff=False)
    sphere.visible_camera = True
    sphere.visible_diffuse = False
    area = light('AREA', (0.9, 0.6, 1.5), 30.0, rotation=(0.4, 0.0, 0.0), size=0.8)
    if with_trees:
        _strength_from(point, _bounced_tenfold)
        _strength_from(diffuse, _diffuse_bounced_tenfold)
        _strength_from(sphere, _direct_tenfold)
        _strength_from(area, _ray_kinds)
    cam = scene.camera
    cam.location = (0.0, -3.2, 1.6)
    cam.rotation_euler = (math.radians(72.0), 0.0, 0.0)
    cam.data.lens = 22.0
    small_resolution(scene, WIDTH, HEIGHT)
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.node_tree is not None and 'Background' in scene.world.node_tree.nodes:
        scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)
    return BOUNCES


SCENES = {'light_tree_path': light_tree_path}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_light_path_in_light_trees_matches_cycles(tmp_path, tapped_engine):
    """Ray Depth (light samples b + 1, rays that hit the light b + 2) and
    the ray kinds (0) in light trees against Cycles."""
    name = 'light_tree_path'
    scene, bounces = reference_scene(name)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, SPP, 4, bounces)
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1].get('warnings', ())
    assert not [w for w in warnings if 'Light' in w], warnings
    check = check_against_reference(name, scene, bounces, image, var, SPP, BLOCK)
    plain = empty_factory_scene()
    light_tree_path(plain, with_trees=False)
    without, _ = render_for_reference(plain, tmp_path, name + '_plain', tapped_engine, 64, 4, bounces)
    diff = abs(image[..., :3] - without[..., :3]).mean() / without[..., :3].mean()
    print(f"{name}: mean |with trees - without| / mean {diff:.3f}")
    assert diff > 0.1, f"{name}: the light trees change little ({diff:.3f})"
    check.assert_agrees(0.005, 0.02)
