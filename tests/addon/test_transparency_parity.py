"""Cycles parity for transparent surfaces (issue 4): transparent shadows and
transparent bounces.

A point light and an area light shine through two planes onto a floor: a
Principled BSDF with Alpha 0.4 and a Mix(Transparent, Diffuse).  Both renderers
use the same max and transparent max bounces.  Rendered by Ember (one sample
per pass: independent batches) and by Cycles with several seeds, compared
block by block with Welch's t, Sidak-corrected to a family-wise 1% (as
test_light_parity.py); the relative mean error per scene is printed.
"""
import time

import bpy
import numpy as np
import pytest

import ember_stats as stats
from ember_testlib import per_pass_estimates, render_array, setup_cycles, setup_ember
from test_light_parity import light, material, plane, top_camera

EMBER_SPP = 48
CYCLES_SEEDS = 6
CYCLES_SPP = 16
BLOCK = 4
BOUNCES = 3


def alpha_material(alpha):
    mat = bpy.data.materials.new("alpha")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes['Principled BSDF']
    bsdf.inputs['Base Color'].default_value = (0.8, 0.5, 0.3, 1.0)
    bsdf.inputs['Alpha'].default_value = alpha
    return mat


def mix_material(fac):
    """Mix(Diffuse, Transparent): fac of the light goes straight through."""
    mat = bpy.data.materials.new("mix")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    out = nodes.new('ShaderNodeOutputMaterial')
    diffuse = nodes.new('ShaderNodeBsdfDiffuse')
    diffuse.inputs['Color'].default_value = (0.3, 0.5, 0.8, 1.0)
    clear = nodes.new('ShaderNodeBsdfTransparent')
    clear.inputs['Color'].default_value = (1.0, 0.9, 0.8, 1.0)
    mix = nodes.new('ShaderNodeMixShader')
    mix.inputs['Fac'].default_value = fac
    links.new(diffuse.outputs[0], mix.inputs[1])
    links.new(clear.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs['Surface'])
    return mat


def two_planes(scene):
    """The floor, the Alpha 0.4 plane (left) and the Mix plane (right) at
    1 m; the camera sees planes and floor, so camera rays cross them too."""
    plane("floor", material("floor", 'diffuse'))
    left = plane("alpha", alpha_material(0.4), half=0.7, z=1.0)
    left.location = (-0.8, 0.0, 0.0)
    right = plane("mix", mix_material(0.5), half=0.7, z=1.0)
    right.location = (0.8, 0.0, 0.0)
    top_camera(scene, 6.0)


def point_light(scene):
    two_planes(scene)
    light('POINT', (0.0, 0.0, 2.5), 300.0, shadow_soft_size=0.05)


def area_light(scene):
    two_planes(scene)
    light('AREA', (0.0, 0.0, 2.5), 300.0, shape='SQUARE', size=0.8)


SCENES = {'point_light': point_light, 'area_light': area_light}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_transparency_parity_with_cycles(name, empty_scene, tmp_path, tapped_engine):
    scene = empty_scene
    SCENES[name](scene)
    t0 = time.perf_counter()
    setup_ember(scene, EMBER_SPP, seed=4, max_bounces=BOUNCES)
    assert scene.ember.transparent_max_bounces == BOUNCES
    image = render_array(scene, tmp_path, "ember_" + name)
    from addon import engine as ember_engine
    assert ember_engine.RENDER_LOG[-1]['error'] is None
    assert np.isfinite(image).all()
    ember_batches = per_pass_estimates(tapped_engine[-1].images)[..., :3]
    t1 = time.perf_counter()
    cycles_images = []
    for seed in range(CYCLES_SEEDS):
        setup_cycles(scene, CYCLES_SPP, seed, BOUNCES)
        assert scene.cycles.transparent_max_bounces == BOUNCES
        cycles_images.append(render_array(scene, tmp_path, f"cycles_{name}_{seed}")[..., :3])
    t2 = time.perf_counter()
    cycles = np.array(cycles_images, dtype=np.float64)
    failures, details = stats.failing_blocks(stats.block_means(ember_batches, BLOCK),
                                             stats.block_means(cycles, BLOCK))
    print(f"\n{name}: relative mean error vs Cycles {details['relative_mean_error']:.4f}, "
          f"mean |block error| {details['relative_abs_error']:.4f}, max |t| {details['max_abs_t']:.2f} "
          f"over {details['blocks']} block-channels; Ember {t1 - t0:.1f}s, Cycles {t2 - t1:.1f}s")
    assert image[..., :3].mean() > 1e-3, "black image"
    assert len(failures) == 0, (
        f"{len(failures)} blocks differ from Cycles (block, y, x, channel): {failures[:10].tolist()}; {details}")


def test_transparent_max_bounces_is_exported(factory_scene):
    from addon.export import scene as scene_export
    ember = factory_scene.ember
    assert ember.transparent_max_bounces == factory_scene.cycles.transparent_max_bounces == 8
    ember.transparent_max_bounces = 3
    assert scene_export.render_settings(factory_scene).transparent_max_bounces == 3
