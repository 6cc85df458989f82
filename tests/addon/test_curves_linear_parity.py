"""Cycles parity of linear 3D curves (Render > Curves > Shape = Linear 3D
Curves): engine/points.py Strands.linear, Embree's
RTC_GEOMETRY_TYPE_ROUND_LINEAR_CURVE (engine/motion.py _curve_geometry).
Cycles traces each segment between the keys as they are (no Catmull-Rom)
as a cone of the two keys' radii, with spheres at the joints and the ends
(its linear curves keep their end caps), and shades it with the normal from
the axis at u.

The scene: 300 zig-zag strands of 4 keys (a tapering radius attribute) on a
diffuse floor under an area light, seen from above, diffuse (two bounces).
Against live Cycles (8 seeds of 128 spp, rendered by the test): the image,
2 x 2 regions and 16 x 16-pixel blocks: +0.003 % +- 0.088 % (t 0.04), max
block |t| 1.1.  Before (Linear 3D Curves rendered as 3D curves, Catmull-Rom
through the same keys, warned) Ember was -1.04 % +- 0.09 % (t -11.8; max
block |t| 8.4) against this reference: the image test resolves 0.42 %.
``sliding_zigzag``: the strands sliding 3 units in the shutter (motion
blur), -0.09 % +- 0.09 % (t -1.0), max block |t| 2.0; a sharp render is 12
of 18 blocks beyond (max |t| 42): the test sees the blur.
``emitting_zigzag``: the strands alone emitting the Geometry Normal, the
Tangent or the Curves Info Thickness (768 / 8 x 384 spp): 0.000 %, -0.000 %,
-0.005 % (+- 0.10 %), max block |t| <= 0.64; as Catmull-Rom +3.4 %, +2.1 %,
+3.8 % (t 20 to 35)."""
import bpy
import numpy as np
import pytest

from ember_testlib import (ReferenceCheck, empty_factory_scene, live_cycles_reference, render_for_reference,
                           small_resolution)
from parity_scenes import hair_curves, light, material, plane, top_camera

SPP = 256
CYCLES_SEEDS, CYCLES_SPP = 8, 128
BLOCK = 16
CURVES, KEYS = 300, 4


def zigzag(scene, shape='THICK_LINEAR'):
    """300 strands of 4 keys zig-zagging 0.14 either side of their root as
    they rise (sharp corners: where Catmull-Rom curves bulge past the keys'
    polyline), radius 0.035 at the root to 0.012 at the tip."""
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.5, -0.5, 4.0), 300.0, size=2.0)
    rng = np.random.default_rng(41)
    base = np.c_[rng.uniform(-1.5, 1.5, (CURVES, 2)), np.zeros(CURVES)]
    angle = rng.uniform(0, 2 * np.pi, CURVES)
    side = 0.14 * np.c_[np.cos(angle), np.sin(angle), np.zeros(CURVES)]
    sign = np.array([0.0, 1.0, -1.0, 1.0])
    rise = np.array([0.0, 0.2, 0.4, 0.6])
    points = base[:, None, :] + sign[None, :, None] * side[:, None, :] + rise[None, :, None] * [0.0, 0.0, 1.0]
    radii = np.tile(np.linspace(0.035, 0.012, KEYS), CURVES)
    hair_curves(scene, points, radii, KEYS, CURVES)
    top_camera(scene, 5.0)
    small_resolution(scene, 48, 32)
    scene.cycles_curves.shape = shape
    return 2


def test_linear_curves_parity_with_cycles(tmp_path, tapped_engine):
    scene = empty_factory_scene()
    bounces = zigzag(scene)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'linear', CYCLES_SEEDS, CYCLES_SPP, bounces)
    image, var = render_for_reference(scene, tmp_path, 'linear', tapped_engine, SPP, 2, bounces)
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1]['warnings']
    assert not [w for w in warnings if 'Curves' in w], warnings   # linear curves are no longer named
    check = ReferenceCheck('linear_curves', image[..., :3].astype(np.float64), var, SPP, ref, ref_var, header, BLOCK)
    check.assert_agrees(0.005, 0.03)


def sliding_zigzag(scene, blur=True):
    """The zig-zag linear strands sliding 3 units along x in a shutter of 1
    frame (object transform motion: Embree's time-stepped instance of the
    round linear curves)."""
    from test_curve_motion_parity import _blur
    from test_motion_parity import _linear_keys
    bounces = zigzag(scene)
    _linear_keys(bpy.data.objects['strands'], 'location', [(-3.0, 0.0, 0.0), (3.0, 0.0, 0.0)])
    _blur(scene, blur)
    return bounces


def _sharp_blocks_beyond(name, image, var, ref, ref_var, level, spp):
    """How many blocks of a sharp Ember render differ from the blurred
    reference at ``level`` (the blur test's power), printed."""
    import ember_stats as stats
    a, va = stats.block_means_var(image[..., :3].astype(np.float64), var, BLOCK)
    b, vb = stats.block_means_var(ref, ref_var, BLOCK)
    t = np.abs(a - b) / np.sqrt(va + vb)
    limit = stats.t_threshold(level, spp - 1)
    print(f"{name}: a sharp render against the blurred reference: max block |t| {t.max():.1f} "
          f"(limit {limit:.1f}), {(t > limit).sum()} of {t.size} blocks beyond")
    return int((t > limit).sum())


def test_moving_linear_curves_parity_with_cycles(tmp_path, tapped_engine):
    scene = empty_factory_scene()
    bounces = sliding_zigzag(scene)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'sliding', CYCLES_SEEDS, CYCLES_SPP, bounces)
    image, var = render_for_reference(scene, tmp_path, 'sliding', tapped_engine, SPP, 2, bounces)
    check = ReferenceCheck('sliding_linear_curves', image[..., :3].astype(np.float64), var, SPP, ref, ref_var,
                           header, BLOCK)
    check.assert_agrees(0.005, 0.03)
    still = empty_factory_scene()
    sliding_zigzag(still, blur=False)
    sharp, sharp_var = render_for_reference(still, tmp_path, 'sliding_still', tapped_engine, SPP // 2, 2, bounces)
    assert _sharp_blocks_beyond('sliding_linear_curves', sharp, sharp_var, ref, ref_var, check.details['level'],
                                SPP // 2), "the test cannot tell the linear curves' motion blur from none"


def _frame_output(name):
    """(nodes, links) -> the socket a strand emits: the Geometry node's
    Normal or Tangent (x 0.5 + 0.5), or the Curves Info Thickness x 12
    (linear in u on these curves: Cycles' curve_thickness)."""
    from test_curve_shading_parity import _affine

    def build(nodes, links):
        if name == 'Thickness':
            scale = nodes.new('ShaderNodeMath')
            scale.operation = 'MULTIPLY'
            links.new(nodes.new('ShaderNodeHairInfo').outputs['Thickness'], scale.inputs[0])
            scale.inputs[1].default_value = 12.0
            return scale.outputs[0]
        return _affine(nodes, links, nodes.new('ShaderNodeNewGeometry').outputs[name], 0.5)
    return build


def emitting_zigzag(scene, output):
    """The zig-zag strands alone (no floor, no light, a black world)
    emitting ``output`` (_frame_output)."""
    from test_curve_shading_parity import emission_material
    zigzag(scene)
    for name in ('floor', 'area'):
        bpy.data.objects.remove(bpy.data.objects[name])
    scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)
    data = bpy.data.objects['strands'].data
    data.materials.clear()
    data.materials.append(emission_material(output.lower(), _frame_output(output)))
    return 1


@pytest.mark.parametrize("output", ['Normal', 'Tangent', 'Thickness'])
def test_linear_curve_shading_frame_parity_with_cycles(output, tmp_path, tapped_engine):
    """The hit's normal (from the segment's axis), tangent (its chord) and
    thickness (linear in u) as Cycles shades them on linear curves (with
    Catmull-Rom curves through the same keys Ember was +3.4 % (t 32), +2.1 %
    (t 20), +3.8 % (t 35) at 640 / 8 x 320 spp)."""
    scene = empty_factory_scene()
    bounces = emitting_zigzag(scene, output)
    name = 'linear_' + output.lower()
    # 256 / 8 x 128 spp resolved 0.79-0.82 % (the strands' edges are most of
    # the noise), 2.5x 0.49-0.51 %: 3x the samples.
    spp, cycles_spp = 768, 384
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, name, CYCLES_SEEDS, cycles_spp, bounces)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 2, bounces)
    check = ReferenceCheck(name, image[..., :3].astype(np.float64), var, spp, ref, ref_var, header, BLOCK)
    check.assert_agrees(0.005, 0.03)
