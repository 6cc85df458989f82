"""Cycles parity of Filter Glossy (Light Paths > Caustics; scene.ember.filter_glossy,
engine/integrator/stages.filter_glossy): Cycles' default of 1.0 blurs
glossy lobes after blurry bounces, so a third-party file renders its
caustics and glossy-after-diffuse paths blurred; Ember must do the same to
match it (before, its floor near glossy spheres sparkled with fireflies
Cycles does not have, and its image mean was 1.7-2.5% high).  A smooth
glossy sphere and a smooth glass sphere on a diffuse floor under a small
area light, both engines with Filter Glossy 1.0 against a live Cycles
reference (8 seeds) by the suite's region and block tests, power printed;
Ember's image must also differ from its own with the filter off."""
import bpy
import numpy as np
import pytest

from parity_scenes import glass_material, smooth_sphere, light, material, plane
from ember_testlib import (ReferenceCheck, empty_factory_scene, live_cycles_reference, render_for_reference,
                           small_resolution)

SIZE = (40, 30)
BLOCK = 10
BOUNCES = 4
EMBER_SPP = 1024
CYCLES_SEEDS, CYCLES_SPP = 8, 128
FILTER = 1.0


def caustics(scene):
    plane('floor', material('floor', 'diffuse', (0.8, 0.8, 0.8)), half=3.0)
    smooth_sphere('mirror', material('mirror', 'glossy', (0.9, 0.9, 0.9), roughness=0.0), (-0.6, 0.0, 0.5))
    smooth_sphere('glass', glass_material('glass'), (0.6, 0.0, 0.5))
    light('AREA', (0.0, 0.8, 2.2), 60.0, size=0.25)
    background = scene.world.node_tree.nodes.get('Background')
    if background is not None:
        background.inputs['Color'].default_value = (0.0, 0.0, 0.0, 1.0)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, -3.6, 2.0), (np.radians(62.0), 0.0, 0.0)
    cam.data.lens = 35.0
    small_resolution(scene, *SIZE)


def _filter(value):
    return lambda settings: setattr(settings, 'blur_glossy' if hasattr(settings, 'blur_glossy')
                                    else 'filter_glossy', value)


def _render_all(tmp_path, tapped_engine):
    scene = empty_factory_scene()
    caustics(scene)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'filter_glossy', CYCLES_SEEDS, CYCLES_SPP,
                                                 BOUNCES, configure=_filter(FILTER))
    image, var = render_for_reference(scene, tmp_path, 'filter_glossy', tapped_engine, EMBER_SPP, 5, BOUNCES,
                                      configure=_filter(FILTER))
    sharp, _ = render_for_reference(scene, tmp_path, 'filter_off', tapped_engine, 128, 5, BOUNCES,
                                    configure=_filter(0.0))
    return ref, ref_var, header, image[..., :3].astype(np.float64), var, sharp[..., :3].astype(np.float64)


def _block_error(image, ref):
    import ember_stats as stats
    a, b = stats.block_means(image[None], BLOCK)[0], stats.block_means(ref[None], BLOCK)[0]
    return float(np.mean(np.abs(a - b)) / np.mean(b))


def test_filter_glossy_matches_cycles(tmp_path, tapped_engine):
    """The filter closes most of the gap to Cycles' default (mean |block
    error| at most a third of the unfiltered image's, which is 22% here),
    and the region and block tests agree with Cycles.  Until rough
    refraction scored the pairs no microfacet joins as Cycles does
    (engine/lobes/glass.py: unjoined), the blurred glass sphere's caustic
    was 1.9% +- 0.4% dark and this was a strict xfail."""
    ref, ref_var, header, image, var, sharp = _render_all(tmp_path, tapped_engine)
    on, off = _block_error(image, ref), _block_error(sharp, ref)
    print(f"filter_glossy: mean |block error| against Cycles (Filter Glossy {FILTER}): {on:.3f} with the "
          f"filter, {off:.3f} without")
    assert off > 0.05, f"Filter Glossy changes little here ({off:.3f}): the test shows nothing"
    assert on < off / 3, f"the filter leaves {on:.3f} of block error against Cycles (without: {off:.3f})"
    ReferenceCheck('filter_glossy', image, var, EMBER_SPP, ref, ref_var, header, BLOCK).assert_agrees()
