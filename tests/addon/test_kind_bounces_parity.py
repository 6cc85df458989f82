"""Cycles parity of the per-kind bounce limits (Light Paths > Max Bounces >
Diffuse / Glossy / Transmission; scene.ember.*_bounces, engine/integrator
count_kind): a room of diffuse walls with a glossy sphere and a glass
sphere under an area light, rendered by both engines with Max Bounces 8
but Diffuse 1, Glossy 1, Transmission 2, where the diffuse interreflection,
glossy-glossy chains and light through the glass are each cut by their own
limit.  Cycles is rendered here (8 seeds), its per-pixel variance of the
mean from the seeds' scatter; Ember's image against it by the suite's
region and block tests (ember_testlib.ReferenceCheck), power printed.
Beside it, Ember's image must differ from the same scene with the limits
left at Max Bounces (the limits have their effect)."""
import bpy
import numpy as np

from parity_scenes import glass_material, smooth_sphere, light, material, mesh_object, plane
from ember_testlib import (ReferenceCheck, empty_factory_scene, live_cycles_reference, render_for_reference,
                           small_resolution)

SIZE = 32
BLOCK = 8
EMBER_SPP = 1536   # 512 resolved 2.45 % of the image, not 2 % (the channel sum's variance)
CYCLES_SEEDS, CYCLES_SPP = 8, 128
LIMITS = {'diffuse_bounces': 1, 'glossy_bounces': 1, 'transmission_bounces': 2}
MAX_BOUNCES = 8


def room(scene):
    walls = material('walls', 'diffuse', (0.75, 0.7, 0.65))
    plane('floor', walls, half=2.0, z=0.0)
    plane('ceiling', walls, half=2.0, z=2.5)
    for name, verts in (('back', [(-2, 2, 0), (2, 2, 0), (2, 2, 2.5), (-2, 2, 2.5)]),
                        ('left', [(-2, -2, 0), (-2, 2, 0), (-2, 2, 2.5), (-2, -2, 2.5)]),
                        ('right', [(2, 2, 0), (2, -2, 0), (2, -2, 2.5), (2, 2, 2.5)])):
        mesh_object(name, verts, [(0, 1, 2, 3)], walls)
    smooth_sphere('metal', material('metal', 'glossy', (0.9, 0.9, 0.9), roughness=0.15), (-0.8, 0.5, 0.6), 0.6)
    smooth_sphere('glass', glass_material('glass', ior=1.45), (0.8, 0.0, 0.6), 0.6)
    light('AREA', (0.0, 0.5, 2.45), 120.0, size=1.0)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, -5.5, 1.3), (np.radians(87.0), 0.0, 0.0)
    cam.data.lens = 30.0
    small_resolution(scene, SIZE, SIZE)


def _limits(settings, limits):
    for name, value in limits.items():
        setattr(settings, name, value)


def test_kind_limits_match_cycles(tmp_path, tapped_engine):
    scene = empty_factory_scene()
    room(scene)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, 'kinds', CYCLES_SEEDS, CYCLES_SPP, MAX_BOUNCES,
                                                 configure=lambda cycles: _limits(cycles, LIMITS))
    image, var = render_for_reference(scene, tmp_path, 'kinds', tapped_engine, EMBER_SPP, 5, MAX_BOUNCES,
                                      configure=lambda ember: _limits(ember, LIMITS))
    check = ReferenceCheck('kind_bounces', image[..., :3].astype(np.float64), var, EMBER_SPP, ref, ref_var,
                           header, BLOCK)
    unlimited, _ = render_for_reference(scene, tmp_path, 'kinds_unlimited', tapped_engine, 64, 5, MAX_BOUNCES)
    ratio = unlimited[..., :3].mean() / image[..., :3].mean()
    print(f"kind_bounces: image mean without the per-kind limits / with them: {ratio:.3f}")
    assert ratio > 1.1, f"the per-kind limits change little (ratio {ratio:.3f}): the test shows nothing"
    check.assert_agrees(0.02, 0.1)
