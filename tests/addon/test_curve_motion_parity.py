"""Cycles parity of motion blur of curves, points and particle hair
(engine/primitive_motion.py, addon/export/primitive_motion.py): a Curves
object sliding along x (object transform motion), a Curves object swaying
by a geometry-nodes Set Position driven by the scene's frame (deformation
motion: its control points at the shutter's steps), a point cloud sliding
along x, and particle hair (Principled Hair, Chiang, melanin 0.6) on a
sphere sliding along x, each keyframed linearly and rendered at frame 2
with a shutter of 1 frame, Position Centre, against converged Cycles
references (tools/cycles_references.py curve_motion_*).  The same block
test must tell each blurred reference from Ember's sharp render (it sees
the blur).  Hostile: shutters of 0 and 10 frames, NaN motion positions."""
import bpy
import numpy as np
import pytest

from ember_testlib import (empty_factory_scene, record_engine_scenes, render_for_reference,
                           small_resolution)
from parity_scenes import light, material, plane, top_camera
from test_curves_parity import strands
from test_hair_parity import hair_material, hairy_sphere
from test_motion_parity import FRAME, _linear_keys, check_blur_parity
from test_points_parity import _points_material, point_object

BLOCK = 16   # (8-pixel blocks resolved 2.1-2.7 % at 256 spp: most of a block is floor)


def _blur(scene, on=True, shutter=1.0):
    scene.render.use_motion_blur = on
    scene.render.motion_blur_shutter = shutter
    scene.render.motion_blur_position = 'CENTER'
    scene.frame_set(FRAME)


def sliding_curves(scene, blur=True):
    """test_curves_parity's strands (200 of them) sliding 1 unit along x in the shutter."""
    strands(scene, curves=200)
    _linear_keys(bpy.data.objects['strands'], 'location', [(-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)])
    _blur(scene, blur)
    return 2


def sway_modifier(obj, amount=1.0):
    """Geometry nodes moving each point by amount (frame - 2) z along x: the
    strands lean one way, then the other (their tips 0.9 unit over the shutter)."""
    tree = bpy.data.node_groups.new("sway", 'GeometryNodeTree')
    tree.interface.new_socket('Geometry', in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket('Geometry', in_out='OUTPUT', socket_type='NodeSocketGeometry')
    nodes, links = tree.nodes, tree.links
    group_in, group_out = nodes.new('NodeGroupInput'), nodes.new('NodeGroupOutput')
    time = nodes.new('GeometryNodeInputSceneTime')
    position = nodes.new('GeometryNodeInputPosition')
    split = nodes.new('ShaderNodeSeparateXYZ')
    since = nodes.new('ShaderNodeMath')
    since.operation = 'SUBTRACT'
    since.inputs[1].default_value = float(FRAME)
    lean = nodes.new('ShaderNodeMath')
    lean.operation = 'MULTIPLY'
    scaled = nodes.new('ShaderNodeMath')
    scaled.operation = 'MULTIPLY'
    scaled.inputs[1].default_value = amount
    offset = nodes.new('ShaderNodeCombineXYZ')
    move = nodes.new('GeometryNodeSetPosition')
    links.new(time.outputs['Frame'], since.inputs[0])
    links.new(position.outputs['Position'], split.inputs[0])
    links.new(since.outputs[0], lean.inputs[0])
    links.new(split.outputs['Z'], lean.inputs[1])
    links.new(lean.outputs[0], scaled.inputs[0])
    links.new(scaled.outputs[0], offset.inputs['X'])
    links.new(group_in.outputs[0], move.inputs['Geometry'])
    links.new(offset.outputs[0], move.inputs['Offset'])
    links.new(move.outputs['Geometry'], group_out.inputs[0])
    modifier = obj.modifiers.new("sway", 'NODES')
    modifier.node_group = tree
    return modifier


def infinite_sway():
    """Blow sway_modifier's sway up to 1e38 x 1e38 x (frame - 2): infinite at
    frames 1 and 3, 0 at frame 2 (hostile motion steps)."""
    tree = bpy.data.node_groups['sway']
    scaled = next(n for n in tree.nodes if n.type == 'MATH' and n.inputs[1].default_value == 1.0)
    scaled.inputs[1].default_value = 1e38
    again = tree.nodes.new('ShaderNodeMath')
    again.operation = 'MULTIPLY'
    again.inputs[1].default_value = 1e38
    tree.links.new(scaled.outputs[0], again.inputs[0])
    tree.links.new(again.outputs[0], next(n for n in tree.nodes if n.type == 'COMBXYZ').inputs['X'])


def swaying_curves(scene, blur=True):
    """The strands (200) swaying by sway_modifier: deformation motion."""
    strands(scene, curves=200)
    sway_modifier(bpy.data.objects['strands'])
    _blur(scene, blur)
    return 2


def sliding_points(scene, blur=True, count=1500):
    """A point cloud (geometry nodes' Mesh to Points as test_points_parity's
    heap, 1500 points in a band 1.6 wide) sliding 1 unit along x in the shutter."""
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.5, -0.5, 4.0), 300.0, size=2.0)
    rng = np.random.default_rng(25)
    # a band 1.6 wide sliding 1 unit: its ends blur (a heap over the whole floor would not change)
    positions = np.c_[rng.uniform(-0.8, 0.8, count), rng.uniform(-1.2, 1.2, count), rng.uniform(0.05, 0.6, count)]
    radii = rng.uniform(0.03, 0.08, count)
    colours = np.c_[rng.uniform(0.1, 0.9, (count, 3)), np.ones(count)]
    obj = point_object("heap", positions, radii, colours, _points_material())
    _linear_keys(obj, 'location', [(-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)])
    top_camera(scene, 5.0)
    small_resolution(scene, 48, 32)
    _blur(scene, blur)
    return 2


def sliding_hair(scene, blur=True):
    """A sphere with particle hair (test_hair_parity's, Chiang, melanin 0.6)
    sliding 1 unit along x in the shutter, on a floor under an area light."""
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.5, -0.5, 4.0), 300.0, size=2.0)
    top_camera(scene, 3.0)
    scene.cycles_curves.shape = 'THICK'
    obj = hairy_sphere("hairy", (0.0, 0.0, 0.5), hair_material())
    _linear_keys(obj, 'location', [(-1.0, 0.0, 0.5), (1.0, 0.0, 0.5)])
    small_resolution(scene, 64, 48)
    _blur(scene, blur)
    return 4


SCENES = dict(sliding_curves=sliding_curves, swaying_curves=swaying_curves, sliding_points=sliding_points,
              sliding_hair=sliding_hair)


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    build, scene = SCENES[name], empty_factory_scene()
    return scene, build(scene)


@pytest.mark.parametrize("name", list(SCENES))
def test_curve_and_point_motion_blur_parity_with_cycles(name, tmp_path, tapped_engine):
    check_blur_parity(name, SCENES[name], 'curve_motion_', tmp_path, tapped_engine, BLOCK)


def test_motion_reaches_the_engine_scene(tmp_path, tapped_engine, monkeypatch):
    """The export gives the sliding strands 3 transform steps 1 unit apart
    in x, the swaying strands 3 steps of control points (tips 0.45 unit
    either side of the centre's), and none with motion blur off."""
    seen = record_engine_scenes(monkeypatch)
    for name in ('sliding_curves', 'swaying_curves'):
        scene, bounces = reference_scene(name)
        render_for_reference(scene, tmp_path, name, tapped_engine, 1, 2, bounces)
    sliding, swaying = seen[0].curves[0], seen[1].curves[0]
    assert sliding.motion is not None and np.allclose(sliding.motion[:, 0, 3], [-0.5, 0.0, 0.5], atol=1e-4)
    assert sliding.motion_positions is None
    steps = np.asarray(swaying.motion_positions)
    points = np.asarray(swaying.points, np.float64)
    assert steps.shape == (3,) + points.shape and swaying.motion is None
    dx = steps[:, :, 0] - points[None, :, 0]
    assert np.allclose(dx, np.array([-0.5, 0.0, 0.5])[:, None] * points[None, :, 2], atol=1e-4)
    scene, bounces = reference_scene('sliding_points')
    render_for_reference(scene, tmp_path, 'points', tapped_engine, 1, 2, bounces)
    cloud = seen[-1].points[0]
    assert cloud.motion is not None and np.allclose(cloud.motion[:, 0, 3], [-0.5, 0.0, 0.5], atol=1e-4)
    still = empty_factory_scene()
    sliding_curves(still, blur=False)
    render_for_reference(still, tmp_path, 'still', tapped_engine, 1, 2, 2)
    assert seen[-1].curves[0].motion is None and seen[-1].curves[0].motion_positions is None


@pytest.mark.parametrize("case", ['shutter_0', 'shutter_10', 'nan_sway'])
def test_hostile_curve_and_point_motion_renders_finite(case, tmp_path, tapped_engine, monkeypatch):
    """Shutters of 0 and of 10 frames on swaying curves and sliding points;
    infinite motion positions (the sway blown up at the shutter's steps
    only): finite pixels, and the object is named in a warning."""
    from addon import engine as ember_engine
    seen = record_engine_scenes(monkeypatch)
    scene = empty_factory_scene()
    bounces = swaying_curves(scene)
    obj = point_object("dots", [(0.0, 0.5, 0.3), (0.4, -0.5, 0.2)], [0.1, 0.05], [(1, 0, 0, 1), (0, 1, 0, 1)],
                       _points_material())
    _linear_keys(obj, 'location', [(-1.0, 0.0, 0.0), (1.0, 0.0, 0.0)])
    if case == 'shutter_0':
        scene.render.motion_blur_shutter = 0.0
    elif case == 'shutter_10':
        scene.render.motion_blur_shutter = 10.0
    else:   # 1e38 x 1e38 x (frame - 2): infinite at the shutter's steps, 0 at its centre
        infinite_sway()
    image, _ = render_for_reference(scene, tmp_path, 'hostile_' + case, tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()
    curves = seen[-1].curves[0]
    if case == 'shutter_0':
        assert curves.motion_positions is None and seen[-1].points[0].motion is None
    elif case == 'shutter_10':
        assert np.asarray(curves.motion_positions).shape[0] == 3 and seen[-1].points[0].motion is not None
    else:
        warnings = ember_engine.RENDER_LOG[-1].get('warnings') or []
        assert curves.motion_positions is None
        assert any("'strands'" in w for w in warnings), warnings
