"""Light bakes (issue 26): Diffuse, Glossy, Transmission, Combined, Shadow and
Environment bakes with Blender's pass filter, Ember against Cycles' own bake of the same object.

Scene: a 2 x 2 plane (the baked object, 32 x 32 float image, margin 0) with
a Mix of a checker-coloured Diffuse (0.7) and a GGX Glossy (roughness 0.3,
0.3), under a tilted red cube that shadows it and bounces light onto it,
lit by an area light and a constant grey world.  Cycles' references are the
mean of SEEDS bakes of CYCLES_SAMPLES samples each, with the variance of
that mean from the seeds' scatter, stored in tests/data/cycles_bake_<case>.npz
with the scene's fingerprint, samples, seeds and bounces (regenerate:
``.venv/bin/python -P tests/addon/test_light_bake_parity.py``; about a
minute).  Ember bakes once with EMBER_SAMPLES samples and its per-texel
variance (engine.bake.bake_light): Welch-style z-tests on 4 x 4 texel
blocks per channel and on the whole image's mean, one statistical family
per case (4: diffuse, glossy, transmission, combined), power printed and
asserted. The Transmission case bakes a variant of the scene: a Refraction
BSDF with the checker colour over a floor lit by a point light below the plane.
Shadow and Environment bakes and a Glass BSDF's Glossy / Transmission bakes
(GLASSY: the glass over a Diffuse floor under a world coloured by the
direction) are one family each; the Shadow bake has no per-texel variance
(a ratio), so Ember bakes it with ENGINE_SEEDS seeds and uses their scatter.
Diffuse Color alone is a colour pass (the closure colour at the texel
centre at 1 sample): compared per texel, no statistics.
"""
import os
import sys

import bpy
import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
for _path in (HERE, os.path.dirname(HERE)):
    if _path not in sys.path:
        sys.path.insert(0, _path)

from ember_testlib import empty_factory_scene, node_material, scene_fingerprint  # noqa: E402

SIZE = 32
BLOCK = 4
BOUNCES = 4
SEEDS = 8
CYCLES_SAMPLES = 1024
EMBER_SAMPLES = 256
DATA = os.path.join(os.path.dirname(HERE), 'data')

# case: (bake type, pass filter, held power: image mean, median block, relative)
CASES = {
    'diffuse': ('DIFFUSE', {'DIRECT', 'INDIRECT', 'COLOR'}, 0.005, 0.05),
    'glossy': ('GLOSSY', {'DIRECT', 'INDIRECT', 'COLOR'}, 0.01, 0.05),
    'combined': ('COMBINED', {'DIRECT', 'INDIRECT', 'EMIT', 'DIFFUSE', 'GLOSSY', 'TRANSMISSION'}, 0.01, 0.05),
    # Direct light alone, not multiplied by the colour (Diffuse Direct = light / Diffuse Color).
    'diffuse_direct': ('DIFFUSE', {'DIRECT'}, 0.01, 0.05),
    # Indirect light through the diffuse and glossy lobes and the plane's emission, no direct light.
    # (Without Emit Cycles zeroes the emission of every surface a path meets but keeps light
    # sampling's MIS-weighted share of emissive meshes: the result then depends on each
    # renderer's light pdf; combined_no_emit compares that with the same light selection.)
    'combined_indirect': ('COMBINED', {'INDIRECT', 'EMIT', 'DIFFUSE', 'GLOSSY'}, 0.005, 0.02),
    # The plane of TRANSMISSIVE: light through its Refraction BSDF (the world and the floor below).
    'transmission': ('TRANSMISSION', {'DIRECT', 'INDIRECT', 'COLOR'}, 0.01, 0.05),
    # Cycles' Shadow bake: the plane as a shadow catcher, its Shadow Catcher pass (the cube's shadow).
    'shadow': ('SHADOW', set(), 0.01, 0.05),
    # The world seen along each texel's position (GLASSY's world: its colour is the direction).
    'environment': ('ENVIRONMENT', set(), 0.01, 0.05),
    # A Glass BSDF in place of the Glossy: its reflection alone in a Glossy bake, its refraction alone
    # in a Transmission bake (Cycles splits one glass closure between the two passes).
    # (Dim, noisy light: 1024 samples hold 2.5 % on the image mean; the bug this holds was +500 %.)
    'glass_glossy': ('GLOSSY', {'DIRECT', 'INDIRECT', 'COLOR'}, 0.025, 0.2),
    'glass_transmission': ('TRANSMISSION', {'DIRECT', 'INDIRECT', 'COLOR'}, 0.015, 0.12),
    # Combined without Emit, lit by emissive meshes only (EMISSIVE_MESH): every emission a path hits
    # is zeroed, light sampling's MIS-weighted share of the panels stays (Cycles' light tree off,
    # Ember's Power selection: the same pdf).
    'combined_no_emit': ('COMBINED', {'DIRECT', 'INDIRECT', 'DIFFUSE', 'GLOSSY'}, 0.01, 0.05),
    # Its direct light alone: the panels' light samples at the texel, MIS-weighted against the
    # plane's Diffuse and Glossy lobes.
    'no_emit_direct': ('COMBINED', {'DIRECT', 'DIFFUSE', 'GLOSSY'}, 0.01, 0.05),
    # The same with Emit: every emission counts in full, whatever the pdfs (the scene's control).
    'combined_panels': ('COMBINED', {'DIRECT', 'INDIRECT', 'EMIT', 'DIFFUSE', 'GLOSSY'}, 0.01, 0.05),
    # The scene in a world volume (Principled Volume, density 0.08): bake paths start in it.
    'world_volume': ('COMBINED', {'DIRECT', 'INDIRECT', 'EMIT', 'DIFFUSE', 'GLOSSY'}, 0.01, 0.05),
    # The plane and the red cube inside an absorbing volume cube (density 0.5), the light outside:
    # Cycles' bake paths start without it (init_from_bake.h queues no volume stack walk, unlike
    # init_from_camera.h), so light and paths leaving it are not attenuated.
    'inside_volume': ('COMBINED', {'DIRECT', 'INDIRECT', 'EMIT', 'DIFFUSE', 'GLOSSY'}, 0.01, 0.05),
}
# Cases baked on the scene variant with a Refraction BSDF in place of the Glossy.
TRANSMISSIVE = ('transmission',)
# Cases baked on the variant with a Glass BSDF there, over the lit floor, under a world whose colour
# varies with the direction.
GLASSY = ('environment', 'glass_glossy', 'glass_transmission')
# Cases baked on the variant lit by two emissive panels of one material (no lamp, a black world, the
# plane's own emission off), with Cycles' light tree off and Ember's Power light selection.
EMISSIVE_MESH = ('combined_no_emit', 'no_emit_direct', 'combined_panels')
# Cases baked with a world volume / inside a volume-only cube (VOLUMETRIC: how).
VOLUMETRIC = {'world_volume': 'world', 'inside_volume': 'cube'}
# Cycles' samples per seed where CYCLES_SAMPLES leaves too little power (the median block).
REFERENCE_SAMPLES = {'transmission': 4096}
# Ember's samples where EMBER_SAMPLES leaves too little power (dim, noisy indirect light).
# glossy 256 -> 512, glass_glossy 1024 -> 3072, world_volume 256 -> 384: with the variance of the texels'
# channel sums (bounded) they resolved 1.31 %, 3.45 % and 1.04 % of the image (asked 1 %, 2.5 %, 1 %).
SAMPLES = {'combined_indirect': 1024, 'combined_no_emit': 1024, 'combined_panels': 1024, 'no_emit_direct': 1024,
           'glass_glossy': 3072, 'glass_transmission': 1024, 'transmission': 8192, 'glossy': 512, 'world_volume': 384}
# One statistical family each for Diffuse and Glossy; the Combined bake and
# the filtered bakes share one (test_filtered_bakes_match_cycles).
FILTERED = ('combined', 'diffuse_direct', 'combined_indirect')


def bake_scene(case=None):
    """The scene, the baked plane and its bake image (for the TRANSMISSIVE
    cases: a Refraction BSDF with the checker's colour in place of the
    Glossy, over a lit floor that it sees through)."""
    transmissive = case in TRANSMISSIVE
    glassy = case in GLASSY
    panels = case in EMISSIVE_MESH
    scene = empty_factory_scene()
    bpy.ops.mesh.primitive_plane_add(size=2.0)
    plane = bpy.context.active_object
    image = bpy.data.images.new("bake_target", SIZE, SIZE, float_buffer=True, alpha=True)
    mat = bpy.data.materials.new("plane_mat")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    for node in list(nodes):
        if node.type != 'OUTPUT_MATERIAL':
            nodes.remove(node)
    out = next(n for n in nodes if n.type == 'OUTPUT_MATERIAL')
    coords = nodes.new('ShaderNodeTexCoord')
    checker = nodes.new('ShaderNodeTexChecker')
    checker.inputs['Scale'].default_value = 4.0
    checker.inputs['Color1'].default_value = (0.8, 0.7, 0.2, 1.0)
    checker.inputs['Color2'].default_value = (0.2, 0.5, 0.8, 1.0)
    links.new(coords.outputs['UV'], checker.inputs['Vector'])
    diffuse = nodes.new('ShaderNodeBsdfDiffuse')
    links.new(checker.outputs['Color'], diffuse.inputs['Color'])
    if glassy:
        glossy = nodes.new('ShaderNodeBsdfGlass')
        glossy.distribution = 'GGX'
        glossy.inputs['IOR'].default_value = 1.45
        glossy.inputs['Color'].default_value = (0.9, 0.85, 0.7, 1.0)
    elif transmissive:
        glossy = nodes.new('ShaderNodeBsdfRefraction')
        glossy.distribution = 'GGX'
        glossy.inputs['IOR'].default_value = 1.45
        links.new(checker.outputs['Color'], glossy.inputs['Color'])
    else:
        glossy = nodes.new('ShaderNodeBsdfGlossy')
        glossy.distribution = 'GGX'
        glossy.inputs['Color'].default_value = (0.9, 0.9, 0.9, 1.0)
    glossy.inputs['Roughness'].default_value = 0.3
    mix = nodes.new('ShaderNodeMixShader')
    mix.inputs['Fac'].default_value = 0.6 if transmissive else 0.3
    links.new(diffuse.outputs[0], mix.inputs[1])
    links.new(glossy.outputs[0], mix.inputs[2])
    emission = nodes.new('ShaderNodeEmission')   # what Combined's Emit toggle keeps or drops
    emission.inputs['Color'].default_value = (0.2, 0.9, 0.4, 1.0)
    emission.inputs['Strength'].default_value = 0.0 if panels else 0.3
    add = nodes.new('ShaderNodeAddShader')
    links.new(mix.outputs[0], add.inputs[0])
    links.new(emission.outputs[0], add.inputs[1])
    links.new(add.outputs[0], out.inputs['Surface'])
    target = nodes.new('ShaderNodeTexImage')
    target.image = image
    nodes.active = target
    plane.data.materials.append(mat)

    bpy.ops.mesh.primitive_cube_add(size=0.7, location=(0.25, -0.1, 0.6), rotation=(0.3, 0.2, 0.5))
    cube = bpy.context.active_object
    red = bpy.data.materials.new("red")
    red.use_nodes = True
    bsdf = red.node_tree.nodes.get('Principled BSDF')
    bsdf.inputs['Base Color'].default_value = (0.8, 0.1, 0.05, 1.0)
    bsdf.inputs['Roughness'].default_value = 1.0
    cube.data.materials.append(red)

    if transmissive or glassy:   # a floor below, lit by a point light beside the plane
        bpy.ops.mesh.primitive_plane_add(size=6.0, location=(0.0, 0.0, -0.8))
        bpy.context.active_object.data.materials.append(diffuse_floor() if glassy else red)
        bpy.ops.object.light_add(type='POINT', location=(1.8, -1.5, -0.2))
        bpy.context.active_object.data.energy = 150.0
    if panels:
        emissive_panels()
    else:
        bpy.ops.object.light_add(type='AREA', location=(-0.8, 0.6, 2.2), rotation=(0.3, -0.3, 0.0))
        light = bpy.context.active_object
        light.data.energy = 60.0
        light.data.size = 0.6

    if scene.world is None:
        scene.world = bpy.data.worlds.new("World")
    scene.world.use_nodes = True
    scene.world.node_tree.nodes['Background'].inputs['Color'].default_value = (0.25, 0.25, 0.3, 1.0)
    scene.world.node_tree.nodes['Background'].inputs['Strength'].default_value = 1.0
    if glassy:
        world_by_direction(scene.world.node_tree)
    if panels:   # the panels are the only emitter; both renderers pick their triangles by area (power)
        scene.world.node_tree.nodes['Background'].inputs['Strength'].default_value = 0.0
        scene.cycles.use_light_tree = False
        scene.ember.light_selection = 'POWER'
    if case in VOLUMETRIC:
        add_volume(scene, VOLUMETRIC[case])
    scene.render.bake.margin = 0
    for obj in scene.objects:
        obj.select_set(False)
    plane.select_set(True)
    bpy.context.view_layer.objects.active = plane
    return scene, plane, image


def emissive_panels():
    """EMISSIVE_MESH's emitters: two quads of one Emission material (a warm
    white, strength 6), a large one tilted over the plane's left and a
    small one low at its right."""
    panel = node_material("panel", 'ShaderNodeEmission', {'Color': (1.0, 0.85, 0.6, 1.0), 'Strength': 6.0})
    for size, location, rotation in ((0.8, (-0.7, 0.5, 1.3), (0.5, -0.4, 0.0)),
                                     (0.35, (1.1, -0.6, 0.45), (0.2, 1.1, 0.3))):
        bpy.ops.mesh.primitive_plane_add(size=size, location=location, rotation=rotation)
        bpy.context.active_object.data.materials.append(panel)


def add_volume(scene, where):
    """VOLUMETRIC's medium: 'world' a Principled Volume (density 0.08) in
    the world's Volume output; 'cube' a volume-only Volume Absorption cube
    (density 0.5) holding the plane and the red cube, the light above it.
    Unbiased null scattering in Cycles, single scattering in both."""
    if where == 'world':
        tree = scene.world.node_tree
        fog = tree.nodes.new('ShaderNodeVolumePrincipled')
        fog.inputs['Color'].default_value = (0.8, 0.85, 0.9, 1.0)
        fog.inputs['Density'].default_value = 0.08
        output = next(n for n in tree.nodes if n.type == 'OUTPUT_WORLD')
        tree.links.new(fog.outputs[0], output.inputs['Volume'])
    else:
        smoke = bpy.data.materials.new("smoke")
        smoke.use_nodes = True
        tree = smoke.node_tree
        tree.nodes.clear()
        out = tree.nodes.new('ShaderNodeOutputMaterial')
        absorb = tree.nodes.new('ShaderNodeVolumeAbsorption')
        absorb.inputs['Color'].default_value = (0.9, 0.5, 0.3, 1.0)
        absorb.inputs['Density'].default_value = 0.5
        tree.links.new(absorb.outputs[0], out.inputs['Volume'])
        bpy.ops.mesh.primitive_cube_add(size=2.8, location=(0.0, 0.0, 0.4))   # z -1 .. 1.8: clear of the light
        bpy.context.active_object.data.materials.append(smoke)
    scene.ember.volume_bounces = 0
    if hasattr(scene.cycles, 'volume_biased'):
        scene.cycles.volume_biased = False


def diffuse_floor():
    """GLASSY's floor: a Diffuse BSDF."""
    return node_material("floor", 'ShaderNodeBsdfDiffuse', {'Color': (0.8, 0.3, 0.2, 1.0)})


def world_by_direction(tree):
    """The world's colour |direction| x 0.5 + 0.05 per channel (its Generated coordinates are the direction)."""
    coords = tree.nodes.new('ShaderNodeTexCoord')
    absolute = tree.nodes.new('ShaderNodeVectorMath')
    absolute.operation = 'ABSOLUTE'
    scale = tree.nodes.new('ShaderNodeVectorMath')
    scale.operation = 'MULTIPLY_ADD'
    scale.inputs[1].default_value = (0.5, 0.5, 0.5)
    scale.inputs[2].default_value = (0.05, 0.05, 0.05)
    tree.links.new(coords.outputs['Generated'], absolute.inputs[0])
    tree.links.new(absolute.outputs[0], scale.inputs[0])
    tree.links.new(scale.outputs[0], tree.nodes['Background'].inputs['Color'])


def run_bake(scene, image, engine, kind, pass_filter, samples, seed=0):
    """One bake of the plane; (SIZE, SIZE, 4) float32, row 0 at the bottom."""
    from ember_testlib import setup_cycles, setup_ember
    if engine == 'CYCLES':
        setup_cycles(scene, samples, seed, BOUNCES)
    else:
        setup_ember(scene, samples, seed, BOUNCES)
    image.pixels.foreach_set(np.zeros(SIZE * SIZE * 4, np.float32))
    bpy.ops.object.bake(type=kind, pass_filter=set(pass_filter), margin=0)
    out = np.empty(SIZE * SIZE * 4, np.float32)
    image.pixels.foreach_get(out)
    return out.reshape(SIZE, SIZE, 4)


def reference_path(case):
    return os.path.join(DATA, f"cycles_bake_{case}.npz")


def make_reference(case):
    kind, pass_filter = CASES[case][:2]
    scene, plane, image = bake_scene(case)
    samples = REFERENCE_SAMPLES.get(case, CYCLES_SAMPLES)
    bakes = np.stack([run_bake(scene, image, 'CYCLES', kind, pass_filter, samples, seed)[..., :3]
                      for seed in range(1, SEEDS + 1)])
    scene, plane, image = bake_scene(case)
    np.savez_compressed(reference_path(case), mean=bakes.mean(axis=0), var=bakes.var(axis=0, ddof=1) / SEEDS,
                        fingerprint=scene_fingerprint(scene), samples=samples, seeds=SEEDS, bounces=BOUNCES,
                        blender=bpy.app.version_string)


def load_reference(case, scene):
    path = reference_path(case)
    assert os.path.isfile(path), f"{path} is missing: run python -P {__file__}"
    ref = np.load(path)
    assert str(ref['fingerprint']) == scene_fingerprint(scene), \
        f"{path} was baked from another scene: run python -P {__file__}"
    assert int(ref['samples']) == REFERENCE_SAMPLES.get(case, CYCLES_SAMPLES) and int(ref['seeds']) == SEEDS and int(ref['bounces']) == BOUNCES
    return ref['mean'], ref['var']


# The engine functions behind the add-on's light, Shadow and Environment bakes.
BAKE_FUNCTIONS = ('bake_light', 'bake_shadow', 'bake_background')
# Cases whose value has no per-texel variance (Shadow: a ratio of estimates): Ember bakes them
# with this many seeds, their scatter giving the variance of the mean.
ENGINE_SEEDS = {'shadow': 4}
# Relative rounding added to the blocks' standard error where a bake has noise-free blocks (the
# environment's blue is 0.05 everywhere: Cycles' float arithmetic gives 0.0499995).
ROUNDING = {'shadow': 1e-5, 'environment': 1e-4}


def ember_bake(scene, image, kind, pass_filter, samples=EMBER_SAMPLES, seed=0):
    """Ember's bake through bpy.ops.object.bake (what a user gets) and the
    same bake's per-texel variance from the engine (same seed and
    samples: the same numbers; None for a Shadow bake)."""
    from addon import backend
    engine = backend.engine()
    captured = {}
    originals = {name: getattr(engine.bake, name) for name in BAKE_FUNCTIONS}

    def spy(real):
        def keep(*args, **kwargs):
            captured['baked'] = result = real(*args, **kwargs)
            return result
        return keep
    for name, real in originals.items():
        setattr(engine.bake, name, spy(real))
    try:
        pixels = run_bake(scene, image, 'EMBER', kind, pass_filter, samples, seed)
    finally:
        for name, real in originals.items():
            setattr(engine.bake, name, real)
    baked = captured['baked']
    assert np.allclose(baked.rgba.reshape(SIZE, SIZE, 4)[..., :3], pixels[..., :3], atol=1e-6), \
        "the image is not the bake the engine returned"
    var = None if baked.variance is None else baked.variance.reshape(SIZE, SIZE, 3)
    return pixels[..., :3], var, baked.result


def ember_estimate(case, scene, image, kind, pass_filter, samples):
    """(mean, variance of the mean, samples per bake, seconds) of Ember's bake of ``case``."""
    seeds = ENGINE_SEEDS.get(case)
    if seeds is None:
        ember, var, result = ember_bake(scene, image, kind, pass_filter, samples)
        assert var is not None
        if result is not None:
            assert result.samples == samples
        return ember, var, (result.stats.get('seconds', 0) if result is not None else 0.0)
    bakes, seconds = [], 0.0
    for seed in range(1, seeds + 1):
        ember, _var, result = ember_bake(scene, image, kind, pass_filter, samples, seed)
        assert result.samples == samples
        bakes.append(ember)
        seconds += result.stats.get('seconds', 0)
    bakes = np.stack(bakes)
    return bakes.mean(axis=0), bakes.var(axis=0, ddof=1) / seeds, seconds


def _blocks(img):
    return img.reshape(SIZE // BLOCK, BLOCK, SIZE // BLOCK, BLOCK, -1).mean(axis=(1, 3))


def compare(case, level):
    """Ember's bake of ``case`` against its reference: (z of the blocks,
    z of the image mean, image and median block power, relative)."""
    from ember_stats import detectable, sum_variance
    kind, pass_filter = CASES[case][:2]
    scene, plane, image = bake_scene(case)
    ref, ref_var = load_reference(case, scene)
    samples = SAMPLES.get(case, EMBER_SAMPLES)
    ember, var, seconds = ember_estimate(case, scene, image, kind, pass_filter, samples)
    a, b = _blocks(ember), _blocks(ref)
    va, vb = _blocks(var) / BLOCK ** 2, _blocks(ref_var) / BLOCK ** 2
    if case in ROUNDING:   # blocks without noise (the Shadow Catcher pass is 1 in the open) differ by rounding
        vb = vb + (ROUNDING[case] * b) ** 2
    z = (a - b) / np.sqrt(va + vb)
    mean_a, mean_b = ember.mean(), ref.mean()
    # A mean over channels: the variance of each texel's R + G + B, bounded
    # (ember_stats.sum_variance; neither the bake nor the stored references
    # keep the sum's own variance), not the channel variances summed.
    se_mean = float(np.sqrt(sum_variance(ember, var).sum() + sum_variance(ref, ref_var).sum()) / ember.size)
    z_mean = (mean_a - mean_b) / se_mean
    image_power = detectable(se_mean, level) / mean_b
    block_power = float(np.median(detectable(np.sqrt(va + vb), level) / np.maximum(b, 1e-12)))
    worst = np.unravel_index(np.argmax(np.abs(z)), z.shape)
    print(f"{case}: Cycles mean {mean_b:.4f}, Ember {mean_a:.4f} ({(mean_a / mean_b - 1) * 100:+.2f} % "
          f"+- {se_mean / mean_b * 100:.2f} %, z {z_mean:+.2f}); {a.size} block-channels, max |z| "
          f"{np.abs(z).max():.2f} at {worst}; detects {image_power * 100:.2f} % (image), "
          f"{block_power * 100:.1f} % (median block); {seconds:.1f} s")
    assert b.min() > 0 and np.ptp(b) > 0.05 * b.max(), "the bake did not vary: the test would see little"
    return z, z_mean, image_power, block_power


def _assert_agrees(case, result, threshold):
    z, z_mean, image_power, block_power = result
    image_target, block_target = CASES[case][2:]
    print(f"{case}: threshold {threshold:.2f}; held {image_target * 100:.1f} % (image), {block_target * 100:.0f} % (block)")
    assert image_power <= image_target and block_power <= block_target, f"{case}: too little power"
    assert abs(z_mean) < threshold, f"{case}: the image mean differs"
    assert np.abs(z).max() < threshold, f"{case}: {int((np.abs(z) >= threshold).sum())} blocks differ"


BLOCK_TESTS = 3 * (SIZE // BLOCK) ** 2 + 1   # block-channels and the image mean of one bake


# Found by this test: the Transmission bake of the Refraction BSDF was 10 %
# low in blue where a point light sits below the plane at a grazing angle
# (block |z| 27), and the Glass BSDF's 1.6 % +- 0.2 % low (z -8): all in the
# Direct part (Cycles 0.0009, Ember 0).  Cause: Ember's rough refraction
# returned 0 for directions no microfacet refracts into (pbrt's check);
# Cycles evaluates them (bsdf_microfacet_eval: "TODO: check if the
# refraction configuration is valid"), in renders as in bakes
# (tests/addon/test_rough_refraction_parity.py), and so does Ember now.


@pytest.mark.parametrize("case", ['diffuse', 'glossy', 'transmission'])
def test_light_bake_matches_cycles(case):
    from ember_stats import family_level, z_threshold
    level = family_level(f"light bake {case}", BLOCK_TESTS)
    _assert_agrees(case, compare(case, level), z_threshold(level))


@pytest.mark.parametrize("case", ['shadow', 'environment'])
def test_shadow_and_environment_bakes_match_cycles(case):
    """Shadow: the plane as Cycles bakes it, a shadow catcher for the bake,
    its Shadow Catcher pass (the cube's shadow, 1 in the open); Environment:
    the world (its colour the direction) along each texel's position."""
    from ember_stats import family_level, z_threshold
    level = family_level(f"light bake {case}", BLOCK_TESTS)
    _assert_agrees(case, compare(case, level), z_threshold(level))


@pytest.mark.parametrize("case", ['glass_glossy', 'glass_transmission'])
def test_glass_bakes_split_like_cycles(case):
    """A Glass BSDF in a Glossy bake brings only its reflected light and in
    a Transmission bake only its refracted light (Cycles counts one glass
    closure's light by the side it leaves to: film/light_passes.h)."""
    from ember_stats import family_level, z_threshold
    level = family_level(f"light bake {case}", BLOCK_TESTS)
    _assert_agrees(case, compare(case, level), z_threshold(level))


def test_filtered_bakes_match_cycles():
    """Combined with every contribution, Diffuse Direct without Color (the
    light divided by the colour) and Combined's Indirect light and Emit
    through the Diffuse and Glossy lobes: one family."""
    from ember_stats import family_level, z_threshold
    level = family_level("light bake filters", BLOCK_TESTS * len(FILTERED))
    results = {case: compare(case, level) for case in FILTERED}
    for case in FILTERED:
        _assert_agrees(case, results[case], z_threshold(level))


# Found by this test, two causes: without Emit Ember was +2.8 % +- 0.16 % on the image (z 17) and
# +20 % in the blocks under the large panel.  (1) Cycles picks solid-angle or area sampling of an
# emissive triangle by longest edge^2 > (dot(N0, V0 - P) / dot(N0, N0))^2, N0 the unnormalized
# normal (light/triangle.h): its "distance to the plane" is the distance over twice the area; Ember
# compared the plain distance, so it solid-angle sampled from points where Cycles area samples.
# (2) Left +0.7 % +- 0.08 % (z 8.5; +4 % and -2 % on the checker's two colours): Ember chose
# lobes by the luminance of their weight, Cycles by its mean (bsdf_alloc: sample_weight =
# fabsf(average(weight))); the direct light of one class alone agreed.  Both are unbiased in a
# render, but the light and BSDF pdfs set the MIS weight that is all a bake without Emit keeps.


def test_combined_without_emit_matches_cycles():
    """Combined without Emit over a plane lit only by two emissive panels of
    one material (EMISSIVE_MESH): Cycles zeroes every emission a path hits
    and keeps the MIS-weighted light samples of the panels; with Cycles'
    light tree off (triangles picked by area) and Ember's Power selection
    (the one material's triangles by area) both weigh them alike.  Direct
    and indirect light, the direct light alone, and with Emit (the control:
    every emission counts, whatever the pdfs): one family."""
    from ember_stats import family_level, z_threshold
    cases = ('combined_no_emit', 'no_emit_direct', 'combined_panels')
    level = family_level("light bake without emit", BLOCK_TESTS * len(cases))
    results = {case: compare(case, level) for case in cases}
    for case in cases:
        _assert_agrees(case, results[case], z_threshold(level))


# Found by this test: in a world volume Ember's bake was -6.1 % +- 0.12 % (z -52): it flew the
# bake's stand-in first ray (from P + N to the texel, length 1) through the world medium.  Cycles'
# init_from_bake.h goes straight to shading the texel; the volume starts with the next segment.


def test_bakes_in_volumes_match_cycles():
    """A bake in a world volume (paths and shadow rays from the texel start
    in it) and a bake of a plane inside an absorbing volume-only cube with
    the light outside (Cycles' bake paths start with the world volume only:
    init_from_bake.h never walks the volume stack as init_from_camera.h
    does, so neither the light nor the paths leaving the cube are
    attenuated by it; started inside it, the direct light's 1.8 through it
    would lose some 9 % of its red and 47 % of its blue): one family."""
    from ember_stats import family_level, z_threshold
    cases = tuple(VOLUMETRIC)
    level = family_level("light bake in volumes", BLOCK_TESTS * len(cases))
    results = {case: compare(case, level) for case in cases}
    for case in cases:
        _assert_agrees(case, results[case], z_threshold(level))


def test_diffuse_color_bake_matches_cycles():
    """Diffuse Color alone: the closure colour (checker x mix weight 0.7)
    at each texel centre (1 sample), Ember against Cycles per texel,
    within float tolerance except at the checker's edges."""
    scene, plane, image = bake_scene()
    cycles = run_bake(scene, image, 'CYCLES', 'DIFFUSE', {'COLOR'}, 1)
    ember = run_bake(scene, image, 'EMBER', 'DIFFUSE', {'COLOR'}, 1)
    diff = np.abs(ember[..., :3] - cycles[..., :3]).max(axis=2)
    close = diff < 2e-4
    print(f"diffuse colour: {int((~close).sum())} of {SIZE * SIZE} texels differ by > 2e-4, max {diff.max():.2e}; "
          f"Cycles' range {np.ptp(cycles[..., :3], axis=(0, 1))}")
    assert np.ptp(cycles[..., :3]) > 0.1
    assert np.allclose(np.unique(np.round(cycles[..., 0], 3)), [0.14, 0.56], atol=2e-3), "not checker x 0.7"
    assert close.mean() > 0.99


def test_light_bake_hostile():
    """Hostile input: an object without a UV map (Blender's clear refusal,
    before Ember), 0 samples asked of the engine (a clear error), a bake
    of an empty texel list (nothing traced), no crash or NaN anywhere."""
    from addon import backend
    engine = backend.engine()
    scene, plane, image = bake_scene()
    scene.render.engine = 'EMBER'
    plane.data.uv_layers.remove(plane.data.uv_layers[0])
    with pytest.raises(RuntimeError) as err:
        bpy.ops.object.bake(type='DIFFUSE', pass_filter={'DIRECT', 'INDIRECT', 'COLOR'}, margin=0)
    print("no UV ->", str(err.value).strip())
    assert "UV" in str(err.value)
    scene.ember.samples = 0                   # clamped by the property to 1
    assert scene.ember.samples == 1
    tiny = engine.Scene()
    with pytest.raises(ValueError) as err:
        engine.bake.bake_light(tiny, 0, np.zeros(0, np.int64), np.zeros(0), np.zeros(0), 'DIFFUSE', {'DIRECT'},
                               engine.RenderSettings(samples=0))
    print("0 samples ->", err.value)
    assert "samples" in str(err.value)
    with pytest.raises(ValueError) as err:
        engine.bake.light_filter('DIFFUSE', {'DIRECT', 'SHADOW'})
    assert "SHADOW" in str(err.value)


def test_shadow_environment_glass_bakes_hostile():
    """Hostile input for the Shadow and Environment bakes and the glass
    split: Blender refuses an object without a UV map; the engine bakes a
    mesh with a zero-area triangle, texels off the mesh and NaN
    barycentrics to finite pixels (alpha 0 on the degenerate triangle and
    off the mesh), a texel at the world origin included."""
    from addon import backend
    engine = backend.engine()
    scene, plane, image = bake_scene()
    scene.render.engine = 'EMBER'
    plane.data.uv_layers.remove(plane.data.uv_layers[0])
    for kind in ('SHADOW', 'ENVIRONMENT'):
        with pytest.raises(RuntimeError) as err:
            bpy.ops.object.bake(type=kind, margin=0)
        print(kind, "without UV ->", str(err.value).strip())
        assert "UV" in str(err.value)
    positions = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [2, 2, 0], [2, 2, 0], [3, 3, 0]], np.float64)
    corners = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]])
    mesh = engine.Mesh(positions, np.array([[0, 1, 2], [3, 4, 5]]), uvs=np.stack([corners, corners]))
    glass = engine.Material("glass", (engine.Lobe("glass", (0.9, 0.9, 0.9), 0.3, ior=1.45),))
    world = engine.World((0.2, 0.3, 0.4))
    below = np.eye(4)
    below[2, 3] = -1.0
    tiny = engine.Scene(meshes=[mesh], world=world, materials=[glass],   # the baked object second
                        instances=[engine.Instance(mesh=0, matrix=below, materials=[0], name="other"),
                                   engine.Instance(mesh=0, materials=[0], name="baked")])
    prim = np.array([0, 0, 1, -1, 7, 0])
    u = np.array([0.3, 0.5, 0.2, 0.5, 0.5, np.nan])   # texel 1 is at the world origin
    v = np.array([0.3, 0.0, 0.2, 0.5, 0.5, 0.2])
    settings = engine.RenderSettings(samples=3, max_bounces=2)
    bakes = {
        'shadow': engine.bake.bake_shadow(tiny, 1, prim, u, v, settings),
        'environment': engine.bake.bake_background(tiny, 1, prim, u, v, settings),
        'glossy': engine.bake.bake_light(tiny, 1, prim, u, v, 'GLOSSY', {'DIRECT', 'INDIRECT', 'COLOR'}, settings),
        'transmission': engine.bake.bake_light(tiny, 1, prim, u, v, 'TRANSMISSION', {'DIRECT', 'INDIRECT'},
                                               settings),
    }
    for name, baked in bakes.items():
        print(name, baked.rgba.tolist())
        assert np.isfinite(baked.rgba).all(), name
        assert baked.rgba[:2, 3].tolist() == [1.0, 1.0] and baked.rgba[2:5, 3].tolist() == [0.0, 0.0, 0.0], name
    assert np.allclose(bakes['environment'].rgba[:2, :3], (0.2, 0.3, 0.4))
    empty = engine.bake.bake_background(tiny, 1, np.zeros(0, np.int64), np.zeros(0), np.zeros(0), settings)
    assert empty.rgba.shape == (0, 4)


def test_light_bake_progress_and_cancel(monkeypatch):
    """A bake of 10^6 samples reports its progress and stops at Esc (the
    render's break flag, asked between batches) long before its last sample,
    leaving finite pixels; no error is reported.  How soon is printed, not
    asserted (issue 27: a wall-clock bound fails on a busy machine and proves
    nothing on a fast one; the stop poll's timing is tested with an injected
    clock in tests/engine/test_render_api.py)."""
    import time
    from addon import bake as addon_bake
    from addon import output
    seen = []
    original = addon_bake._BakeProgress.on_pass

    def on_pass(self, image, samples_done, stats):
        seen.append(samples_done)
        original(self, image, samples_done, stats)
    monkeypatch.setattr(addon_bake._BakeProgress, 'on_pass', on_pass)
    monkeypatch.setattr(output, 'break_requested', lambda engine: len(seen) >= 2)
    scene, plane, image = bake_scene()
    start = time.perf_counter()
    pixels = run_bake(scene, image, 'EMBER', 'DIFFUSE', {'DIRECT', 'INDIRECT', 'COLOR'}, 1_000_000)
    seconds = time.perf_counter() - start
    print(f"cancelled after passes {seen} in {seconds:.1f} s")
    assert len(seen) >= 2 and seen[-1] < 1_000_000
    assert np.isfinite(pixels).all()


if __name__ == "__main__":
    import addon
    addon.register()
    for name in (sys.argv[1:] or CASES):
        make_reference(name)
        print("wrote", reference_path(name))
