"""The Vector pass against Cycles' (issue 24): the motion-blur parity scene
(tests/addon/test_motion_parity.py: a sliding cube, a tumbling torus, a box
sheared by a shape key, a moving, turning camera; keys at frames 1 and 3)
rendered at frame 2 with motion blur off, so both renderers write each first
hit's motion to frames 1 and 3.  Ember and Cycles seeds through Blender into
multilayer EXRs, compared by seed_block_test (Welch t per 4x4 block and of
the image mean).  With motion blur on, the pass is 0 (Cycles' rule)."""
import os

import bpy
import numpy as np
import pytest

from ember_testlib import (multilayer_output, read_multilayer_exr, require, seed_block_test, setup_cycles,
                           setup_ember, small_resolution, empty_factory_scene)
import test_motion_parity as motion_scene

SEEDS, SPP, CYCLES_SEEDS, CYCLES_SPP = 8, 8, 8, 16
WIDTH, HEIGHT = 32, 32


def _scene(blur=False):
    scene = empty_factory_scene()
    motion_scene.objects(scene, blur=blur)
    small_resolution(scene, WIDTH, HEIGHT)
    bpy.context.view_layer.use_pass_vector = True
    multilayer_output(scene)
    return scene


def _render(scene, folder, engine, seed, spp):
    (setup_ember if engine == 'EMBER' else setup_cycles)(scene, spp, 100 + seed, 0)
    scene.render.filepath = os.path.join(str(folder), f"{engine}_{seed}.exr")
    bpy.ops.render.render(write_still=True)
    return read_multilayer_exr(scene.render.filepath)


@pytest.fixture(scope="module")
def renders(registered_addon, tmp_path_factory):
    require(bpy.app.version >= (5, 0, 0), "the motion scene's keyframes need Blender 5.0's actions")
    folder = tmp_path_factory.mktemp("vector")
    scene = _scene()
    out = {'EMBER': [_render(scene, folder, 'EMBER', s, SPP)['Vector'] for s in range(SEEDS)],
           'CYCLES': [_render(scene, folder, 'CYCLES', s, CYCLES_SPP)['Vector'] for s in range(CYCLES_SEEDS)]}
    return {k: np.array(v) for k, v in out.items()}


def test_vector_pass_matches_cycles(renders):
    ember, cycles = renders['EMBER'], renders['CYCLES']
    # the scene moves: most pixels carry motion of several pixels a frame
    assert (np.abs(cycles.mean(axis=0)) > 0.5).mean() > 0.5
    seed_block_test("vector parity blocks", "vector parity image mean", "Vector", ember, cycles)


def test_vector_pass_is_zero_with_motion_blur_on(registered_addon, tmp_path):
    scene = _scene(blur=True)
    for engine in ('EMBER', 'CYCLES'):
        vector = _render(scene, tmp_path, engine, 0, 1)['Vector']
        assert np.all(vector == 0.0), engine


def test_vector_pass_of_a_one_frame_range(registered_addon, tmp_path):
    """Frames outside the scene's range are still evaluated (as Cycles does)."""
    scene = _scene()
    scene.frame_start = scene.frame_end = scene.frame_current
    vector = _render(scene, tmp_path, 'EMBER', 0, 1)['Vector']
    assert np.isfinite(vector).all() and np.abs(vector).max() > 0.5
