"""Cycles parity of hair curves (engine/points.py Strands, the export's
``_add_curves``): a Curves object of 400 wavy strands of 6 points with a
radius attribute (tapering), a Diffuse BSDF, on a floor under an area
light, traced as round Catmull-Rom curves (Cycles' 3D curves), against a
converged Cycles reference (tools/cycles_references.py curves_strands).
The Principled Hair BSDF is not translated: these strands are diffuse.

The scene sets Render > Curves > Shape to 3D curves: the factory default is
ribbons (flat, camera-facing, no end caps), which Ember does not have (the
export warns); against ribbons Ember was 1.7 % darker (its round strands
covered 3.6 % more of a white world).

Known gap (a strict xfail): against 3D curves Ember is 0.36 % +- 0.06 %
darker (t -6; quadrants -0.19 to -0.56 %); not the strands' ray offset (30x
larger changes nothing), not their shape (a straight strand is the
closed-form cylinder, tests/engine/test_curves.py).  A candidate: Cycles
skips the primitive a ray leaves (its self-intersection rule), Embree's
queries here cannot.  While open, only the image and quadrant means are
tested (one statistical family)."""
import bpy
import numpy as np
import pytest

from parity_scenes import light, material, plane, top_camera
import ember_stats as stats
from ember_testlib import empty_factory_scene, load_reference, render_for_reference, small_resolution

SPP = 256
CURVES, POINTS = 400, 6


def strands(scene, curves=CURVES, zero_length=0):
    plane("floor", material("floor", 'diffuse'))
    light('AREA', (0.5, -0.5, 4.0), 300.0, size=2.0)
    rng = np.random.default_rng(33)
    base = np.c_[rng.uniform(-1.5, 1.5, (curves, 2)), np.zeros(curves)]
    phase = rng.uniform(0, 6, (curves, 1))
    k = np.arange(POINTS)[None, :]
    wave = np.stack([0.15 * np.sin(0.9 * k + phase), 0.1 * np.cos(0.7 * k + phase), 0.18 * k + 0 * phase], axis=2)
    points = base[:, None, :] + wave
    points[:zero_length] = base[:zero_length, None, :]          # zero-length strands: every point at the root
    radii = np.tile(np.linspace(0.03, 0.008, POINTS), curves)
    data = bpy.data.hair_curves.new("strands")
    data.add_curves([POINTS] * curves)
    data.attributes['position'].data.foreach_set('vector', points.reshape(-1).astype(np.float32))
    radius = data.attributes.new('radius', 'FLOAT', 'POINT')
    radius.data.foreach_set('value', radii.astype(np.float32))
    data.materials.append(material("hair", 'diffuse', color=(0.7, 0.45, 0.2)))
    obj = bpy.data.objects.new("strands", data)
    scene.collection.objects.link(obj)
    top_camera(scene, 5.0)
    small_resolution(scene, 48, 32)
    scene.cycles_curves.shape = 'THICK'   # 3D curves (the factory default is ribbons)
    return 2


SCENES = {'strands': strands}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


@pytest.mark.xfail(strict=True, reason="0.36 % darker than Cycles' 3D curves, cause open (module docstring)")
def test_curves_parity_with_cycles(tmp_path, tapped_engine):
    scene, bounces = reference_scene('strands')
    image, var = render_for_reference(scene, tmp_path, 'strands', tapped_engine, SPP, 2, bounces)
    ref, ref_var, header = load_reference('curves_strands', scene, bounces)
    # the image and quadrant means only (one family while it is a known gap)
    tests, level = stats.region_mean_tests_var(image[..., :3].astype(np.float64), var, SPP - 1, ref, ref_var,
                                               int(header['seeds']) - 1, name="curves against Cycles",
                                               float32_sums_b=int(header['samples']))
    failures = stats.report_mean_tests(f"curves_strands: Ember ({SPP} spp) against Cycles", tests, level)
    assert stats.detectable(tests[0].relative_se, level, tests[0].dof) <= 0.005
    assert not failures, failures


def test_zero_length_strands_render_finite(tmp_path, tapped_engine):
    scene = empty_factory_scene()
    bounces = strands(scene, curves=60, zero_length=20)
    image, _ = render_for_reference(scene, tmp_path, 'zero', tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()
