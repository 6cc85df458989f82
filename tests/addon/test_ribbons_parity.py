"""Cycles parity of ribbon curves (Render > Curves > Shape = Rounded Ribbons,
the factory default): engine/points.py ribbon_hits, Embree's
RTC_GEOMETRY_TYPE_FLAT_CATMULL_ROM_CURVE (engine/motion.py).  Cycles traces
each strand as a flat band 2 r wide facing the ray, without end caps, and
shades it with a rounded normal (sin = Embree's v across the band), which
the hair BSDFs' h = -v follows.

The scenes are test_curves_parity's 400 wavy strands of 6 points (a
tapering radius attribute) on a diffuse floor under an area light, seen
from above, as ribbons: ``ribbons_diffuse`` with the Diffuse BSDF (two
bounces), ``ribbons_hair`` with test_hair_parity's Principled Hair Chiang
(four bounces).  Against live Cycles (8 seeds of 128 spp, rendered by the
test): the image, 2 x 2 regions and 16 x 16-pixel blocks.  ``true_normals``:
the strands alone emitting the Geometry node's True Normal (Cycles' Ng on a
ribbon is the view direction; Ember's rounded normal there was 14.3 %
darker, t -73).  The export of Render > Curves (Shape, Curve Subdivisions)
is checked on its own.

Before ribbons (3D curves for every shape): 1.7 % darker than Cycles on the
diffuse scene (docs/testing.md, test_curves_parity)."""
import bpy
import numpy as np

from ember_testlib import (ReferenceCheck, empty_factory_scene, live_cycles_reference, record_engine_scenes,
                           render_for_reference)
from test_curves_parity import strands
from test_hair_parity import hair_material

SPP = 256
CYCLES_SEEDS, CYCLES_SPP = 8, 128
BLOCK = 16


def ribbons_diffuse(scene):
    bounces = strands(scene)
    scene.cycles_curves.shape = 'RIBBONS'
    return bounces


def ribbons_hair(scene):
    strands(scene)
    scene.cycles_curves.shape = 'RIBBONS'
    data = bpy.data.objects['strands'].data
    data.materials.clear()
    data.materials.append(hair_material())
    return 4


def true_normals(scene):
    """The strands alone (no floor, no light, a black world) emitting their
    Geometry True Normal x 0.5 + 0.5: Cycles' Ng on ribbons is the view
    direction (Ember's shading frame keeps the rounded normal there)."""
    from test_curve_shading_parity import _affine, emission_material
    strands(scene)
    scene.cycles_curves.shape = 'RIBBONS'
    for name in ('floor', 'area'):
        bpy.data.objects.remove(bpy.data.objects[name])
    scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0, 0, 0, 1)
    data = bpy.data.objects['strands'].data
    data.materials.clear()
    def colour(nodes, links):
        return _affine(nodes, links, nodes.new('ShaderNodeNewGeometry').outputs['True Normal'], 0.5)
    data.materials.append(emission_material("true_normal", colour))
    return 1


def against_cycles(build, name, tmp_path, taps, spp=SPP, cycles_spp=CYCLES_SPP):
    """Ember's render of the scene ``build`` makes against live Cycles (a ReferenceCheck)."""
    scene = empty_factory_scene()
    bounces = build(scene)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, name, CYCLES_SEEDS, cycles_spp, bounces)
    image, var = render_for_reference(scene, tmp_path, name, taps, spp, 2, bounces)
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1]['warnings']
    assert not [w for w in warnings if 'Curves' in w], warnings   # ribbons are no longer named
    return ReferenceCheck(name, image[..., :3].astype(np.float64), var, spp, ref, ref_var, header, BLOCK)


def test_diffuse_ribbons_parity_with_cycles(tmp_path, tapped_engine):
    # With the channel sum's variance (tests/ember_stats.py) 256 / 8 x 128 spp
    # resolved 0.51 %: 1.25x the samples.
    check = against_cycles(ribbons_diffuse, 'ribbons_diffuse', tmp_path, tapped_engine, spp=320, cycles_spp=160)
    check.assert_agrees(0.005, 0.03)


def test_principled_hair_ribbons_parity_with_cycles(tmp_path, tapped_engine):
    # Cycles' hair is noisier: with the channel sum's variance 256 / 8 x 128 spp
    # resolved 0.81 %; 2.25x the samples.
    check = against_cycles(ribbons_hair, 'ribbons_hair', tmp_path, tapped_engine, spp=576, cycles_spp=288)
    check.assert_agrees(0.0055, 0.03)


def test_ribbon_true_normal_parity_with_cycles(tmp_path, tapped_engine):
    # 256 / 8 x 128 spp resolved 0.75 % with the channel sum's variance: 2.5x.
    check = against_cycles(true_normals, 'ribbon_true_normal', tmp_path, tapped_engine, spp=640, cycles_spp=320)
    check.assert_agrees(0.005, 0.03)


def test_curve_settings_are_exported(tmp_path, tapped_engine, monkeypatch):
    """Render > Curves reaches the engine: Shape (Rounded Ribbons, 3D Curves,
    Linear 3D Curves: none of them named in a warning) and Curve Subdivisions."""
    from addon import engine as ember_engine
    seen = record_engine_scenes(monkeypatch)
    scene = empty_factory_scene()
    bounces = strands(scene, curves=40)
    for shape, subdivisions, expect in (('RIBBONS', 3, 'RIBBONS'), ('THICK', 2, 'THICK'),
                                        ('THICK_LINEAR', 1, 'THICK_LINEAR')):
        scene.cycles_curves.shape, scene.cycles_curves.subdivisions = shape, subdivisions
        image, _ = render_for_reference(scene, tmp_path, shape, tapped_engine, 2, 2, bounces)
        assert np.isfinite(image).all()
        assert (seen[-1].curve_shape, seen[-1].curve_subdivisions) == (expect, subdivisions)
        named = [w for w in ember_engine.RENDER_LOG[-1]['warnings'] if 'Curves are rendered as 3D curves' in w]
        assert not named, ember_engine.RENDER_LOG[-1]['warnings']
