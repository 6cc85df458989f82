"""Render passes under Cycles' names (issue 9): every pass Ember fills is
compared with Cycles' pass of the same name on one small scene (diffuse
floor, rough glossy box, rough glass ball, emissive card, area light, a
coloured world, mist), both rendered through Blender into multilayer EXRs
with independent seeds.

- Passes estimated by sampling: block Welch t-test per 4x4 block (Sidak)
  and a whole-image mean Welch t-test, over 8 Ember and 12 Cycles seeds
  (Welch's dof about 8-18; with the 4 + 4 seeds of before, dof near 3 put
  the thresholds at 15-60 standard errors); the power of both is printed.  Light passes are compared undivided
  (Direct x Color: the light itself; the divided ones blow up where a colour
  is near 0 at object edges), and their sum must give Combined.
- Passes Cycles writes from one sample at the pixel centre (Depth, Position,
  Object / Material Index): every pixel must agree (1e-3; measured: all).
- Closure colours (Diffuse / Glossy / Transmission Color): block and image
  mean tests, no allowance.  The box and the ball are single-scatter GGX:
  Cycles' Multiscatter GGX closure weight is 0.5% under its colour (its
  darkening; Ember's colours hold it too since issue 26), which a 1%
  hand-set floor used to hide.  Glossy Color
  on the rough glass ball was 0.7% under Cycles' (t -10.8) until the
  colours became Cycles' bsdf_albedo estimates (issue 26).
- Denoising Albedo / Normal: compared off the glass ball.  Behind rough glass
  (specular for the denoiser: roughness^2 < 0.075) Cycles writes smaller
  normals than Ember (its glass sample weights are not Ember's); that
  difference is known and left out here.
- Light groups (Combined_key: the area light, Combined_card: the emissive
  card) by the block test; that groups add up to Combined is tested in
  tests/engine/test_passes.py.
- Shader AOVs 'tint' (colour) and 'mask' (value), written by AOV Output
  nodes, by the block test.
- Cryptomatte: Blender's Cryptomatte node, reading Ember's manifest, selects
  the box; its matte is compared with Cycles' by block test.
"""
import os

import bpy
import numpy as np
import pytest

from ember_testlib import (SCENES_DIR, multilayer_output, node_material, read_multilayer_exr, require,
                           seed_block_test, setup_cycles, setup_ember, small_resolution)

# Ember 8 seeds x 12 samples (its cost is mostly per render), Cycles 12 x 24 (cheap).
SEEDS, SPP, CYCLES_SEEDS, CYCLES_SPP, BOUNCES = 8, 12, 12, 24, 3
WIDTH, HEIGHT = 32, 24
BOX, BALL = 2, 3   # object indices
# Combined_card was a strict xfail ("directly seen card emission 3% under
# Cycles"): a seed-set artefact, not a bias.  Against the exact value (the
# card's projected quad weighted by the pixel filter's periodic density)
# Ember's directly seen card is -0.08% +- 0.13% over 240 seeds and Cycles'
# +0.26% +- 0.14%; the card's light in the full scene -0.5% +- 0.5% (40 seeds).
# Seeds 0-3 happen to sit 2 sigma apart.  tests/addon/test_emission_area.py
# holds the exact claim (docs/testing.md, "Directly seen emission").
STATISTICAL = ("Combined", "Combined_key", "Combined_card", "tint", "mask", "Mist", "Normal", "UV", "Ambient Occlusion", "Emission", "Environment",
               "Diffuse Direct x Color", "Diffuse Indirect x Color", "Glossy Direct x Color",
               "Glossy Indirect x Color", "Transmission Direct x Color", "Transmission Indirect x Color")
CENTRE = ("Depth", "Position", "Object Index", "Material Index")
COLOURS = ("Diffuse Color", "Glossy Color", "Transmission Color")
LIGHT_GROUPS = ("key", "card")   # the area light's and the emissive card's (the world has none)
CLASSES = ("Diffuse", "Glossy", "Transmission")


def _material(name, kind, color, index, **inputs):
    mat = node_material(name, kind, dict({'Color': color + (1.0,)}, **inputs))
    mat.pass_index = index
    return mat


def _object(add, name, mat, index, **kwargs):
    add(**kwargs)
    obj = bpy.context.active_object
    obj.name = name
    obj.pass_index = index
    obj.data.materials.append(mat)
    return obj


def _scene():
    bpy.ops.wm.read_factory_settings()
    scene = bpy.context.scene
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    mesh = bpy.ops.mesh
    _object(mesh.primitive_plane_add, "Floor", _material("FloorMat", 'ShaderNodeBsdfDiffuse', (0.6, 0.5, 0.4), 1),
            1, size=8)
    _object(mesh.primitive_cube_add, "Box", _material("BoxMat", 'ShaderNodeBsdfGlossy', (0.8, 0.8, 0.8), 2,
                                                      Roughness=0.3, distribution='GGX'), BOX, location=(-1.2, 0.5, 1))
    _object(mesh.primitive_uv_sphere_add, "Ball", _material("BallMat", 'ShaderNodeBsdfGlass', (0.9, 0.9, 0.9), 3,
                                                             Roughness=0.2, distribution='GGX'), BALL, location=(1.3, -0.6, 1),
            radius=0.9)
    card = _object(mesh.primitive_plane_add, "Card", _material("CardMat", 'ShaderNodeEmission', (1.0, 0.8, 0.6),
                                                               4, Strength=4.0), 4, size=0.8,
                   location=(0, 2.5, 0.8), rotation=(1.2, 0, 0))
    bpy.ops.object.light_add(type='AREA', location=(1, -1, 5))
    light = bpy.context.active_object
    light.data.energy = 300.0
    light.data.size = 1.5
    for name in LIGHT_GROUPS:
        bpy.context.view_layer.lightgroups.add(name=name)
    light.lightgroup, card.lightgroup = LIGHT_GROUPS
    _shader_aovs(bpy.context.view_layer)
    world = scene.world
    world.use_nodes = True
    background = next(n for n in world.node_tree.nodes if n.type == 'BACKGROUND')
    background.inputs['Color'].default_value = (0.05, 0.06, 0.1, 1.0)
    world.mist_settings.start = 3.0
    world.mist_settings.depth = 12.0
    small_resolution(scene, WIDTH, HEIGHT)
    _enable_passes(bpy.context.view_layer)
    _cryptomatte_compositor(scene)
    multilayer_output(scene)
    return scene


def _shader_aovs(layer):
    """AOVs 'tint' (colour, written by the box) and 'mask' (value, written
    by the box and the floor)."""
    for name, kind in (("tint", 'COLOR'), ("mask", 'VALUE')):
        aov = layer.aovs.add()
        aov.name, aov.type = name, kind
    for mat, aovs in (("BoxMat", (("tint", (0.2, 0.4, 0.6), 0.0), ("mask", (0, 0, 0), 0.7))),
                      ("FloorMat", (("mask", (0, 0, 0), 0.3),))):
        tree = bpy.data.materials[mat].node_tree
        for name, colour, value in aovs:
            node = tree.nodes.new('ShaderNodeOutputAOV')
            node.aov_name = name
            node.inputs['Color'].default_value = colour + (1.0,)
            node.inputs['Value'].default_value = value


def _enable_passes(layer):
    skip = ('use_pass_grease_pencil', 'use_pass_shadow', 'use_pass_cryptomatte_accurate')
    for name in dir(layer):
        if name.startswith('use_pass') and name not in skip and 'subsurface' not in name:
            setattr(layer, name, True)
    layer.ember.use_pass_denoising_data = True
    layer.ember.use_pass_sample_count = True
    layer.cycles.denoising_store_passes = True
    layer.cycles.pass_debug_sample_count = True


def _cryptomatte_compositor(scene):
    """Composite = the Cryptomatte node's matte of the object 'Box'."""
    tree = bpy.data.node_groups.new("Passes Compositor", 'CompositorNodeTree')
    scene.compositing_node_group = tree
    layers = tree.nodes.new('CompositorNodeRLayers')
    crypto = tree.nodes.new('CompositorNodeCryptomatteV2')
    crypto.source = 'RENDER'
    crypto.scene = scene
    crypto.layer_name = f"{bpy.context.view_layer.name}.CryptoObject"
    crypto.matte_id = "Box"
    tree.interface.new_socket("Image", in_out='OUTPUT', socket_type='NodeSocketColor')
    out = tree.nodes.new('NodeGroupOutput')
    tree.links.new(layers.outputs['Image'], crypto.inputs['Image'])
    tree.links.new(crypto.outputs['Matte'], out.inputs[0])


def _with_products(images):
    for c in CLASSES:
        for part in ("Direct", "Indirect"):
            images[f"{c} {part} x Color"] = images[f"{c} {part}"] * images[f"{c} Color"]
    return images


@pytest.fixture(scope="module")
def renders(registered_addon, tmp_path_factory):
    require(bpy.app.version >= (5, 0, 0), "the parity scene's compositor set-up needs Blender 5.0")
    folder = tmp_path_factory.mktemp("passes")
    scene = _scene()
    out = {}
    for engine, setup in (('EMBER', setup_ember), ('CYCLES', setup_cycles)):
        out[engine] = []
        for seed in range(SEEDS if engine == 'EMBER' else CYCLES_SEEDS):
            setup(scene, SPP if engine == 'EMBER' else CYCLES_SPP, 100 + seed, BOUNCES)
            scene.render.filepath = os.path.join(str(folder), f"{engine}_{seed}.exr")
            bpy.ops.render.render(write_still=True)
            out[engine].append(_with_products(read_multilayer_exr(scene.render.filepath)))
    from addon import engine as ember_engine
    assert all(entry['error'] is None for entry in ember_engine.RENDER_LOG[-SEEDS:])
    return out


def _stack(renders, engine, name):
    return np.array([r[name] for r in renders[engine]])


def _interior(mask, steps=1):
    for _ in range(steps):
        mask = mask & np.roll(mask, 1, 0) & np.roll(mask, -1, 0) & np.roll(mask, 1, 1) & np.roll(mask, -1, 1)
    return mask


def _block_test(name, ember, cycles, keep=None, storage=1e-5):
    seed_block_test(f"passes parity blocks: {name}", f"passes parity image mean: {name}", name, ember, cycles,
                    keep, storage)


def test_every_pass_cycles_writes_exists(renders):
    missing = set(renders['CYCLES'][0]) - set(renders['EMBER'][0]) - {'Denoising Depth', 'Noisy Image'}
    assert not missing, f"passes Cycles has and Ember lacks: {sorted(missing)}"


@pytest.mark.parametrize("name", STATISTICAL)
def test_sampled_pass_matches_cycles(renders, name):
    ember, cycles = _stack(renders, 'EMBER', name)[..., :3], _stack(renders, 'CYCLES', name)[..., :3]
    _block_test(name, ember, cycles)


@pytest.mark.parametrize("name", CENTRE)
def test_centre_sample_pass_matches_cycles(renders, name):
    """One value per pixel from a ray through its centre, in both."""
    ember, cycles = _stack(renders, 'EMBER', name)[0], _stack(renders, 'CYCLES', name)[0]
    close = np.all(np.abs(ember - cycles) <= 1e-3 * (1.0 + np.abs(cycles)), axis=-1)
    print(f"\n{name}: {close.mean():.4f} of the pixels agree")
    assert close.all(), f"{name}: {int((~close).sum())} pixels differ, at {np.argwhere(~close)[:8].tolist()}"


@pytest.mark.parametrize("name", COLOURS)
def test_colour_pass_matches_cycles(renders, name):
    """Every pixel, the rough glass ball too: its Glossy Color was 0.7%
    under Cycles' (0.03724 against 0.03750 in the centre block, t -10.8)
    while Ember split glass by the exact Fresnel at the view angle; Cycles'
    bsdf_albedo takes the reflection from its ggx_gen_schlick_ior_s table
    (bsdf.closure_albedos; max block |t| 2.0 after)."""
    _block_test(name, _stack(renders, 'EMBER', name), _stack(renders, 'CYCLES', name))


@pytest.mark.parametrize("name", ("Denoising Albedo", "Denoising Normal"))
def test_denoising_pass_matches_cycles_off_glass(renders, name):
    index = renders['CYCLES'][0]['Object Index'][..., 0]
    off_glass = _interior(index != BALL, 2)
    _block_test(name, _stack(renders, 'EMBER', name), _stack(renders, 'CYCLES', name), keep=off_glass)


def test_light_passes_add_up_to_combined(renders):
    for images in renders['EMBER']:
        combined = images["Combined"][..., :3]
        total = sum(images[f"{c} {p} x Color"] for c in CLASSES for p in ("Direct", "Indirect"))
        total = total + images["Emission"] + images["Environment"]
        assert np.abs(total - combined).max() <= 1e-4 * (1.0 + combined.max())



def test_cryptomatte_node_selects_the_box_as_in_cycles(renders):
    """The node reads Ember's manifest: the box's matte is 1 inside it, 0
    away from it, and matches Cycles' block by block."""
    ember, cycles = _stack(renders, 'EMBER', 'Composite')[..., :1], _stack(renders, 'CYCLES', 'Composite')[..., :1]
    index = renders['CYCLES'][0]['Object Index'][..., 0]
    assert ember.mean(axis=0)[_interior(index == BOX, 2)].min() > 0.99
    assert ember.mean(axis=0)[_interior(index != BOX, 2)].max() < 0.01
    _block_test("Cryptomatte matte", ember, cycles)


def test_sample_count_and_vector(renders):
    for images in renders['EMBER']:
        assert np.all(images["Debug Sample Count"] == 1.0)  # every sample taken, as Cycles writes it
        assert np.all(images["Vector"] == 0.0)              # a still scene: nothing moves


def test_legacy_pass_names_in_blender_34_binary(tmp_path, legacy_addon, needs_engine):
    """Debian's Blender 3.4 (legacy zip, `blender -b -f 1`, multilayer EXR):
    the passes carry 3.4's names (IndexOB, DiffDir, Emit, Env, AO) and the
    file holds the Cryptomatte manifest."""
    import OpenImageIO as oiio
    from blender34 import BLENDER, require_blender_34
    from test_other_blenders import install_legacy, run
    require_blender_34()
    scripts = install_legacy(legacy_addon)
    settings = ("import bpy; s = bpy.context.scene; s.render.resolution_x = s.render.resolution_y = 16; "
                "s.render.resolution_percentage = 100; s.ember.samples = 4; s.ember.max_bounces = 2; "
                "s.render.image_settings.color_depth = '32'; l = bpy.context.view_layer; "
                "[setattr(l, n, True) for n in ('use_pass_object_index', 'use_pass_diffuse_direct', "
                "'use_pass_diffuse_color', 'use_pass_emit', 'use_pass_environment', 'use_pass_ambient_occlusion', "
                "'use_pass_cryptomatte_object')]; l.ember.use_pass_strategies = True")
    code, out = run([BLENDER, '-b', '--addons', 'ember', os.path.join(SCENES_DIR, 'cornell.blend'),
                     '-E', 'EMBER', '-o', str(tmp_path / 'frame_####'), '-F', 'OPEN_EXR_MULTILAYER',
                     '--python-expr', settings, '-f', '1'], env={'BLENDER_USER_SCRIPTS': scripts})
    path = str(tmp_path / 'frame_0001.exr')
    assert code == 0 and os.path.exists(path), out[-4000:]
    image = oiio.ImageInput.open(path)
    spec = image.spec()
    names = {c.split('.')[-2] for c in spec.channelnames}
    for name in ("IndexOB", "DiffDir", "DiffCol", "Emit", "Env", "AO", "CryptoObject00", "Strategy Light",
                 "MIS Weight Light"):
        assert name in names, (name, sorted(names))
    pixels = image.read_image('float')
    assert np.isfinite(pixels).all()
    keys = [a.name for a in spec.extra_attribs if a.name.startswith('cryptomatte/')]
    image.close()
    assert any(k.endswith('/manifest') for k in keys), keys
