"""Cycles parity of the Hair BSDF node (engine/lobes/hair_bsdf.py, the
export's ``_node_bsdf_hair``) on test_curves_parity's Curves object (400
wavy strands, a tapering radius attribute, 3D curves, a diffuse floor under
an area light, seen from above; four bounces): a Mix Shader (0.5) of the
Reflection component (tinted, RoughnessU 0.15, RoughnessV 1, Offset 2
degrees) and the Transmission component (RoughnessU 0.3, RoughnessV 0.6),
against a converged Cycles reference (tools/cycles_references.py
hair_bsdf_strands), and hostile inputs (NaN / zero roughness, an offset far
out of range, a linked Tangent).

Cycles' Hair BSDF samplers are not consistent with its eval (the
reflection sampler spreads its azimuths over pi RoughnessV, its eval stops
at pi / 2): parity needs the sampled closure's own value and pdf
(registry.OWN_WEIGHT); with the eval's instead Ember rendered this scene
-2.74 % +- 0.07 % darker (t -37, 15 of 18 block-channels off).  Measured:
+0.006 % +- 0.074 % (image mean detects 0.34 %, median block 1.4 %); with
the light tree's culling at the diffuse floor -0.020 % +- 0.074 % (the Mix
transmits, so the strands cull nothing)."""
import math

import bpy
import numpy as np
import pytest

import ember_stats as stats

from ember_testlib import (ReferenceCheck, check_against_reference, empty_factory_scene, live_cycles_reference,
                           render_for_reference)
from test_curves_parity import strands

SPP = 256
# The strands against the stored reference: 384 spp for the 0.5 % asked of
# the image mean (256 resolved 0.57 % once the channels' covariance was in
# its variance; with the channel variances summed it had read 0.33 %).
STRANDS_SPP = 384
BLOCK = 16


def hair_bsdf_material(name="hair_bsdf", roughness_u=(0.15, 0.3), roughness_v=(1.0, 0.6),
                       offset=math.radians(2.0)):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new('ShaderNodeOutputMaterial')
    mix = nodes.new('ShaderNodeMixShader')
    mix.inputs[0].default_value = 0.5
    colours = ((0.9, 0.7, 0.5, 1.0), (0.8, 0.5, 0.3, 1.0))
    for i, component in enumerate(('Reflection', 'Transmission')):
        node = nodes.new('ShaderNodeBsdfHair')
        node.component = component
        node.inputs['Color'].default_value = colours[i]
        node.inputs['RoughnessU'].default_value = roughness_u[i]
        node.inputs['RoughnessV'].default_value = roughness_v[i]
        node.inputs['Offset'].default_value = offset
        links.new(node.outputs[0], mix.inputs[1 + i])
    links.new(mix.outputs[0], out.inputs['Surface'])
    return mat


def hair_bsdf_strands(scene):
    strands(scene)
    obj = bpy.data.objects['strands']
    obj.data.materials.clear()
    obj.data.materials.append(hair_bsdf_material())
    return 4


SCENES = {'strands': hair_bsdf_strands}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_hair_bsdf_parity_with_cycles(tmp_path, tapped_engine):
    scene, bounces = reference_scene('strands')
    image, var = render_for_reference(scene, tmp_path, 'hair_bsdf', tapped_engine, STRANDS_SPP, 2, bounces)
    check = check_against_reference('hair_bsdf_strands', scene, bounces, image, var, STRANDS_SPP, BLOCK)
    check.assert_agrees(0.005, 0.02)


def reflection_strands(scene):
    """The strands with the Reflection component alone (RoughnessV 1: a
    third of its samples leave below N)."""
    strands(scene)
    mat = bpy.data.materials.new("reflection")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    node = nodes.new('ShaderNodeBsdfHair')
    node.inputs['Color'].default_value = (0.9, 0.8, 0.7, 1.0)
    node.inputs['RoughnessU'].default_value = 0.2
    node.inputs['RoughnessV'].default_value = 1.0
    links.new(node.outputs[0], nodes.new('ShaderNodeOutputMaterial').inputs['Surface'])
    obj = bpy.data.objects['strands']
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    return 4


def one_glossy_bounce(settings):
    settings.glossy_bounces = 1


LABEL_SEEDS, LABEL_SPP = 4, 256


def test_hair_bsdf_reflection_parity_with_live_cycles(tmp_path, tapped_engine):
    """The Reflection component alone at four bounces, against live Cycles
    seeds.  Its sampler sends a third of its samples below N, where its eval
    is 0, so the image depends on the MIS weights of the BSDF rays that meet
    the light from there: Cycles' light tree gives the light no importance
    at a point without a transmission closure when the light is wholly
    behind N (engine/lighttree.py), so those hits weigh 1.  Measured with
    that rule -0.41 % +- 0.17 % (t -2.4; image mean detects 0.89 %; at twice
    the samples -0.19 % +- 0.12 %, one quadrant -0.61 % +- 0.21 %); with
    |cos| for every closure (Ember before) -3.75 % +- 0.09 % (t -41); those
    with the channel variances summed.  With the channel sum's own variance
    (2.86x that) at 320 spp: -0.10 % +- 0.19 %, image mean detects 0.92 %."""
    scene = empty_factory_scene()
    bounces = reflection_strands(scene)
    # 320 spp for the 1 % asked of the image mean (128 resolved 1.50 % with the
    # channels' covariance in the variance, 0.89 % without); the 3.75 % it
    # guards against needs no more.
    spp = SPP + SPP // 4
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'reflection', LABEL_SEEDS, spp, bounces)
    image, var = render_for_reference(scene, tmp_path, 'reflection', tapped_engine, spp, 2, bounces)
    check = ReferenceCheck('hair_bsdf_reflection', image[..., :3].astype(np.float64), var, spp, ref, ref_var,
                           header, BLOCK)
    check.assert_agrees(0.01)


def channel_sum(image, var):
    """(H, W, 1): a pixel's R + G + B and the measured variance of that sum
    (the last channel of ``var``: Ember's film and the scatter of Cycles'
    seeds, ember_stats.sum_variance).  The channels of a pixel come from the
    same paths, so their errors are correlated (here almost fully: white
    light on near-grey surfaces); the blocks are tested on the sum too."""
    rgb = image[..., :3]
    return rgb.sum(axis=2, keepdims=True), stats.sum_variance(rgb, var)[..., None]


def test_hair_bsdf_labels_parity_with_live_cycles(tmp_path, tapped_engine):
    """Glossy bounces 1 of 4: Cycles counts every Reflection sample a glossy
    bounce, also those below N (its label; Ember: bsdf.sample's labels,
    visibility._labelled), against live Cycles seeds.  The image depends on
    the light tree's rule for points without transmission (lights wholly
    behind N not picked, their BSDF hits weigh 1; engine/lighttree.py):
    without it -2.99 %, counting labels as Ember once did (Glossy bounces 2)
    +5.3 %; the power asked (1.5 %) sees both.

    Measured on the channel sum (``channel_sum``, with the sum's measured
    variance: Ember's film, the seeds' scatter) at these seeds: image
    -0.39 % +- 0.20 %, quadrants within +- 0.34 to 0.51 %, the largest
    -0.99 % +- 0.34 % (t -2.9); the Cauchy-Schwarz bound used before gave
    the same (+- 0.20 %, t -2.9: the channels are almost fully correlated).
    With the channels' variances added as if independent it read +- 0.12 %
    and t -5.0 in that quadrant, a strict xfail until 2026-12-07; three
    other seed sets (Cycles 10-13, 20-23, 30-33) gave images of -0.04, +0.03
    and -0.23 % and their largest |t| in other quadrants (-1.36 % in region
    0,0 at 30), and the four scatter 0.19 % (image) as the sum's variance
    says, not 0.12 %.  Their mean: image
    -0.16 % +- 0.10 %.  Neither NEE alone (Cycles' light MIS off, Ember's
    Light strategy: region 1,1 -0.60 % +- 0.16 % (summed variances) at these
    seeds, -0.00 % +- 0.16 % at seeds 10) nor BSDF sampling alone (an
    emissive plane, Emission Sampling None: -0.5 % +- 0.5 %, summed variances) locates a
    difference."""
    scene = empty_factory_scene()
    bounces = reflection_strands(scene)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'labels', LABEL_SEEDS, LABEL_SPP, bounces,
                                                 configure=one_glossy_bounce)
    image, var = render_for_reference(scene, tmp_path, 'labels', tapped_engine, SPP, 2, bounces,
                                      configure=one_glossy_bounce)
    image, var = channel_sum(image.astype(np.float64), var)
    ref, ref_var = channel_sum(ref, ref_var)
    check = ReferenceCheck('hair_bsdf_labels', image, var, SPP, ref, ref_var, header, BLOCK)
    check.assert_agrees(0.015)


def test_hair_bsdf_hostile_inputs_render_finite(tmp_path, tapped_engine):
    """NaN and zero roughness, an offset of 1e6 radians and a linked Tangent
    input render finite pixels; the linked tangent is named."""
    from addon import engine as ember_engine
    scene = empty_factory_scene()
    bounces = strands(scene, curves=60)
    mat = hair_bsdf_material("hostile", roughness_u=(float('nan'), 0.0), roughness_v=(0.0, float('nan')),
                             offset=1e6)
    tree = mat.node_tree
    hair = next(n for n in tree.nodes if n.type == 'BSDF_HAIR')
    tree.links.new(tree.nodes.new('ShaderNodeTangent').outputs[0], hair.inputs['Tangent'])
    obj = bpy.data.objects['strands']
    obj.data.materials.clear()
    obj.data.materials.append(mat)
    image, _ = render_for_reference(scene, tmp_path, 'hostile', tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()
    warnings = ember_engine.RENDER_LOG[-1].get('warnings') or []
    assert any("Tangent" in w for w in warnings), warnings


def test_hair_bsdf_export(factory_scene):
    """What the export makes of the node (no statistics): one lobe per
    component, its colour, RoughnessU as the roughness, RoughnessV and
    Offset as they are (the engine negates the offset and clamps as Cycles)."""
    from addon.export import material as material_export
    translated, warning = material_export.translate(hair_bsdf_material("export"))
    assert warning is None
    reflection, transmission = translated.lobes
    assert (reflection.kind, transmission.kind) == ('hair_reflection', 'hair_transmission')
    assert reflection.weight == transmission.weight == 0.5
    assert reflection.color == pytest.approx((0.9, 0.7, 0.5)) and transmission.color == pytest.approx((0.8, 0.5, 0.3))
    assert (reflection.roughness, reflection.radial_roughness) == pytest.approx((0.15, 1.0))
    assert (transmission.roughness, transmission.radial_roughness) == pytest.approx((0.3, 0.6))
    assert reflection.offset == pytest.approx(math.radians(2.0)) == transmission.offset
