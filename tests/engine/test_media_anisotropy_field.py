"""A textured Henyey-Greenstein g (engine/media/field.py: Volume.anisotropy
an expression, evaluated where paths scatter and where their direct light
is sampled).

Truth from outside the field: one tall box whose density is textured to 0
in a middle gap and whose g steps from -0.6 (below) to 0.8 (above) renders
as two separate homogeneous slabs of constant g (-0.6 and 0.8) with the
same gap, sigma_s and light: the image means and blocks agree (block and
image z-tests, power printed); with the textured g read as 0 they do not.
"""
import numpy as np

from ember_stats import block_means_var, family_z, z_scores
from engine.media import field as fieldmod
from engine.render import render
from engine.scene import (Camera, Instance, Lobe, Material, Math, MixColor, NodeCall, NodeOutput, RenderSettings,
                          Scene, SunLight, Volume, World)
from engine.testscenes import box, look_at

PASS = (Lobe("transparent", (1.0, 1.0, 1.0)),)
SIGMA = 1.5
LOW, HIGH = -0.6, 0.8
SPP = 192


def gen_z():
    coords = NodeCall("ShaderNodeTexCoord", {}, {"object_inverse": None})
    return NodeOutput(NodeCall("ShaderNodeSeparateXYZ", {"Vector": NodeOutput(coords, "Generated")}), "Z")


def _lit(meshes, instances, materials):
    cam = Camera(look_at((0.0, -4.0, 2.5), (0.0, 0.0, 0.0)), lens=55.0, resolution=(24, 24))
    sun = SunLight(direction=(0.35, 0.25, -1.0), strength=(3.0, 3.0, 3.0), angle=0.05)
    return Scene(meshes, instances, materials, [sun], World((0.0, 0.0, 0.0)), cam)


def textured_scene(g=None):
    """A 2 x 2 x 1.2 box: density SIGMA outside Generated z in (5/12, 7/12)
    (the gap z in (-0.1, 0.1)), g LOW below the middle and HIGH above
    (``g`` given: that expression instead)."""
    z = gen_z()
    gap = Math("MULTIPLY", Math("GREATER_THAN", z, 5.0 / 12.0), Math("LESS_THAN", z, 7.0 / 12.0))
    density = Math("MULTIPLY", Math("SUBTRACT", 1.0, gap), SIGMA)
    g = Math("MULTIPLY_ADD", Math("GREATER_THAN", z, 0.5), HIGH - LOW, LOW) if g is None else g
    vol = Volume(scattering=MixColor("MULTIPLY", 1.0, (1.0, 1.0, 1.0), density, clamp_factor=False),
                 anisotropy=g)
    return _lit([box((2.0, 2.0, 1.2))], [Instance(0, np.eye(4), [0], "tall")],
                [Material("stepped", PASS, volume=vol)])


def slabs_scene():
    """Two 2 x 2 x 0.5 homogeneous slabs at z in (-0.6, -0.1) and (0.1, 0.6)."""
    mats = [Material(f"slab{g}", PASS, volume=Volume(scattering=(SIGMA,) * 3, anisotropy=g)) for g in (LOW, HIGH)]
    inst = []
    for k, zc in enumerate((-0.35, 0.35)):
        m = np.eye(4)
        m[2, 3] = zc
        inst.append(Instance(0, m, [k], f"slab{k}"))
    return _lit([box((2.0, 2.0, 0.5))], inst, mats)


def _render(scene, seed):
    r = render(scene, RenderSettings(samples=SPP, samples_per_pass=SPP, seed=seed, max_bounces=2, volume_bounces=0))
    assert np.isfinite(r.image).all()
    return r


def _compare(a, b, zc):
    """(max block |z|, image |z|, image relative se) of renders a and b."""
    ba = block_means_var(a.image[..., :3].astype(np.float64), a.variance.astype(np.float64), 5)
    bb = block_means_var(b.image[..., :3].astype(np.float64), b.variance.astype(np.float64), 5)
    keep = bb[0] > 0.02 * bb[0].max()
    z = z_scores(*ba, *bb)[keep]
    ma, mb = (r.image[..., :3].astype(np.float64).sum() for r in (a, b))
    se = np.sqrt(sum(r.variance[..., :3].astype(np.float64).sum() for r in (a, b)))
    return np.abs(z).max(), abs(ma - mb) / se, se / mb, keep.sum()


def test_textured_anisotropy_matches_constant_slabs():
    zc = family_z(__name__ + ".slabs", 2 * 48 + 2)
    slabs = _render(slabs_scene(), 5)
    stepped = _render(textured_scene(), 6)
    block_z, image_z, rel_se, blocks = _compare(stepped, slabs, zc)
    print(f"textured g vs constant slabs: {blocks} block-channels, max |z| {block_z:.2f}, image |z| {image_z:.2f} "
          f"(limit {zc:.2f}), image detects {zc * rel_se:.2%}")
    flat = _render(textured_scene(g=Math("MULTIPLY", gen_z(), 0.0)), 6)
    flat_block, flat_image, _, _ = _compare(flat, slabs, zc)
    print(f"g read as 0: max block |z| {flat_block:.2f}, image |z| {flat_image:.2f}")
    assert blocks >= 20 and zc * rel_se < 0.05
    assert block_z < zc and image_z < zc
    assert max(flat_block, flat_image) > zc


def test_nan_and_out_of_range_textured_anisotropy_are_repaired():
    field = fieldmod.Field.__new__(fieldmod.Field)
    field.repaired = {"NaN": 0, "negative": 0, "too large": 0, "NaN anisotropy": 0}
    field.name = "swirl"
    got = field._anisotropy(np.array([np.nan, 5.0, -7.0, 0.3, np.inf]), 5)
    np.testing.assert_array_equal(got, [0.0, 1.0, -1.0, 0.3, 1.0])
    w = field.warning()
    assert "'swirl'" in w and "NaN anisotropy (1 values)" in w, w
