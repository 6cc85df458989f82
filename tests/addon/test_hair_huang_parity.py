"""Cycles parity of the Principled Hair BSDF's Huang model
(engine/lobes/hair_huang.py, the export's ``_node_bsdf_hair_principled``)
on test_curves_parity's Curves object (400 wavy strands of 6 points, radius
0.03 tapering to 0.008, 3D curves, a diffuse floor under an area light, seen
from above; four bounces) at 64 x 48, Melanin 0.6 (redness 0.3), Roughness
0.3, IOR 1.55, Offset 2 degrees, Aspect Ratio 1 (round) and 0.85
(elliptical, the major axis along Blender's curve normals), against converged
Cycles references (tools/cycles_references.py hair_huang_*, 8 x 1024 spp:
rendered live in each run before, a minute each).  At
this size a pixel is about as wide as the roots: camera rays meet both
Cycles' near field (a fibre wider than half a pixel) and its far field.

Also: the export of the node (aspect, gains, the roughness as the radial
roughness) and hostile inputs (Aspect Ratio 0 and NaN, negative gains)."""
import math

import bpy
import numpy as np
import pytest

from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference, small_resolution
from test_curves_parity import strands
from test_hair_parity import hair_material

SPP = 256
BLOCK = 16


def huang_material(name="huang", aspect=0.85, gains=(1.0, 1.0, 1.0), melanin=0.6):
    """test_hair_parity's Principled Hair material switched to the Huang model."""
    mat = hair_material(name, melanin=melanin, redness=0.3)
    node = next(n for n in mat.node_tree.nodes if n.bl_idname == 'ShaderNodeBsdfHairPrincipled')
    node.model = 'HUANG'
    node.inputs['Aspect Ratio'].default_value = aspect
    for name_, gain in zip(('Reflection', 'Transmission', 'Secondary Reflection'), gains):
        node.inputs[name_].default_value = gain
    return mat


def huang_strands(scene, aspect, curves=400):
    strands(scene, curves=curves)
    obj = bpy.data.objects['strands']
    obj.data.materials.clear()
    obj.data.materials.append(huang_material(aspect=aspect))
    small_resolution(scene, 64, 48)
    return 4


ASPECTS = {'round': 1.0, 'elliptical': 0.85}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, huang_strands(scene, ASPECTS[name])


@pytest.mark.parametrize("shape", list(ASPECTS))
def test_huang_parity_with_cycles(tmp_path, tapped_engine, shape):
    scene, bounces = reference_scene(shape)
    image, var = render_for_reference(scene, tmp_path, shape, tapped_engine, SPP, 2, bounces)
    check_against_reference(f"hair_huang_{shape}", scene, bounces, image, var, SPP, BLOCK).assert_agrees(0.01, 0.03)


def test_huang_export(factory_scene):
    """What the export makes of the node (no statistics)."""
    from addon.export import material as material_export
    translated, warning = material_export.translate(huang_material("export", aspect=1.25, gains=(0.5, -1.0, 2.0)))
    assert warning is None
    (lobe,) = translated.lobes
    assert lobe.kind == 'hair_huang'
    assert lobe.aspect_ratio == pytest.approx(1.25)
    assert lobe.hair_gains == pytest.approx((0.5, 0.0, 2.0))
    assert lobe.roughness == pytest.approx(0.3) and lobe.ior == pytest.approx(1.55)
    assert lobe.offset == pytest.approx(math.radians(2.0))


def test_huang_hostile_inputs_render_finite(tmp_path, tapped_engine):
    """Aspect Ratio 0 and NaN, negative gains: finite pixels."""
    scene = empty_factory_scene()
    bounces = huang_strands(scene, 0.0, curves=60)
    obj = bpy.data.objects['strands']
    obj.data.materials.append(huang_material("nan", aspect=float('nan'), gains=(-1.0, float('nan'), 1.0)))
    data = obj.data
    index = np.zeros(len(data.curves), np.int32)
    index[::2] = 1
    data.attributes.new('material_index', 'INT', 'CURVE').data.foreach_set('value', index)
    image, _ = render_for_reference(scene, tmp_path, 'huang_hostile', tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()
