"""Render blend_scenes/ with Ember: real pixels, and agreement with Cycles.

Agreement is a statistical test, not a tolerance: Ember's render, with the
variance of each pixel's mean, against a converged Cycles reference rendered
once by tools/cycles_references.py (tests/data/cycles_scenes_<scene>.exr,
with the variance of its mean): Welch's t on the totals of the whole image
and its quadrants and on every block and channel, at the suite's family level
(tests/ember_stats.py), must not reject.  The power of each is printed
(pytest -s shows it).  The Cornell box is held by test_cycles_references.py.
"""
import numpy as np
import pytest

import ember_stats as stats
from ember_testlib import (check_against_reference, load_reference, open_scene, render_array, render_for_reference,
                           setup_ember, small_resolution)

EMBER_SPP = 64        # one sample per pass -> 64 passes (test_ember_renders_real_pixels)
PARITY = {
    # name: (Ember samples, block side in pixels, image and block power asserted)
    # 640: 384 resolved 0.57 % of the image, not 0.5 % (the channel sum's variance).
    'instances_lights': (640, 16, (0.005, 0.02)),
    # Veach's plates reflect four small, very bright lights, and the lights
    # themselves are in view: ten pixels on the lights' rims hold 90 % of the
    # image's variance in both renderers (the pixel filter's samples), so the
    # image target of 0.5 % would take some 20 times more samples.  The image
    # mean is held to the power derived from the reference: what it resolves
    # at Cycles' noise per sample and Ember's 512 samples (2.9 %; measured
    # 2.3 %); the blocks to the suite's 2 % (measured 1.5 %).  Issue 27: it
    # was a hand-set 4.5 %, 3 %.
    'veach_mis': (512, 16, ('cycles', 0.02)),
}
REFERENCE_NAMES = {'cornell': 'cornell', 'veach_mis': 'scenes_veach_mis',
                   'instances_lights': 'scenes_instances_lights'}
SCENES = {
    # name: (width, height, max bounces)
    'cornell': (48, 48, 4),
    'veach_mis': (64, 48, 3),
    'instances_lights': (64, 48, 3),
}


def reference_scene(name, folder=None):
    """The scene ``name`` at the tests' resolution and its bounces (as
    tools/cycles_references.py renders it)."""
    scene = open_scene(name)
    width, height, bounces = SCENES[name]
    small_resolution(scene, width, height)
    return scene, bounces


def ember_render(name, tmp_path, taps):
    scene, bounces = reference_scene(name)
    setup_ember(scene, EMBER_SPP, seed=1, max_bounces=bounces)
    image = render_array(scene, tmp_path, "ember_" + name)
    return scene, image, taps[-1].images


@pytest.mark.parametrize("name", sorted(SCENES))
def test_ember_renders_real_pixels(name, tmp_path, tapped_engine):
    """Progressive passes, finite pixels, opaque alpha, the image and its
    quadrants against the converged Cycles reference, and what each scene
    must show (coloured walls, a directly lit floor, glossy highlights)."""
    _, image, passes = ember_render(name, tmp_path, tapped_engine)
    from addon import engine as ember_engine
    assert ember_engine.RENDER_LOG[-1]['error'] is None
    assert len(passes) >= 2, "the engine must display progressive passes"
    rgb = image[..., :3]
    assert np.isfinite(image).all(), "NaN or inf pixels"
    assert (image[..., 3] == 1.0).all()
    luminance = rgb @ np.array([0.2126, 0.7152, 0.0722])
    h, w = luminance.shape
    # The image and its quadrants against the converged Cycles reference
    # (one family: Welch's t on each total, with Ember's per-pixel variance),
    # where this test only asked for a quadrant mean above 1e-3.
    scene, bounces = reference_scene(name)
    ref, ref_var, header = load_reference(REFERENCE_NAMES[name], scene, bounces)
    var = tapped_engine[-1].result.variance_with_sum.astype(np.float64)
    tests, level = stats.region_mean_tests_var(
        rgb.astype(np.float64), var, EMBER_SPP - 1, ref, ref_var, int(header['seeds']) - 1,
        name=f"{name} quadrants against Cycles", float32_sums_b=int(header['samples']))
    failures = stats.report_mean_tests(f"{name}: Ember ({EMBER_SPP} spp, 1 per pass) against converged Cycles",
                                       tests, level)
    assert not failures, f"{name}: the image or a quadrant differs from Cycles: {failures}"
    if name == 'cornell':
        middle = rgb[h // 3: 2 * h // 3]
        left, right = middle[:, 1:w // 8].mean(axis=(0, 1)), middle[:, -w // 8:-1].mean(axis=(0, 1))
        assert left[0] > 2 * left[1], f"left wall should be red: {left}"
        assert right[1] > 1.5 * right[0], f"right wall should be green: {right}"
        # Lights are invisible to camera rays by default (Blender's object
        # visibility); the ceiling is lit only indirectly, the floor directly.
        floor = luminance[7 * h // 8:, 3 * w // 8:5 * w // 8].mean()
        ceiling = luminance[:h // 8, 3 * w // 8:5 * w // 8].mean()
        assert floor > 1.5 * ceiling, f"floor {floor} should outshine the ceiling {ceiling}"
    if name == 'veach_mis':
        plates = luminance[h // 2:]
        assert plates.max() > 10 * np.median(plates), "no glossy highlights on the plates"


@pytest.mark.parametrize("name", sorted(PARITY))
def test_agrees_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name)
    spp, block, power = PARITY[name]
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 1, bounces)
    check = check_against_reference('scenes_' + name, scene, bounces, image, var, spp, block)
    check.assert_agrees(*(power or (None, None)))


def test_cancel_with_the_real_engine(factory_scene, monkeypatch, tmp_path, tapped_engine):
    """Esc (test_break) between passes stops the engine and keeps its image."""
    from addon import engine as ember_engine
    from addon import output
    def esc_after_two_passes(engine):
        # Also asked during export and scene preparation: Esc once two passes
        # are shown (automatic passes: 1 + 1 samples; the third, 2).
        return ember_engine.RENDER_LOG[-1]['passes'] >= 2
    monkeypatch.setattr(output, 'break_requested', esc_after_two_passes)
    small_resolution(factory_scene, 32, 24)
    setup_ember(factory_scene, 500, seed=0, max_bounces=2)
    image = render_array(factory_scene, tmp_path, "cancelled")
    log = ember_engine.RENDER_LOG[-1]
    assert log['cancelled'] and log['error'] is None
    assert log['samples'] == tapped_engine[-1].images[-1][0] < 500
    np.testing.assert_allclose(image, tapped_engine[-1].images[-1][1].astype(np.float32), atol=1e-6)
    assert image[..., :3].mean() > 0.01, "the partial image was lost"
