"""Helpers shared by the add-on tests (imported after conftest has set up bpy)."""
import os

import bpy
import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SCENES_DIR = os.path.join(ROOT, 'blend_scenes')
SCENE_NAMES = ('cornell', 'veach_mis', 'instances_lights')


def in_ci():
    return os.environ.get('CI', '').lower() == 'true'


def require(condition, reason):
    """Skip locally, fail in CI, when a prerequisite is missing."""
    if condition:
        return
    if in_ci():
        pytest.fail("missing prerequisite (CI=true): " + reason)
    pytest.skip(reason)


def engine_available():
    """True once the renderer exposes engine.render.render."""
    try:
        from addon import backend
        backend.render_function()
    except ImportError as err:
        return False, str(err)
    return True, ""


def open_scene(name):
    """Open one of blend_scenes/*.blend (saved by Blender 3.4)."""
    path = os.path.join(SCENES_DIR, name + '.blend')
    require(os.path.isfile(path), f"{path} is missing: run blend_scenes/build_scenes.py")
    bpy.ops.wm.open_mainfile(filepath=path)
    scene = bpy.context.scene
    scene.render.engine = 'EMBER'
    return scene


# ----------------------------------------------------------------------------
# rendering to NumPy

def load_exr(path):
    """An image file as (H, W, 4) float32, row 0 = top (loaded by Blender)."""
    import numpy as np
    image = bpy.data.images.load(path)
    try:
        width, height = image.size
        pixels = np.empty(width * height * 4, np.float32)
        image.pixels.foreach_get(pixels)
    finally:
        bpy.data.images.remove(image)
    return pixels.reshape(height, width, 4)[::-1].copy()


def render_array(scene, folder, name="render"):
    """Render the scene with its engine; returns the linear RGBA result."""
    scene.render.image_settings.file_format = 'OPEN_EXR'
    scene.render.image_settings.color_depth = '32'
    bpy.ops.render.render()
    path = os.path.join(str(folder), name + ".exr")
    bpy.data.images['Render Result'].save_render(path)
    return load_exr(path)


def setup_cycles(scene, samples, seed, max_bounces, filter_type='BLACKMAN_HARRIS', filter_width=1.5):
    """Cycles configured as Ember renders: CPU, unbiased, nothing clamped or
    filtered away, the same bounce limit and pixel filter."""
    scene.render.engine = 'CYCLES'
    cycles = scene.cycles
    cycles.device = 'CPU'
    cycles.samples = samples
    cycles.seed = seed
    cycles.use_animated_seed = False
    cycles.use_denoising = False
    cycles.use_adaptive_sampling = False
    cycles.sample_clamp_direct = 0.0
    cycles.sample_clamp_indirect = 0.0
    cycles.light_sampling_threshold = 0.0
    cycles.blur_glossy = 0.0
    cycles.caustics_reflective = True
    cycles.caustics_refractive = True
    cycles.max_bounces = max_bounces
    for name in ('diffuse_bounces', 'glossy_bounces', 'transmission_bounces',
                 'volume_bounces', 'transparent_max_bounces'):
        setattr(cycles, name, max_bounces)
    cycles.min_light_bounces = 0
    cycles.min_transparent_bounces = 0
    if hasattr(cycles, 'use_auto_tile'):
        cycles.use_auto_tile = False
    cycles.pixel_filter_type = filter_type
    cycles.filter_width = filter_width
    scene.render.threads_mode = 'AUTO'


def setup_ember(scene, samples, seed, max_bounces, filter_type='BLACKMAN_HARRIS', filter_width=1.5):
    scene.render.engine = 'EMBER'
    ember = scene.ember
    ember.samples = samples
    ember.use_adaptive_sampling = False   # as setup_cycles
    ember.seed = seed
    ember.max_bounces = max_bounces
    ember.transparent_max_bounces = max_bounces   # as setup_cycles
    ember.clamp = 0.0
    ember.time_limit = 0.0
    ember.filter_type = filter_type
    ember.filter_width = filter_width


def small_resolution(scene, width, height):
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100
    scene.render.use_border = False


# ----------------------------------------------------------------------------
# Ember's progressive passes

class PassTap:
    """Wraps the engine's progress object to keep every displayed pass."""

    def __init__(self, progress):
        self.progress = progress
        self.images = []

    def on_pass(self, image, samples_done, stats_):
        self.images.append((samples_done, np.array(image, dtype=np.float64)))
        self.progress.on_pass(image, samples_done, stats_)

    def should_stop(self):
        return self.progress.should_stop()


def per_pass_estimates(images):
    """Independent per-pass images from running means: n_k M_k - n_{k-1} M_{k-1}."""
    batches, previous_n, previous_sum = [], 0, 0.0
    for n, mean in images:
        total = mean * n
        batches.append((total - previous_sum) / (n - previous_n))
        previous_n, previous_sum = n, total
    return np.array(batches)


# ----------------------------------------------------------------------------
# Ember against Cycles

def render_ember_and_cycles(scene, tmp_path, name, taps, ember_spp, ember_seed, cycles_seeds, cycles_spp,
                            bounces):
    """Ember's final image and per-pass estimates (RGB), and Cycles' RGB
    images for seeds 0..cycles_seeds-1, with the same bounces and filter."""
    setup_ember(scene, ember_spp, seed=ember_seed, max_bounces=bounces)
    image = render_array(scene, tmp_path, "ember_" + name)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert log['error'] is None, log['error']
    assert np.isfinite(image).all()
    ember_batches = per_pass_estimates(taps[-1].images)[..., :3]
    cycles = []
    for seed in range(cycles_seeds):
        setup_cycles(scene, cycles_spp, seed, bounces)
        cycles.append(render_array(scene, tmp_path, f"cycles_{name}_{seed}")[..., :3])
    return image, ember_batches, np.array(cycles, dtype=np.float64)


def compare_with_cycles(name, ember_batches, cycles, block):
    """Ember's passes against Cycles' seeds (tests/ember_stats.py): Welch's t
    per block and channel, and the total of the whole image and of its four
    quadrants (a bias spread over many blocks hides in each of them).  Prints
    both results with their power.  Returns failures (blocks), details (with
    the failing mean tests) and both block-mean arrays."""
    import ember_stats as stats
    ember_blocks = stats.block_means(ember_batches, block)
    cycles_blocks = stats.block_means(cycles, block)
    failures, details = stats.failing_blocks(ember_blocks, cycles_blocks, name=f"{name} blocks")
    tests, level = stats.region_mean_tests(ember_batches, cycles, name=f"{name} region means")
    details['mean_failures'] = stats.report_mean_tests(f"{name}: Ember against Cycles", tests, level)
    details['relative_mean_error'] = tests[0].relative
    block_se = _typical_relative_block_se(ember_blocks, cycles_blocks)
    print(f"{name}: mean |block error| {details['relative_abs_error']:.4f}, max |t| {details['max_abs_t']:.2f} "
          f"over {details['blocks']} block-channels (reject below p={details['level']:.2e}); a bias in one "
          f"block is detected with probability 1/2 from "
          f"{stats.detectable(block_se, details['level'], min(len(ember_batches), len(cycles)) - 1):.1%} "
          f"(median block)")
    return failures, details, ember_blocks, cycles_blocks


def _typical_relative_block_se(a, b):
    """Median relative standard error of a block difference."""
    se = np.sqrt(a.var(axis=0, ddof=1) / len(a) + b.var(axis=0, ddof=1) / len(b))
    mean = np.abs(b.mean(axis=0))
    keep = mean > 0
    return float(np.median(se[keep] / mean[keep])) if keep.any() else 0.0


def assert_no_failing_blocks(failures, details):
    assert len(failures) == 0, (
        f"{len(failures)} blocks differ from Cycles (block, y, x, channel): {failures[:10].tolist()}; {details}")
    assert not details['mean_failures'], (
        f"the image or region means differ from Cycles: {details['mean_failures']}")
