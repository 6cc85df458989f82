"""Cycles parity of hair curves (engine/points.py Strands, the export's
``_add_curves``): a Curves object of 400 wavy strands of 6 points with a
radius attribute (tapering), a Diffuse BSDF, on a floor under an area
light, traced as round Catmull-Rom curves (Cycles' 3D curves), against a
converged Cycles reference (tools/cycles_references.py curves_strands).
The strands are diffuse (test_hair_parity.py: the Principled Hair BSDF).

The scene sets Render > Curves > Shape to 3D curves: the factory default is
ribbons (flat, camera-facing, no end caps: test_ribbons_parity.py), against
which Ember's round strands were 1.7 % darker before it had ribbons (they
covered 3.6 % more of a white world).

It was 0.36 % +- 0.06 % darker than Cycles (t -6): rays leaving a strand
met it again, which Cycles' rays never do (they skip the curve they leave,
engine/accel.py intersect_skipping); now -0.03 % +- 0.06 %.  The image and
region means and 16 x 16-pixel blocks are tested."""
import bpy
import numpy as np

from parity_scenes import hair_curves, light, material, plane, top_camera
from ember_testlib import check_against_reference, empty_factory_scene, render_for_reference, small_resolution

SPP = 256
BLOCK = 16
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
    hair_curves(scene, points, radii, POINTS, curves)
    top_camera(scene, 5.0)
    small_resolution(scene, 48, 32)
    scene.cycles_curves.shape = 'THICK'   # 3D curves (the factory default is ribbons)
    return 2


SCENES = {'strands': strands}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    scene = empty_factory_scene()
    return scene, SCENES[name](scene)


def test_curves_parity_with_cycles(tmp_path, tapped_engine):
    scene, bounces = reference_scene('strands')
    image, var = render_for_reference(scene, tmp_path, 'strands', tapped_engine, SPP, 2, bounces)
    check = check_against_reference('curves_strands', scene, bounces, image, var, SPP, BLOCK)
    check.assert_agrees(0.005, 0.02)


def test_zero_length_strands_render_finite(tmp_path, tapped_engine):
    scene = empty_factory_scene()
    bounces = strands(scene, curves=60, zero_length=20)
    image, _ = render_for_reference(scene, tmp_path, 'zero', tapped_engine, 4, 2, bounces)
    assert np.isfinite(image).all()
