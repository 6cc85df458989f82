"""Homogeneous volumes against Cycles (issue 21): small scenes built here
with bpy, rendered by Ember and compared with converged Cycles references
(tests/data/cycles_volume_<scene>.exr, rendered by tools/cycles_references.py)
by the totals of the image and its quadrants and block by block, at the
suite's family level (ember_testlib.check_against_reference); results and
power are printed.

Cycles' volume settings are set in each scene (the references tool and
setup_cycles read ``scene.ember.volume_bounces`` for Cycles' Volume bounces):
null scattering (not the biased ray marching), Volume bounces 0 as Cycles'
default unless a scene says otherwise.

Every volume mesh stands clear of the floor: a face coincident with another
surface makes which one a ray meets undefined (and the two engines differ).

Scenes:
* coloured_glass: a Glass BSDF cube with Volume Absorption inside (and a
  volume-only absorbing sphere beside it) on a diffuse floor under an area
  light: paths refract into the medium and are attenuated; shadow rays cross
  the volume-only boundary and are attenuated by it;
* fog: a Principled Volume fog cube (volume output only) on a floor, lit by a
  spot light from above: single scattering (volume_bounces 0), NEE with the
  phase function, shadow rays through the fog;
* emission: an Emission shader in a sphere's Volume output (emission only)
  beside a Principled Volume cube with absorption colour and emission,
  seen against a dark world over a dark floor.
"""
import bpy
import pytest

from ember_testlib import built_reference_scene, check_against_reference, render_for_reference

EMBER_SPP = 256
# The fog's single scattering is noisy per sample (a spot beam in a dark
# room): more samples, and still short of the targets (WEAK).  The glass's
# caustics (floor lit through the cube, found by BSDF sampling only) are
# heavy-tailed: at 256 spp their sample variance understates the error.
SPP = {'fog': 2048, 'coloured_glass': 1792}
BLOCK = 12
WIDTH, HEIGHT = 48, 36
IMAGE_POWER, BLOCK_POWER = 0.005, 0.02   # issue 12's targets (docs/testing.md)
# Scenes whose power falls short of the targets at this budget (asserted at
# the stated level instead).
WEAK = {'fog': (0.007, 0.06)}   # measured: 0.60% and 5.0% at 2048 spp
DARK_WORLD = (0.0, 0.0, 0.0)


def _material(name, surface=None, volume=None):
    """A material whose Surface and/or Volume outputs are built by the given
    functions of the node tree."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.clear()
    out = tree.nodes.new('ShaderNodeOutputMaterial')
    if surface is not None:
        tree.links.new(surface(tree), out.inputs['Surface'])
    if volume is not None:
        tree.links.new(volume(tree), out.inputs['Volume'])
    return mat


def _node(tree, kind, **inputs):
    node = tree.nodes.new(kind)
    for name, value in inputs.items():
        socket = node.inputs[name]
        socket.default_value = value if not isinstance(value, tuple) or len(value) == 4 else value + (1.0,)
    return node.outputs[0]


def _object(mesh_op, material, **kwargs):
    mesh_op(**kwargs)
    obj = bpy.context.active_object
    obj.data.materials.append(material)
    return obj


def _floor(color):
    floor = _material("Floor", lambda t: _node(t, 'ShaderNodeBsdfDiffuse', Color=color))
    return _object(bpy.ops.mesh.primitive_plane_add, floor, size=12.0, location=(0, 0, 0))


def _world(scene, color):
    world = bpy.data.worlds.new("W")
    world.use_nodes = True
    world.node_tree.nodes['Background'].inputs['Color'].default_value = tuple(color) + (1.0,)
    scene.world = world


def _camera(scene, location, target, lens=40):
    from mathutils import Vector
    cam = scene.camera
    cam.location = location
    cam.rotation_euler = (Vector(target) - Vector(location)).to_track_quat('-Z', 'Y').to_euler()
    cam.data.lens = lens


def _volume_settings(scene, volume_bounces=0):
    """Cycles' volume settings, explicitly: its default Volume bounces (0:
    single scattering) unless given, unbiased null scattering."""
    scene.ember.volume_bounces = volume_bounces
    cycles = scene.cycles
    if hasattr(cycles, 'volume_biased'):
        cycles.volume_biased = False


# ----------------------------------------------------------------------------
# Scenes

def _lamp(scene, name, kind, location, rotation=(0.0, 0.0, 0.0), **settings):
    """A light object of ``kind`` with the light's ``settings``."""
    light = bpy.data.lights.new(name, kind)
    for key, value in settings.items():
        setattr(light, key, value)
    obj = bpy.data.objects.new(name, light)
    obj.location, obj.rotation_euler = location, rotation
    scene.collection.objects.link(obj)
    return obj


def scene_coloured_glass(scene):
    _floor((0.7, 0.7, 0.7))
    glass = _material("ColouredGlass",
                      lambda t: _node(t, 'ShaderNodeBsdfGlass', Color=(1, 1, 1), Roughness=0.0, IOR=1.45),
                      lambda t: _node(t, 'ShaderNodeVolumeAbsorption', Color=(0.2, 0.45, 0.9), Density=1.5))
    _object(bpy.ops.mesh.primitive_cube_add, glass, size=1.0, location=(-0.6, 0.0, 0.52))   # clear of the floor
    smoke = _material("Smoke", volume=lambda t: _node(t, 'ShaderNodeVolumeAbsorption', Color=(0.9, 0.5, 0.3),
                                                      Density=1.2))
    _object(bpy.ops.mesh.primitive_ico_sphere_add, smoke, radius=0.5, subdivisions=3, location=(0.7, 0.2, 0.52))
    _lamp(scene, "Area", 'AREA', (0.5, -1.5, 3.5), energy=80.0, size=1.5)
    _world(scene, DARK_WORLD)
    _camera(scene, (0.0, -3.0, 1.9), (0.05, 0.0, 0.45))
    _volume_settings(scene)
    return 8


def scene_fog(scene):
    _floor((0.6, 0.6, 0.6))
    fog = _material("Fog", volume=lambda t: _node(t, 'ShaderNodeVolumePrincipled', Color=(0.85, 0.8, 0.7),
                                                  Density=0.6, Anisotropy=0.3))
    _object(bpy.ops.mesh.primitive_cube_add, fog, size=2.0, location=(0.0, 0.0, 1.1))   # clear of the floor
    _lamp(scene, "Spot", 'SPOT', (0.3, 0.2, 3.5), (0.15, 0.0, 0.0), energy=800.0, spot_size=0.6, spot_blend=0.2,
          shadow_soft_size=0.1)
    _world(scene, DARK_WORLD)
    _camera(scene, (0.0, -5.0, 1.6), (0.0, 0.0, 0.9))
    _volume_settings(scene, volume_bounces=0)
    return 4


def scene_emission(scene):
    _floor((0.3, 0.3, 0.3))
    glow = _material("Glow", volume=lambda t: _node(t, 'ShaderNodeEmission', Color=(1.0, 0.5, 0.2), Strength=2.0))
    _object(bpy.ops.mesh.primitive_uv_sphere_add, glow, radius=0.6, segments=32, ring_count=16,
            location=(-0.7, 0.0, 0.62))
    ember = _material("Ember", volume=lambda t: _node(t, 'ShaderNodeVolumePrincipled', **{
        'Color': (0.9, 0.6, 0.3), 'Density': 0.8, 'Absorption Color': (0.3, 0.6, 0.9),
        'Emission Strength': 1.5, 'Emission Color': (0.4, 0.7, 1.0)}))
    _object(bpy.ops.mesh.primitive_cube_add, ember, size=1.0, location=(0.7, 0.0, 0.52))
    _world(scene, (0.02, 0.02, 0.02))
    _camera(scene, (0.0, -3.6, 1.8), (0.0, 0.0, 0.5))
    _volume_settings(scene)
    return 4


SCENES = {'coloured_glass': scene_coloured_glass, 'fog': scene_fog, 'emission': scene_emission}


def reference_scene(name, folder=None):
    """The scene ``name`` and its bounces (as tools/cycles_references.py renders it)."""
    return built_reference_scene(SCENES[name], WIDTH, HEIGHT)


@pytest.mark.parametrize("name", sorted(SCENES))
def test_volume_parity_with_cycles(name, tmp_path, tapped_engine):
    scene, bounces = reference_scene(name)
    spp = SPP.get(name, EMBER_SPP)
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, spp, 1, bounces)
    from addon import engine as ember_engine
    log = ember_engine.RENDER_LOG[-1]
    assert not [w for w in log.get('warnings', ()) if 'Material' in w], log.get('warnings')
    check = check_against_reference('volume_' + name, scene, bounces, image, var, spp, BLOCK)
    check.assert_agrees(*WEAK.get(name, (IMAGE_POWER, BLOCK_POWER)))


def test_volume_export(empty_scene):
    """What the exporter makes of volume nodes: Cycles' coefficients, the
    pass-through surface of a volume-only material, and warnings naming the
    material for what is approximated or read as a constant."""
    from addon.export import material as export
    only = _material("OnlyVolume", volume=lambda t: _node(t, 'ShaderNodeVolumePrincipled', **{
        'Color': (0.5, 0.8, 1.0), 'Density': 2.0, 'Absorption Color': (0.25, 1.0, 0.0), 'Anisotropy': 0.4,
        'Emission Strength': 3.0, 'Emission Color': (1.0, 0.5, 0.0)}))
    only.node_tree.nodes['Principled Volume'].inputs['Blackbody Intensity'].default_value = 0.5
    only.node_tree.nodes['Principled Volume'].inputs['Temperature'].default_value = 1500.0
    mat, warning = export.translate(only)
    assert warning is None, warning
    # Cycles' blackbody: sigma x mix(1, T^4, 0.5) x blackbody(1500 K) added to Strength x Color.
    from addon import backend
    renderer = backend.engine()
    import numpy as np
    bb = renderer.NODE_REGISTRY['ShaderNodeBlackbody'].evaluate(renderer.ShadingContext(1),
                                                                  {'Temperature': np.array([1500.0])}, {})['Color'][0]
    extra = 5.670373e-8 * 1e-6 / np.pi * (0.5 + 0.5 * 1500.0 ** 4) * bb
    assert mat.volume.emission == pytest.approx(tuple(np.array((3.0, 1.5, 0.0)) + extra), rel=1e-6)
    assert extra[0] > 0.1
    assert [lobe.kind for lobe in mat.lobes] == ['transparent']
    v = mat.volume
    assert v.scattering == pytest.approx((1.0, 1.6, 2.0))
    assert v.absorption == pytest.approx((0.5 * 0.5 * 2.0, 0.0, 0.0))
    assert v.anisotropy == pytest.approx(0.4)

    def mixed(t):
        scatter = t.nodes.new('ShaderNodeVolumeScatter')
        scatter.inputs['Density'].default_value = float('nan')
        if hasattr(scatter, 'phase'):
            scatter.phase = 'RAYLEIGH'
        noise = t.nodes.new('ShaderNodeTexNoise')
        absorb = t.nodes.new('ShaderNodeVolumeAbsorption')
        absorb.inputs['Density'].default_value = -3.0
        t.links.new(noise.outputs['Fac'], absorb.inputs['Density'])
        mix = t.nodes.new('ShaderNodeMixShader')
        mix.inputs['Fac'].default_value = 0.25
        t.links.new(scatter.outputs[0], mix.inputs[1])
        t.links.new(absorb.outputs[0], mix.inputs[2])
        return mix.outputs[0]
    glass = _material("HostileGlass", lambda t: _node(t, 'ShaderNodeBsdfGlass'), mixed)
    mat, warning = export.translate(glass)
    assert [lobe.kind for lobe in mat.lobes] == ['glass']
    assert mat.volume.scattering == (0.0, 0.0, 0.0)
    # The noise-driven density is a heterogeneous medium (engine/media/field.py).
    from addon import backend
    assert isinstance(mat.volume.absorption, backend.engine().TEXTURE_TYPES), mat.volume.absorption
    assert "HostileGlass" in warning and "read as 0" in warning and "Density" in warning, warning
    assert "read as its constant" not in warning, warning
    if bpy.app.version >= (4, 2, 0):
        assert mat.volume.phase == 'RAYLEIGH', mat.volume.phase


# ----------------------------------------------------------------------------
# Volume Direct / Volume Indirect (Cycles' view layer passes) on the fog

# Ember 8 seeds x 32 spp (about 1.3 s a render on a loaded machine, mostly per render),
# Cycles 6 x 256 (0.4 s each): about 14 s.  With 5 Ember seeds Welch's dof sat near 4 and the
# image means detected only 17 % / 22 %; with 8 they detect about 5 % / 7 % (printed).
PASS_SEEDS = {'EMBER': 8, 'CYCLES': 6}
PASS_SPP = {'EMBER': 32, 'CYCLES': 256}
PASS_WIDTH, PASS_HEIGHT = 24, 18
VOLUME_PASSES = ("Volume Direct", "Volume Indirect")


def test_fog_volume_passes_match_cycles(registered_addon, tmp_path):
    """The fog scene with Volume bounces 1 (at 0 both engines end a path at
    the surface after its volume scatter, so Volume Indirect is empty in
    both) rendered by both engines at a few seeds with Volume Direct and
    Volume Indirect on: each pass's image mean by Welch's t over the seeds
    (one family of 2 tests, power printed).  Volume Direct: the spot's
    light at the fog's first scattering points; Volume Indirect: the light
    of those paths after, at a second scatter or the floor."""
    import os

    import numpy as np

    import ember_stats as stats
    from ember_testlib import multilayer_output, read_multilayer_exr, setup_cycles, setup_ember
    scene, bounces = built_reference_scene(scene_fog, PASS_WIDTH, PASS_HEIGHT)
    scene.ember.volume_bounces = 1   # setup_cycles gives Cycles the same
    layer = bpy.context.view_layer
    layer.cycles.use_pass_volume_direct = True
    layer.cycles.use_pass_volume_indirect = True
    multilayer_output(scene)
    means = {}
    for engine, setup in (('EMBER', setup_ember), ('CYCLES', setup_cycles)):
        for seed in range(PASS_SEEDS[engine]):
            setup(scene, PASS_SPP[engine], 40 + seed, bounces)
            scene.render.filepath = os.path.join(str(tmp_path), f"{engine}_{seed}.exr")
            bpy.ops.render.render(write_still=True)
            images = read_multilayer_exr(scene.render.filepath)
            for name in VOLUME_PASSES:
                means.setdefault((engine, name), []).append(images[name][..., :3].mean())
    level = stats.family_level("fog volume passes image mean", len(VOLUME_PASSES))
    failed = []
    for name in VOLUME_PASSES:
        a, b = np.array(means[('EMBER', name)]), np.array(means[('CYCLES', name)])
        mean = stats.MeanTest(name, a.mean(), a.var(ddof=1) / len(a), len(a) - 1,
                              b.mean(), b.var(ddof=1) / len(b), len(b) - 1)
        print(f"\n{name}: Ember {a.mean():.5g}, Cycles {b.mean():.5g}: {mean}; detects "
              f"{stats.detectable(mean.relative_se, level, mean.dof):.2%} with probability 1/2")
        assert b.mean() > 0, f"Cycles' {name} is empty"
        if mean.p < level:
            failed.append(mean)
    assert not failed, failed


# ----------------------------------------------------------------------------
# A sphere lamp (soft falloff off) inside fog: scatter points inside the lamp

LAMP_SEEDS, LAMP_SPP = 6, 64
LAMP_WIDTH, LAMP_HEIGHT = 24, 18


def scene_lamp_in_fog(scene):
    """A fog cube holding a point lamp of radius 0.6, Soft Falloff off (a
    sphere light): a tenth of the fog lies inside the lamp, where Cycles 5.0
    samples the uniform sphere and its rays hit the lamp's far side."""
    fog = _material("Fog", volume=lambda t: _node(t, 'ShaderNodeVolumePrincipled', Color=(0.8, 0.8, 0.8),
                                                  Density=0.5, Anisotropy=0.0))
    _object(bpy.ops.mesh.primitive_cube_add, fog, size=2.4, location=(0.0, 0.0, 0.0))
    _lamp(scene, "Lamp", 'POINT', (0.1, 0.0, 0.05), energy=60.0, shadow_soft_size=0.6, use_soft_falloff=False)
    _world(scene, DARK_WORLD)
    _camera(scene, (0.0, -5.0, 0.4), (0.0, 0.0, 0.0))
    _volume_settings(scene, volume_bounces=1)
    return 4


@pytest.mark.parametrize("cycles_mis", [
    False,
    pytest.param(True, marks=pytest.mark.xfail(strict=True, reason=(
        "Cycles 5.0's own MIS render of this scene (Volume bounces 1) is 4.3 % +- 0.3 % darker than Ember's "
        "(t = 15); Cycles with the lamp's Multiple Importance off (NEE only) is 4.5 % +- 0.4 % brighter than "
        "its MIS render and agrees with Ember (-0.2 % +- 0.4 %), whose light, phase and MIS strategies agree "
        "(tests/engine/test_media.py): a bias of Cycles' MIS here (1.2 % +- 0.3 % with Soft Falloff on)")))])
def test_sphere_lamp_in_fog_matches_cycles(registered_addon, tmp_path, cycles_mis):
    """The lamp-in-fog scene by both engines at a few seeds: the image's
    and its quadrants' totals by Welch's t over the seeds (one family,
    power printed).  Cycles renders the lamp with Multiple Importance off
    (NEE only: its MIS render is biased here, see the xfail); Ember as
    always (its strategies agree).  Before Ember sampled the lamp from
    inside, the points there got none of its light."""
    import numpy as np

    import ember_stats as stats
    from ember_testlib import render_seeds
    scene, bounces = built_reference_scene(scene_lamp_in_fog, LAMP_WIDTH, LAMP_HEIGHT)
    bpy.data.objects["Lamp"].data.cycles.use_multiple_importance_sampling = cycles_mis
    images = render_seeds(scene, tmp_path, "lamp_in_fog", LAMP_SEEDS, LAMP_SPP, 60, bounces)
    tests, level = stats.region_mean_tests(images['EMBER'][..., :3], images['CYCLES'][..., :3],
                                           f"sphere lamp in fog region means, Cycles MIS {cycles_mis}")
    for test in tests:
        print(f"\nlamp in fog (Cycles MIS {cycles_mis}), {test}; detects "
              f"{stats.detectable(test.relative_se, level, test.dof):.2%}")
    assert images['CYCLES'][..., :3].mean() > 0
    failed = [test for test in tests if test.p < level]
    assert not failed, failed
