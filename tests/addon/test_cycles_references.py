"""Scenes held to converged Cycles references (tests/data/cycles_*.exr).

The references are means of 8 x 2048 Cycles samples per pixel at a small
resolution, rendered once by tools/cycles_references.py (bpy 5.0.1; version,
samples, bounces, filter and scene fingerprint in the EXR header) with the
variance of their mean per pixel.  Here Ember renders the same scene through
the add-on's export with a modest sample count and its own per-pixel
variances; the totals of the whole image and of a 3 x 3 grid of regions, and
then blocks per channel (16 x 16 pixels for the Cornell box, 8 x 8 for the
glossy plates), are compared by Welch's t with both noises
(ember_stats.region_mean_tests_var, failing_blocks_var), at the suite's
family level; the power of both is asserted.

A scene is *held* to a relative bias: the test also requires the power to see
it (the image-mean test detects ``HELD`` with probability at least 1/2), so
passing means |Ember - Cycles| / Cycles < HELD over the image, up to that
test's threshold.  The mutation check at the end proves it: the Cornell box
with its light's power scaled by 0.99 must fail.
"""
import dataclasses

import bpy
import numpy as np
import pytest

import ember_stats as stats
from ember_testlib import engine_available, load_reference, references_tool, require, setup_ember

HELD = 0.003            # |relative bias| the image mean must resolve (issue 8: 0.3 %)
BLOCK_HELD = 0.02       # the median block must resolve 2 % (issue 12)
EMBER = {
    # name: (samples per pixel, seed, block side in pixels); power printed by the test
    # 1024: the 0.3 % asked of the image mean with the channels' covariance in
    # its variance (384 resolved 0.46 %; 0.28 % with the channel variances summed).
    'cornell': (1024, 11, 16),
    'glossy_world': (64, 12, 8),
}
MUTANT_SPP = 128        # the mutation only needs to see 1 %


def ember_render(refs, name, spp, seed, light_scale=1.0):
    """The reference scene rendered by Ember (the add-on's export, one pass):
    image and per-pixel variance of its mean (the channel sum's last:
    ember_stats.sum_variance)."""
    from addon import backend
    from addon.export import scene as scene_export
    scene = refs.open_reference_scene(bpy, name)
    scene.render.engine = 'EMBER'
    width, height, bounces = refs.BUILT_HERE[name]
    setup_ember(scene, spp, seed, bounces, *refs.FILTER)
    for light in bpy.data.lights:
        light.energy *= light_scale
    exported = scene_export.export_scene(bpy.context.evaluated_depsgraph_get())
    settings = dataclasses.replace(scene_export.render_settings(scene), samples_per_pass=spp, sum_variance=True)
    result = backend.engine().render(exported.scene, settings)
    image = result.image[..., :3].astype(np.float64)
    assert image.shape == (height, width, 3) and np.isfinite(image).all()
    return image, result.variance_with_sum.astype(np.float64), scene, bounces


def compare(name, image, var, spp, ref, ref_var, header):
    seeds, samples = int(header['seeds']), int(header['samples'])
    tests, level = stats.region_mean_tests_var(image, var, spp - 1, ref, ref_var, seeds - 1,
                                               name=f"{name} against Cycles", splits=3,
                                               float32_sums_b=samples)
    failures = stats.report_mean_tests(f"{name}: Ember against the converged Cycles reference", tests, level)
    return tests, level, failures


@pytest.fixture(scope='module')
def refs(registered_addon):
    ok, reason = engine_available()
    require(ok, "engine.render is not importable: " + reason)
    return references_tool()


@pytest.mark.parametrize("name", sorted(EMBER))
def test_held_to_converged_cycles(name, refs):
    spp, seed, block = EMBER[name]
    image, var, scene, bounces = ember_render(refs, name, spp, seed)
    ref, ref_var, header = load_reference(name, scene, bounces)
    tests, level, failures = compare(name, image, var, spp, ref, ref_var, header)
    image_test = tests[0]
    power = stats.detectable(image_test.relative_se, level, image_test.dof)
    print(f"{name}: Cycles {header['blender']}, {header['seeds']} x {header['samples']} spp; Ember {spp} spp")
    assert power <= HELD, (f"the image-mean test only resolves {power:.2%}, not {HELD:.1%}: "
                           f"more Ember samples needed")
    assert not failures, f"Ember differs from converged Cycles: {failures}"
    # Implied by the two assertions above; stated for the reader.
    assert abs(image_test.relative) < HELD
    blocks, details = stats.failing_blocks_var(image, var, spp - 1, ref, ref_var, int(header['seeds']) - 1,
                                               block, name=f"{name} blocks against Cycles",
                                               float32_sums_b=int(header['samples']))
    print(f"{name}: {details['blocks']} block-channels, max |t| {details['max_abs_t']:.2f}; a bias in one "
          f"block is detected with probability 1/2 from {details['median_block_detects']:.1%} (median block)")
    assert details['median_block_detects'] <= BLOCK_HELD, "the block test lacks power: more Ember samples needed"
    assert len(blocks) == 0, f"blocks (y, x, channel) differ from Cycles: {blocks[:10].tolist()}; {details}"


def test_mutation_light_power_099_is_caught(refs):
    """Mutation check: the Cornell box with its light at 0.99 of its power
    must fail the comparison that holds the real one."""
    image, var, _, _ = ember_render(refs, 'cornell', MUTANT_SPP, 13, light_scale=0.99)
    ref, ref_var, header = load_reference('cornell')
    tests, level, failures = compare('cornell, light x 0.99', image, var, MUTANT_SPP, ref, ref_var, header)
    assert tests[0] in failures and tests[0].relative < 0, f"a 1 % darker light went unnoticed: {tests[0]}"


def test_references_carry_the_channel_sum_variance(tmp_path, monkeypatch):
    """tools/cycles_references.py writes var.sum, the seeds' scatter of
    R + G + B (correlated channels: not the three variances summed), and
    load_reference hands it on as the variance's fourth channel, which
    ember_stats reads as the sum's (no render: synthetic seeds)."""
    import ember_testlib
    tool = references_tool()
    monkeypatch.setattr(tool, 'reference_path', lambda name: str(tmp_path / f'cycles_{name}.exr'))
    monkeypatch.setattr(ember_testlib, 'references_tool', lambda: tool)
    rng = np.random.default_rng(3)
    grey = rng.exponential(1.0, (tool.SEEDS, 6, 5, 1))
    seeds = grey * np.array([0.8, 0.5, 0.2]) + rng.uniform(0.0, 0.1, (tool.SEEDS, 6, 5, 3))
    attributes = {'ember:' + k: v for k, v in dict(tool.expected_header('cornell'), width=5, height=6).items()}
    tool.write_reference(tool.reference_path('cornell'), seeds.mean(axis=0), ember_testlib.seed_variance(seeds),
                         attributes)
    mean, var, header = load_reference('cornell')
    assert var.shape == (6, 5, 4) and header['seeds'] == str(tool.SEEDS)
    expected = seeds.sum(axis=3).var(axis=0, ddof=1) / tool.SEEDS
    np.testing.assert_allclose(stats.sum_variance(mean, var), expected, rtol=1e-6)
    np.testing.assert_allclose(var[..., :3], seeds.var(axis=0, ddof=1) / tool.SEEDS, rtol=1e-6)
    assert (expected > 1.5 * var[..., :3].sum(axis=2)).all(), "correlated channels: more than the sum of three"
