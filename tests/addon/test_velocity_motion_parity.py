"""Cycles parity of motion blur from a ``velocity`` attribute (issue 24;
addon/export/motion.py, addon/export/primitive_motion.py): geometry nodes
store a float vector ``velocity`` (units per second) on the points of a
grid mesh (spinning and sliding), of a point cloud (sliding along x) and of
a Curves object (sliding along y) and of a smooth-shaded flap (tilting
about y: its shading changes by the normals Cycles computes at the
steps), and delete a frame-dependent share of
their faces, points or curves, so their topology changes between the
shutter's steps and deformation steps are impossible: Cycles (and Ember)
move them by P +- v s / 2 (s: the shutter, 0.5 frames at 24 fps, in
seconds).  Rendered at frame 2 against a converged Cycles reference
(tools/cycles_references.py velocity_shapes); the same block test must tell
the reference from Ember's sharp render and from Ember keeping the centre's
normals.  Also: the exported steps, velocity on faces and curves, the
Vector pass (against live Cycles), Deformation off, and hostile velocities
(NaN, 1e30, the largest float over a long shutter)."""
import bpy
import numpy as np
import pytest

from ember_testlib import (check_against_reference, empty_factory_scene, record_engine_scenes, render_for_reference,
                           small_resolution)
from parity_scenes import light, material, plane, top_camera
from test_motion_parity import FRAME, SPP, _blocks_beyond
from test_points_parity import _points_material, point_object

BLOCK = 8
FPS = 24
SHUTTER = 0.5
SLIDE = 24.0            # units per second: 1 unit per frame, 0.5 in the shutter
SPIN = 12.0             # radians per second about z (the grid's shear: +- 0.125 rad)
TILT = 96.0             # the flap's: its steps' z -+ x (+- 45 degrees)


def _tree(name):
    tree = bpy.data.node_groups.new(name, 'GeometryNodeTree')
    tree.interface.new_socket('Geometry', in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket('Geometry', in_out='OUTPUT', socket_type='NodeSocketGeometry')
    return tree, tree.nodes.new('NodeGroupInput'), tree.nodes.new('NodeGroupOutput')


def _math(tree, operation, a, b):
    node = tree.nodes.new('ShaderNodeMath')
    node.operation = operation
    for socket, value in zip(node.inputs, (a, b)):
        if isinstance(value, (int, float)):
            socket.default_value = value
        else:
            tree.links.new(value, socket)
    return node.outputs[0]


def velocity_modifier(obj, domain, keep, velocity=(SLIDE, 0.0, 0.0), spin=0.0, axis=(0.0, 0.0, 1.0)):
    """Geometry nodes keeping the first keep + 4 frame elements of
    ``domain`` (FACE, POINT or CURVE: a count that changes with every
    quarter frame) and storing velocity = ``velocity`` + spin axis x position."""
    tree, group_in, group_out = _tree(obj.name + "_velocity")
    nodes, links = tree.nodes, tree.links
    time = nodes.new('GeometryNodeInputSceneTime')
    count = _math(tree, 'ADD', _math(tree, 'MULTIPLY', time.outputs['Frame'], 4.0), float(keep))
    index = nodes.new('GeometryNodeInputIndex')
    beyond = nodes.new('FunctionNodeCompare')
    beyond.data_type = 'FLOAT'
    beyond.operation = 'GREATER_EQUAL'
    links.new(index.outputs[0], beyond.inputs['A'])
    links.new(count, beyond.inputs['B'])
    delete = nodes.new('GeometryNodeDeleteGeometry')
    delete.domain = domain
    links.new(group_in.outputs[0], delete.inputs['Geometry'])
    links.new(beyond.outputs[0], delete.inputs['Selection'])
    position = nodes.new('GeometryNodeInputPosition')
    turn = nodes.new('ShaderNodeVectorMath')
    turn.operation = 'CROSS_PRODUCT'
    turn.inputs[0].default_value = tuple(spin * a for a in axis)
    links.new(position.outputs[0], turn.inputs[1])
    total = nodes.new('ShaderNodeVectorMath')
    total.operation = 'ADD'
    links.new(turn.outputs[0], total.inputs[0])
    total.inputs[1].default_value = velocity
    store = nodes.new('GeometryNodeStoreNamedAttribute')
    store.data_type = 'FLOAT_VECTOR'
    store.domain = 'POINT'
    store.inputs['Name'].default_value = 'velocity'
    links.new(delete.outputs[0], store.inputs['Geometry'])
    links.new(total.outputs[0], store.inputs['Value'])
    links.new(store.outputs[0], group_out.inputs[0])
    modifier = obj.modifiers.new("velocity", 'NODES')
    modifier.node_group = tree
    return tree


def _grid():
    """A 1.2 x 0.8 grid of 12 x 8 faces at z 0.3, left of centre."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=13, y_subdivisions=9, size=1.0, location=(-0.9, 0.3, 0.3))
    obj = bpy.context.active_object
    obj.name = "grid"
    obj.scale = (1.2, 0.8, 1.0)
    obj.data.materials.append(material("red", 'diffuse', color=(0.8, 0.15, 0.1)))
    velocity_modifier(obj, 'FACE', 80, velocity=(0.0, SLIDE, 0.0), spin=SPIN)
    return obj


def _points(count=400):
    rng = np.random.default_rng(24)
    positions = np.c_[rng.uniform(0.3, 1.3, count), rng.uniform(-0.2, 0.9, count), rng.uniform(0.05, 0.5, count)]
    colours = np.c_[rng.uniform(0.1, 0.9, (count, 3)), np.ones(count)]
    obj = point_object("cloud", positions, rng.uniform(0.03, 0.06, count), colours, _points_material())
    velocity_modifier(obj, 'POINT', count - 12, velocity=(SLIDE, 0.0, 0.0))
    return obj


def _curves(count=60, points=6):
    """Strands lying along x at z 0.25 below the others, sliding along y."""
    rng = np.random.default_rng(7)
    x = np.linspace(-0.5, 0.5, points)
    base = np.c_[rng.uniform(-1.2, 0.6, count), rng.uniform(-1.0, -0.5, count)]
    keys = np.stack([base[:, None, 0] + x[None], base[:, None, 1] + 0.1 * np.sin(3 * x)[None],
                     np.full((count, points), 0.25)], axis=2)
    data = bpy.data.hair_curves.new("strands")
    data.add_curves([points] * count)
    data.attributes['position'].data.foreach_set('vector', keys.reshape(-1).astype(np.float32))
    radius = data.attributes.new('radius', 'FLOAT', 'POINT')
    radius.data.foreach_set('value', np.full(count * points, 0.025, np.float32))
    data.materials.append(material("hair", 'diffuse', color=(0.2, 0.6, 0.8)))
    obj = bpy.data.objects.new("strands", data)
    bpy.context.scene.collection.objects.link(obj)
    velocity_modifier(obj, 'CURVE', count - 12, velocity=(0.0, SLIDE, 0.0))
    return obj


def _flap():
    """A smooth-shaded 0.8 x 0.8 grid tilting about y by its velocity
    (v_z = 96 x: the steps' z is -+ x): seen from above its outline
    stays, its shading changes by the normals at the steps (Cycles
    computes them from the moved vertices; the centre's would keep it lit
    as a flat floor)."""
    bpy.ops.mesh.primitive_grid_add(x_subdivisions=8, y_subdivisions=8, size=0.8, location=(1.5, -1.0, 0.5))
    obj = bpy.context.active_object
    obj.name = "flap"
    bpy.ops.object.shade_smooth()
    obj.data.materials.append(material("yellow", 'diffuse', color=(0.9, 0.8, 0.3)))
    velocity_modifier(obj, 'FACE', 100000, velocity=(0.0, 0.0, 0.0), spin=-TILT, axis=(0.0, 1.0, 0.0))
    return obj


def _blur(scene, on=True):
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.render.use_motion_blur = on
    scene.render.motion_blur_shutter = SHUTTER
    scene.render.motion_blur_position = 'CENTER'
    scene.frame_set(FRAME)


def velocity_shapes(scene, blur=True):
    """The grid, the cloud, the strands and the flap on a floor under an area light."""
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.5, -0.5, 4.0), 300.0, size=2.0)
    top_camera(scene, 4.0)
    small_resolution(scene, 64, 48)
    scene.cycles_curves.shape = 'THICK'
    _grid()
    _points()
    _curves()
    _flap()
    _blur(scene, blur)
    return 2


SCENES = dict(shapes=velocity_shapes)


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_velocity_motion_blur_parity_with_cycles(tmp_path, tapped_engine, monkeypatch):
    """Parity with the reference; the same blocks at the same level tell
    it from Ember's sharp render and from Ember keeping the centre's
    shading normals at the steps (the flap's shading)."""
    from addon.export import motion as motion_export
    scene, bounces = reference_scene('shapes')
    image, var = render_for_reference(scene, tmp_path, 'shapes', tapped_engine, SPP, 2, bounces)
    check = check_against_reference('velocity_shapes', scene, bounces, image, var, SPP, BLOCK)
    check.assert_agrees(0.005, 0.02)
    level = check.details['level']
    still = empty_factory_scene()
    velocity_shapes(still, blur=False)
    sharp, sharp_var = render_for_reference(still, tmp_path, 'shapes_still', tapped_engine, SPP // 4, 2, bounces)
    assert _blocks_beyond('shapes', sharp, sharp_var, level, "a sharp render", 'velocity_', BLOCK, SPP // 4)
    monkeypatch.setattr(motion_export, '_step_normals', lambda mesh, steps: None)
    scene, bounces = reference_scene('shapes')
    centre, centre_var = render_for_reference(scene, tmp_path, 'shapes_centre', tapped_engine, SPP // 4, 2, bounces)
    assert _blocks_beyond('shapes', centre, centre_var, level, "the centre's normals at every step", 'velocity_', BLOCK,
                          SPP // 4)


def _exported(name, tmp_path, taps, monkeypatch, scene=None, spp=1):
    from addon import engine as ember_engine
    seen = record_engine_scenes(monkeypatch)
    if scene is None:
        scene, _ = reference_scene('shapes')
    image, _ = render_for_reference(scene, tmp_path, name, taps, spp, 2, 2)
    warnings = ember_engine.RENDER_LOG[-1].get('warnings') or []
    return seen[-1], image, warnings


def _mesh_of(engine_scene, name):
    """The engine Mesh the instance of object ``name`` places."""
    return engine_scene.meshes[next(inst.mesh for inst in engine_scene.instances if inst.name == name)]


def test_velocity_gives_the_motion_steps(tmp_path, tapped_engine, monkeypatch):
    """The grid, the cloud and the strands get three steps P -+ v s / 2
    (s = 0.5 / 24 s) with v the stored velocity, no warning that their
    topology changes, and their counts are the centre frame's."""
    engine_scene, _, warnings = _exported('steps', tmp_path, tapped_engine, monkeypatch)
    half = 0.5 * SHUTTER / FPS
    grid_mesh = _mesh_of(engine_scene, 'grid')
    p = np.asarray(grid_mesh.positions, np.float64)
    spin = np.c_[-SPIN * p[:, 1], SPIN * p[:, 0], np.zeros(len(p))]   # (0, 0, w) x p
    v = spin + np.array([0.0, SLIDE, 0.0])
    assert grid_mesh.motion is not None and grid_mesh.motion.shape == (3,) + p.shape
    assert np.allclose(grid_mesh.motion - p[None], np.array([-half, 0.0, half])[:, None, None] * v[None], atol=1e-5)
    cloud = engine_scene.points[0]
    assert len(cloud.positions) == 400 - 12 + 4 * FRAME
    steps = np.asarray(cloud.motion_positions) - np.asarray(cloud.positions, np.float64)[None]
    assert np.allclose(steps[..., 0], np.array([-half, 0.0, half])[:, None] * SLIDE, atol=1e-5)
    assert np.allclose(steps[..., 1:], 0.0)
    strands = engine_scene.curves[0]
    assert len(strands.offsets) - 1 == 60 - 12 + 4 * FRAME
    steps = np.asarray(strands.motion_positions) - np.asarray(strands.points, np.float64)[None]
    assert np.allclose(steps[..., 1], np.array([-half, 0.0, half])[:, None] * SLIDE, atol=1e-5)
    assert not [w for w in warnings if 'change' in w or 'velocity' in w], warnings
    assert all(getattr(item, 'velocity', None) is None for item in engine_scene.meshes)


def test_velocity_on_faces_and_curves_is_read_on_their_points(tmp_path, tapped_engine, monkeypatch):
    """A velocity stored on the grid's faces (without spin: (0, 24, 0) on
    each) and on the strands' curves reaches every point as Blender's
    domain interpolation gives it (the faces' mean, the curve's value)."""
    scene, _ = reference_scene('shapes')
    for name, domain in (('grid', 'FACE'), ('strands', 'CURVE')):
        tree = bpy.data.node_groups[name + '_velocity']
        next(n for n in tree.nodes if n.type == 'STORE_NAMED_ATTRIBUTE').domain = domain
        next(n for n in tree.nodes if n.type == 'VECT_MATH' and n.operation == 'CROSS_PRODUCT').inputs[0] \
            .default_value = (0.0, 0.0, 0.0)
    engine_scene, _, warnings = _exported('domains', tmp_path, tapped_engine, monkeypatch, scene)
    half = 0.5 * SHUTTER / FPS
    for item, centre in ((_mesh_of(engine_scene, 'grid'), 'positions'), (engine_scene.curves[0], 'points')):
        steps = getattr(item, 'motion' if centre == 'positions' else 'motion_positions')
        moved = np.asarray(steps) - np.asarray(getattr(item, centre), np.float64)[None]
        assert np.allclose(moved[..., 1], np.array([-half, 0.0, half])[:, None] * SLIDE, atol=1e-5)
        assert np.allclose(moved[..., [0, 2]], 0.0, atol=1e-6)
    assert not [w for w in warnings if 'velocity' in w], warnings


def test_velocity_gives_the_vector_pass_steps(tmp_path, tapped_engine, monkeypatch):
    """With motion blur off and the Vector pass on, the steps are a frame
    either side (Cycles' motion_shutter_time of 2 frames): P -+ v / fps."""
    scene, _ = reference_scene('shapes')
    _blur(scene, on=False)
    bpy.context.view_layer.use_pass_vector = True
    engine_scene, _, _ = _exported('vector', tmp_path, tapped_engine, monkeypatch, scene)
    grid_mesh = _mesh_of(engine_scene, 'grid')
    assert grid_mesh.motion is None and grid_mesh.vector_motion is not None
    dy = grid_mesh.vector_motion[..., 1] - np.asarray(grid_mesh.positions, np.float64)[None, :, 1]
    x = np.asarray(grid_mesh.positions, np.float64)[:, 0]
    assert np.allclose(dy, np.array([-1.0, 0.0, 1.0])[:, None] * (SLIDE + SPIN * x)[None] / FPS, atol=1e-5)
    cloud = engine_scene.points[0]
    dx = np.asarray(cloud.vector_positions)[..., 0] - np.asarray(cloud.positions, np.float64)[None, :, 0]
    assert np.allclose(dx, np.array([-1.0, 0.0, 1.0])[:, None] * SLIDE / FPS, atol=1e-5)


def test_deformation_off_keeps_velocity_still(tmp_path, tapped_engine, monkeypatch):
    """Object > Motion Blur > Deformation off (Cycles: the geometry's
    use_motion_blur off) or Motion Blur off: no motion from velocity."""
    scene, _ = reference_scene('shapes')
    bpy.data.objects['grid'].cycles.use_deform_motion = False
    bpy.data.objects['cloud'].cycles.use_motion_blur = False
    engine_scene, _, _ = _exported('deform_off', tmp_path, tapped_engine, monkeypatch, scene)
    assert _mesh_of(engine_scene, 'grid').motion is None
    assert engine_scene.points[0].motion_positions is None
    assert engine_scene.curves[0].motion_positions is not None


@pytest.mark.parametrize("case", ['nan', 'huge', 'overflow'])
def test_hostile_velocity_renders_finite(case, tmp_path, tapped_engine, monkeypatch):
    """A NaN velocity; a huge finite one (1e30: the steps 1e28 away); the
    largest float (an infinite input is stored as 3.4e38) over a shutter of
    10 frames at 1 fps, whose steps overflow float32: finite pixels; a
    velocity whose steps are not finite renders its object still, named
    in a warning."""
    value = {'nan': float('nan'), 'huge': 1e30, 'overflow': float('inf')}[case]
    scene, _ = reference_scene('shapes')
    if case == 'overflow':
        scene.render.fps, scene.render.motion_blur_shutter = 1, 10.0
    for tree in bpy.data.node_groups:
        if tree.name.endswith('_velocity'):
            add = next(n for n in tree.nodes if n.type == 'VECT_MATH' and n.operation == 'ADD')
            add.inputs[1].default_value = (value, value, value)
    engine_scene, image, warnings = _exported('hostile', tmp_path, tapped_engine, monkeypatch, scene, spp=4)
    assert np.isfinite(image).all()
    grid_mesh = _mesh_of(engine_scene, 'grid')
    if case == 'huge':
        assert grid_mesh.motion is not None and np.isfinite(grid_mesh.motion).all()
        return
    assert grid_mesh.motion is None and engine_scene.points[0].motion_positions is None
    assert engine_scene.curves[0].motion_positions is None
    for name in ('grid', 'cloud', 'strands'):
        assert any(f"'{name}'" in w and 'without motion blur from it' in w for w in warnings), warnings


VECTOR_SEEDS = 8
# Cycles 5.0 writes the same Vector pass for a point cloud whatever moves
# its points (velocity or deformation steps): pre = post, on this cloud an
# image mean of (-13.6, -6.0, +13.6, +6.0) px with a velocity of 1 unit per
# frame along x and with a sway along x alike (Ember: (-17.2, 0, -17.2, 0)
# px, the velocity's); its object motion is right (test_vector_primitives_parity).
CLOUD_VECTOR_GAP = ("Cycles 5.0's Vector pass of a point cloud ignores its motion positions (pre = post, image "
                    "mean (-13.6, -6.0, 13.6, 6.0) px for velocity and sway alike; Ember (-17.2, 0, -17.2, 0), "
                    "the velocity's; per-pixel gap median 31 px)")


@pytest.mark.parametrize("shown", [('grid', 'strands', 'flap'),
                                   pytest.param(('cloud',), marks=pytest.mark.xfail(strict=True,
                                                                                   reason=CLOUD_VECTOR_GAP))],
                         ids=['grid_strands_flap', 'cloud'])
def test_vector_pass_from_velocity_matches_cycles(shown, registered_addon, tmp_path):
    """The Vector pass of the shapes ``shown`` (motion blur off, no floor,
    a transparent film) against live Cycles, VECTOR_SEEDS seeds each, with
    test_vector_primitives_parity's check (covered and edge pixels, image
    means); that check must fail on Ember's vectors 1 % longer and on the
    steps swapped (what it detects, printed)."""
    from ember_testlib import multilayer_output
    from test_vector_primitives_parity import _render, check
    scene, _ = reference_scene('shapes')
    _blur(scene, on=False)
    for name in ('floor', 'grid', 'cloud', 'strands', 'flap'):
        if name not in shown:
            bpy.data.objects.remove(bpy.data.objects[name])
    scene.render.film_transparent = True
    bpy.context.view_layer.use_pass_vector = True
    multilayer_output(scene)
    runs = {}
    for engine in ('EMBER', 'CYCLES'):
        seeds = [_render(scene, tmp_path, engine, seed) for seed in range(VECTOR_SEEDS)]
        runs[engine] = (np.array([s[0] for s in seeds]), np.array([s[1] for s in seeds]))
    e, c = runs['EMBER'], runs['CYCLES']
    label = 'velocity ' + ' '.join(shown)
    ok, levels, lines = check(label, e, c)
    scaled, _, scaled_lines = check(label, (1.01 * e[0], e[1]), c, levels)
    swapped, _, swapped_lines = check(label, (-e[0][..., [2, 3, 0, 1]], e[1]), c, levels)
    print("\n" + "\n".join(lines))
    print("  x 1.01: " + "; ".join(s.strip() for s in scaled_lines[2:]))
    print("  steps swapped: " + swapped_lines[0].split(": ", 1)[1])
    assert ok, lines
    assert not scaled and not swapped, (scaled_lines, swapped_lines)


def test_velocity_keeps_three_steps_under_more_transform_steps(tmp_path, tapped_engine, monkeypatch):
    """Object > Motion Blur > Steps 2 (5 transform steps) on the grid,
    keyframed to slide: its placement takes 5 steps, its vertices the
    velocity's 3 (Cycles forces 3 for motion from velocity), and the
    render is finite."""
    from test_motion_parity import _linear_keys
    scene, _ = reference_scene('shapes')
    grid = bpy.data.objects['grid']
    grid.cycles.motion_steps = 2
    _linear_keys(grid, 'location', [(-1.4, 0.3, 0.3), (-0.4, 0.3, 0.3)])
    scene.frame_set(FRAME)
    engine_scene, image, _ = _exported('five_steps', tmp_path, tapped_engine, monkeypatch, scene, spp=4)
    inst = next(inst for inst in engine_scene.instances if inst.name == 'grid')
    assert inst.motion is not None and len(inst.motion) == 5
    assert np.allclose(np.asarray(inst.motion)[:, 0, 3], -0.9 + 0.5 * np.linspace(-0.25, 0.25, 5), atol=1e-4)
    assert _mesh_of(engine_scene, 'grid').motion.shape[0] == 3
    assert np.isfinite(image).all()
