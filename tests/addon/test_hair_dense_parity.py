"""Cycles parity of dense particle hair with the Principled Hair BSDF
(Chiang) as third-party files carry it (docs/real_scenes.md ``hair``:
image mean 1.017, p90 of 8x8 block errors 0.219 against Cycles' own 0.087,
no warning).

The scene: a sphere with 1,500 particle strands from its faces (3D
curves), Principled Hair Chiang as the check scene's (Melanin 0.5, the
node's Redness 1.0, Roughness 0.3; the node's other defaults), over a
diffuse floor under an area light and the factory world; Cycles' default
bounce limits (12; diffuse 4, glossy 4, transmission 12) and Filter Glossy
1.0 in both engines (Cycles' default: its bsdf_blur widens
the hair closures too, engine/lobes/hair.blur), against a live Cycles
reference: the image, 2 x 2 regions and blocks, power printed.

What differed is not the BSDF: Blender's Jittered distribution (the
default) places some hairs twice (about 250 of the 1,500 here, exactly
coincident), and Cycles renders such twins much darker than one strand
(each one's light blocked by the other) while Ember renders them as one.
With Distribution Random (no twins) Ember agrees: five runs -0.23 % +- 0.19 %,
+0.48 % +- 0.25 %, +0.67 % +- 0.36 % (four bounces), -0.10 % +- 0.35 %,
+0.63 % +- 0.35 % (Cycles' default limits), max block |t| 1.6-2.8; with
Jittered +8.4 % to +11.2 % (t 15-39, a strict xfail below), and the export
names the twins (particle_hair.coincident_strands).  The same strands with
a Diffuse BSDF: +10 % with twins (as much from direct light alone), +0.5 %
without.  Blender's particle placement (Random too) differs between
processes, never between the renders of one: each run compares the
engines on the same strands, but not on last run's."""
import math

import bpy
import numpy as np
import pytest

from ember_testlib import (ReferenceCheck, empty_factory_scene, live_cycles_reference, render_for_reference,
                           small_resolution)
from parity_scenes import light, material, particle_hair, plane
from test_hair_parity import hair_material

SIZE = (40, 30)
BLOCK = 10
BOUNCES = 12   # with Cycles' default per-kind limits (_default_limits)
# 128 / 8 x 24 spp resolved 2.66 % with the channel sum's variance (asked 2.5 %): 1.3x.
EMBER_SPP = 168
CYCLES_SEEDS, CYCLES_SPP = 8, 32
FILTER = 1.0


def hair_ball(scene, distribution='RAND'):
    """The check scene ``hair`` (tests/addon/check_scenes.py) at half the
    strands, seen closer (the hair fills most of the frame), with the
    particle Distribution ``distribution`` ('JIT' Blender's default)."""
    plane('floor', material('floor', 'diffuse', (0.6, 0.6, 0.6)), half=3.0)
    hair = hair_material('hair_default_redness', melanin=0.5, redness=1.0)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.5, location=(0.0, 0.0, 0.6), segments=32, ring_count=16)
    obj = bpy.context.active_object
    obj.data.materials.append(material('scalp', 'diffuse', (0.6, 0.5, 0.45)))
    obj.data.materials.append(hair)
    particle_hair(obj, 1500, distribution=distribution)
    light('AREA', (1.0, -1.5, 2.5), 150.0, size=1.0)
    cam = scene.camera
    cam.location = (0.0, -2.2, 1.0)
    cam.rotation_euler = (math.radians(81.0), 0.0, 0.0)
    cam.data.lens = 40.0
    scene.cycles_curves.shape = 'THICK'
    small_resolution(scene, *SIZE)


def _filter(value):
    return lambda settings: setattr(settings, 'blur_glossy' if hasattr(settings, 'blur_glossy')
                                    else 'filter_glossy', value)



def _default_limits(value=FILTER):
    """Cycles' default per-kind limits (diffuse 4, glossy 4, transmission 12,
    12 in all) and Filter Glossy ``value``."""
    def configure(settings):
        _filter(value)(settings)
        settings.max_bounces, settings.diffuse_bounces = 12, 4
        settings.glossy_bounces, settings.transmission_bounces = 4, 12
    return configure


def _against_cycles(tmp_path, taps, distribution, ember_spp=EMBER_SPP, seeds=CYCLES_SEEDS, spp=CYCLES_SPP):
    scene = empty_factory_scene()
    hair_ball(scene, distribution)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'hair_' + distribution, seeds, spp, BOUNCES,
                                                 configure=_default_limits())
    image, var = render_for_reference(scene, tmp_path, 'hair_' + distribution, taps, ember_spp, 3, BOUNCES,
                                      configure=_default_limits())
    return ReferenceCheck('hair_' + distribution, image[..., :3].astype(np.float64), var, ember_spp, ref, ref_var,
                          header, BLOCK)


def test_dense_principled_hair_matches_cycles(tmp_path, tapped_engine):
    """No twins (Distribution Random): Ember agrees with Cycles."""
    _against_cycles(tmp_path, tapped_engine, 'RAND').assert_agrees(0.025, 0.2)


@pytest.mark.xfail(strict=True, reason="coincident strands (Distribution Jittered twins): Cycles renders them "
                                       "darker than one strand, Ember as one; measured +8.4 % to +11.2 % "
                                       "(+- 0.3-0.6 %, t 15-39) on the image, blocks up to +48 %; named by the "
                                       "export's warning")
def test_coincident_strands_match_cycles(tmp_path, tapped_engine):
    _against_cycles(tmp_path, tapped_engine, 'JIT', ember_spp=64, seeds=4, spp=16).assert_agrees()


def test_coincident_strands_are_named(tmp_path, tapped_engine):
    """The export counts the twins of each particle system and says so;
    Distribution Random has none."""
    from addon import engine as ember_engine
    for distribution, named in (('JIT', True), ('RAND', False)):
        scene = empty_factory_scene()
        hair_ball(scene, distribution)
        render_for_reference(scene, tmp_path, 'named_' + distribution, tapped_engine, 1, 3, 1)
        warnings = ember_engine.RENDER_LOG[-1].get('warnings') or []
        hit = [w for w in warnings if "coincide exactly" in w]
        assert bool(hit) == named, (distribution, warnings)
        if named:
            assert "particle system 'hair'" in hit[0] and "Jittered" in hit[0], hit


def test_coincident_strands_counted():
    from addon.export.particle_hair import coincident_strands
    co = np.random.default_rng(1).normal(size=(5, 4, 3))
    assert coincident_strands(co) == 0 and coincident_strands(co[:1]) == 0
    co[3] = co[1]
    co[4] = co[1]
    assert coincident_strands(co) == 2


