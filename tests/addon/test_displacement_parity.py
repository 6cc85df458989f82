"""Cycles parity of true displacement (engine/displacement.py): a plane
subdivided by a Simple Subdivision modifier to 8192 triangles whose
material displaces it steeply (a Noise texture's Fac through a
Displacement node, object space, scale 0.6 over a 2 m plane) under a low
sun, so the relief's silhouette and cast shadows show; "Displacement Only"
and "Displacement and Bump" each against a live Cycles reference (4 seeds)
by the suite's region and block tests (ReferenceCheck), power printed.
"Both" at scale 0.15 and 0.6, and Bump Only at 0.6: Cycles' bump from a
displacement is the smooth normal (SetNormal), no bump shadowing term
applies to it (with the term Ember was 0.17% / 3.4% / 1.8% dark).
The old fallback (the same material rendered as bump, what Ember did for
both methods before) must fail the same tests against the Displacement
Only reference: its difference is printed.
The transformed cases: the relief scaled (2, 1, 0.5), rotated and parented,
Object and World space, each method."""
import math

import bpy
import numpy as np
import pytest

from parity_scenes import light, material, plane
from ember_testlib import (ReferenceCheck, empty_factory_scene, live_cycles_reference, render_for_reference,
                           small_resolution)

SIZE = (40, 30)
BLOCK = 5
BOUNCES = 2
EMBER_SPP = 256
CYCLES_SEEDS, CYCLES_SPP = 4, 128
LEVELS = 6      # 2 x 4^6 = 8192 triangles


def displaced_material(method, scale=0.6):
    mat = material('relief', 'diffuse', (0.7, 0.6, 0.5))
    mat.displacement_method = method
    tree = mat.node_tree
    noise = tree.nodes.new('ShaderNodeTexNoise')
    noise.inputs['Scale'].default_value = 3.0
    noise.inputs['Detail'].default_value = 1.0
    disp = tree.nodes.new('ShaderNodeDisplacement')
    disp.space = 'OBJECT'
    disp.inputs['Midlevel'].default_value = 0.5
    disp.inputs['Scale'].default_value = scale
    tree.links.new(noise.outputs['Fac'], disp.inputs['Height'])
    out = next(n for n in tree.nodes if n.type == 'OUTPUT_MATERIAL')
    tree.links.new(disp.outputs['Displacement'], out.inputs['Displacement'])
    return mat


def relief(scene, method, scale=0.6, smooth=True):
    obj = plane('relief', displaced_material(method, scale), half=1.0)
    for poly in obj.data.polygons:
        poly.use_smooth = smooth
    sub = obj.modifiers.new('subdivide', 'SUBSURF')
    sub.subdivision_type = 'SIMPLE'
    sub.levels = sub.render_levels = LEVELS
    plane('floor', material('floor', 'diffuse', (0.3, 0.3, 0.3)), half=4.0, z=-0.35)
    light('SUN', (0.0, 0.0, 3.0), 3.0, rotation=(math.radians(70.0), 0.0, math.radians(30.0)), angle=0.05)
    background = scene.world.node_tree.nodes.get('Background')
    if background is not None:
        background.inputs['Color'].default_value = (0.05, 0.05, 0.06, 1.0)
    cam = scene.camera
    cam.location, cam.rotation_euler = (0.0, -2.6, 1.4), (math.radians(62.0), 0.0, 0.0)
    cam.data.lens = 35.0
    small_resolution(scene, *SIZE)


def reference_scene(name, folder=None):
    """The relief with Displacement Only ('only') or Both ('both') at scale
    0.6, and its bounces (tools/render_gallery.py's 'displacement')."""
    scene = empty_factory_scene()
    relief(scene, {'only': 'DISPLACEMENT', 'both': 'BOTH'}[name])
    return scene, BOUNCES


def _ember(scene, tmp_path, tapped_engine, name):
    image, var = render_for_reference(scene, tmp_path, name, tapped_engine, EMBER_SPP, 3, BOUNCES)
    from addon import engine as ember_engine
    warnings = ember_engine.RENDER_LOG[-1].get('warnings') or []
    assert not [w for w in warnings if 'displacement' in w.lower()], warnings
    return image[..., :3].astype(np.float64), var


def _against_cycles(tmp_path, tapped_engine, method, scale, name, smooth=True):
    scene = empty_factory_scene()
    relief(scene, method, scale, smooth)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, name, CYCLES_SEEDS, CYCLES_SPP, BOUNCES)
    image, var = _ember(scene, tmp_path, tapped_engine, name)
    print(f"{name}: Ember mean {image.mean():.5g}, Cycles {ref.mean():.5g} (ratio {image.mean() / ref.mean():.4f})")
    check = ReferenceCheck(name, image, var, EMBER_SPP, ref, ref_var, header, BLOCK)
    return scene, ref, ref_var, header, check


def test_displacement_only_matches_cycles(tmp_path, tapped_engine):
    scene, ref, ref_var, header, check = _against_cycles(tmp_path, tapped_engine, 'DISPLACEMENT', 0.6,
                                                         'displacement_only')
    check.assert_agrees(0.02, 0.15)
    # The old fallback: the same relief as a bump on the flat plane.
    bpy.data.materials['relief'].displacement_method = 'BUMP'
    bump, bump_var = _ember(scene, tmp_path, tapped_engine, 'displace_as_bump')
    old = ReferenceCheck('displacement_as_bump', bump, bump_var, EMBER_SPP, ref, ref_var, header, BLOCK)
    import ember_stats as stats
    a, b = stats.block_means(bump[None], BLOCK)[0], stats.block_means(ref[None], BLOCK)[0]
    print(f"the bump fallback against Cycles' displacement: image mean ratio {bump.mean() / ref.mean():.4f}, "
          f"mean |block error| {np.mean(np.abs(a - b)) / np.mean(b):.3f}, {len(old.blocks)} failing "
          f"block-channels, {len(old.mean_failures)} failing region means")
    assert len(old.blocks) or old.mean_failures, "the bump fallback passes: the scene shows no displacement"


def test_displacement_and_bump_matches_cycles(tmp_path, tapped_engine):
    """"Both" at a moderate height (scale 0.15)."""
    _, _, _, _, check = _against_cycles(tmp_path, tapped_engine, 'BOTH', 0.15, 'displacement_both')
    check.assert_agrees(0.02, 0.15)


def test_flat_displacement_and_bump_matches_cycles(tmp_path, tapped_engine, monkeypatch):
    """"Both" on flat faces: the bump starts from the undisplaced face
    normal as Cycles' (svm_node_enter_bump_eval reads the undisplaced
    normal), not the displaced triangle's, which the relief would bend a
    second time (a flat 2 M-triangle heightmap terrain was 11 % dark in
    tools/compare_blends.py).  That old start must fail the same tests."""
    scene, ref, ref_var, header, check = _against_cycles(tmp_path, tapped_engine, 'BOTH', 0.15,
                                                         'displacement_both_flat', smooth=False)
    check.assert_agrees(0.02, 0.15)
    from engine import textures
    monkeypatch.setattr(textures, "_flat_undisplaced", lambda ns, triangles, ctx: ns)
    twice, twice_var = _ember(scene, tmp_path, tapped_engine, 'displacement_both_flat_twice')
    old = ReferenceCheck('displacement_both_flat_bent_twice', twice, twice_var, EMBER_SPP, ref, ref_var, header,
                         BLOCK)
    print(f"bent twice: image mean ratio {twice.mean() / ref.mean():.4f}, {len(old.blocks)} failing "
          f"block-channels, {len(old.mean_failures)} failing region means")
    assert len(old.blocks) or old.mean_failures, "bending the displaced normal again passes: the test sees nothing"


@pytest.mark.parametrize("method", ['BOTH', 'BUMP'])
def test_steep_displacement_bump_matches_cycles(method, tmp_path, tapped_engine):
    """The steep relief's bump, with true displacement ("Both") and without
    ("Bump Only"): Cycles' displacement bump sets the smooth normal itself
    (SetNormal), so no bump shadowing term dims it.  With the term, Both
    was 3.36% +- 0.03% dark and Bump Only 1.8%."""
    _, _, _, _, check = _against_cycles(tmp_path, tapped_engine, method, 0.6, f'displacement_steep_{method.lower()}')
    check.assert_agrees(0.02, 0.15)


# A transformed relief: the plane scaled (2, 1, 0.5), turned and parented to
# a turned, moved empty.  Cycles does not apply the transform of a truly
# displaced mesh (apply_static_transforms skips has_true_displacement()), so
# the displacement runs on the object-space mesh: Object space moves a vertex
# by the height along the unit object normal, scaled by the object matrix
# afterwards (0.5 along z here); World space by the height along the unit
# world normal, brought back to object space (kernel_displace_evaluate's
# object_inverse_dir_transform).  The two differ by 2x in relief height.
TRANSFORMED_HALF = 0.55


def transformed_relief(scene, method, space, scale):
    relief(scene, method, scale)
    obj = bpy.data.objects['relief']
    node = next(n for n in bpy.data.materials['relief'].node_tree.nodes if n.type == 'DISPLACEMENT')
    node.space = space
    parent = bpy.data.objects.new('holder', None)
    scene.collection.objects.link(parent)
    parent.location = (0.1, 0.15, 0.05)
    parent.rotation_euler = (0.0, 0.0, math.radians(20.0))
    obj.parent = parent
    obj.scale = (2.0, 1.0, 0.5)
    obj.rotation_euler = (math.radians(12.0), math.radians(-8.0), math.radians(-10.0))
    obj.data.transform(__import__('mathutils').Matrix.Scale(TRANSFORMED_HALF, 4))
    return obj


STEEP_BOTH_GAP = pytest.mark.xfail(strict=True, reason=(
    "steep Both: Ember -0.32% +- 0.03% (max block |t| 5.6) with Cycles' footprint bump (-0.29% +- 0.03%, max "
    "block |t| 5.8, with the limit bump: not the bump's differencing); not the transform: the same relief with a unit "
    "scale is -0.65% at height 0.8, Object space at 0.8 (the same surface) -0.37%, Displacement Only at 0.8 "
    "agrees; the identity-transform steep test is at +0.12% +- 0.03%"))


@pytest.mark.parametrize("method,space,scale", [
    ('DISPLACEMENT', 'OBJECT', 0.4), ('DISPLACEMENT', 'WORLD', 0.4), ('BOTH', 'OBJECT', 0.4),
    ('BOTH', 'WORLD', 0.2), pytest.param('BOTH', 'WORLD', 0.4, marks=STEEP_BOTH_GAP)])
def test_transformed_displacement_matches_cycles(method, space, scale, tmp_path, tapped_engine):
    """True displacement of a scaled, rotated, parented object, in Object
    and World space, "Displacement Only" and "Both".  Both's bump is
    Cycles' object-space bump of dot(D, N) (bump_from_displacement with
    use_object_space): with Ember's world-space bump of the node's height
    Both was +3.11% +- 0.04% (Object) and +3.33% +- 0.04% (World, 0.4)
    bright, max block |t| 50 and 47.  World space at 0.2 is the surface of
    Object space at 0.4 (z scale 0.5), reached by the other path."""
    name = f'displacement_transformed_{method.lower()}_{space.lower()}_{scale:g}'
    scene = empty_factory_scene()
    transformed_relief(scene, method, space, scale)
    ref, ref_var, header = live_cycles_reference(scene, tmp_path, name, CYCLES_SEEDS, CYCLES_SPP, BOUNCES)
    image, var = _ember(scene, tmp_path, tapped_engine, name)
    print(f"{name}: Ember mean {image.mean():.5g}, Cycles {ref.mean():.5g} (ratio {image.mean() / ref.mean():.4f})")
    check = ReferenceCheck(name, image, var, EMBER_SPP, ref, ref_var, header, BLOCK)
    check.assert_agrees(0.02, 0.15)
