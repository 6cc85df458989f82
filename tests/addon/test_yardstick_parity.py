"""The yardstick scenes of `make bench-cycles` (tools/bench_scenes.py) at the
bench's settings, against converged Cycles references.

The speed table (docs/benchmarks.md) compares the time each engine needs
for the same noise: that says nothing unless both converge to the same
image.  Cornell and Veach are held by test_render_scenes.py; this module
holds the others, built by the bench's own builders, at 8 bounces of every
kind (the bench's setting), Filter Glossy off and Ember's default light
selection ('auto'), at a small resolution.  The 2.1 M-triangle instanced
scene is left to test_render_scenes.py's instances_lights (the same
exporter path at a size the suite can afford).

Reference: tools/cycles_references.py renders tests/data/cycles_yardstick_<name>.exr
with Cycles (8 seeds); Ember's image, with its per-pixel variance, must agree
over the whole image and its quadrants and in every block (Welch's t at the
suite's family level); the power of each is printed and asserted.
"""
import os
import sys

import pytest

from ember_testlib import render_against_reference, small_resolution

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
BOUNCES = 8          # tools/bench_cycles.py's default
WIDTH, HEIGHT = 48, 48
SCENES = {
    # name: (Ember samples, block side, (image power, block power) asserted)
    # principled 256 -> 512, emissive 1024 -> 1536, glossy_lights 512 -> 1280: with the channel sum's
    # variance they resolved 1.30 %, 1.09 % and 1.31 % of the image, not 1 %.
    'principled': (512, 12, (0.01, 0.05)),
    'many_lights': (256, 12, (0.01, 0.05)),
    'emissive': (1536, 12, (0.01, 0.05)),   # small glowing spheres: rare bright paths
    'hdri': (256, 12, (0.01, 0.05)),
    'procedural': (128, 12, (0.01, 0.05)),
    'glossy_lights': (1280, 12, (0.01, 0.05)),   # small sharp highlights: heavy-tailed
    'interior': (1024, 12, (0.01, 0.05)),   # lit through a window: mostly bounced light
}


def _bench_builder(name):
    tools = os.path.join(ROOT, 'tools')
    if tools not in sys.path:
        sys.path.insert(0, tools)
    import bench_scenes
    return bench_scenes.SCENES[name][1]


def reference_scene(name, folder=None):
    """The bench's scene ``name`` at the tests' resolution (as
    tools/cycles_references.py renders it) and its bounces."""
    scene = _bench_builder(name)()       # the bench's builders start from an empty file
    small_resolution(scene, WIDTH, HEIGHT)
    return scene, BOUNCES


@pytest.mark.parametrize('name', sorted(SCENES))
def test_yardstick_scene_agrees_with_cycles(name, tmp_path, tapped_engine):
    spp, block, power = SCENES[name]
    scene, bounces = reference_scene(name)
    check = render_against_reference('yardstick_' + name, scene, bounces, tmp_path, tapped_engine, spp, block)
    check.assert_agrees(*power)
