"""Light Linking and Shadow Linking (Blender 4.0+: a light's receiver and
blocker collections), against Cycles (issue 26).

Scene: a floor, a red and a blue sphere, a pillar between the key light and
the red sphere; the key light (a sphere light) lights the floor and the red
sphere only (its receiver collection includes both), and its shadows are
cast by the blue sphere alone (blocker collection: the pillar is left out,
so the red sphere is lit through it); a fill area light is linked to
everything.  Ember seeds against Cycles seeds, RGB: Welch's t per 4x4
block and channel and on the image mean (ember_testlib.seed_block_test),
power printed.
"""
import bpy
import numpy as np
import pytest

from ember_testlib import (add_object, empty_factory_scene, render_array, render_seeds, require, rough_material,
                           seed_block_test, setup_ember, small_resolution)

SEEDS, SPP, BOUNCES = 6, 48, 2
WIDTH, HEIGHT = 32, 24


def _add(op, name, color, **kwargs):
    return add_object(op, name, rough_material(name, color)[0], **kwargs)


def linked_scene():
    scene = empty_factory_scene()
    mesh = bpy.ops.mesh
    floor = _add(mesh.primitive_plane_add, "Floor", (0.6, 0.6, 0.6), size=12, location=(0, 0, -1))
    red = _add(mesh.primitive_uv_sphere_add, "Red", (0.8, 0.2, 0.1), radius=0.8, location=(-1.1, 0.0, -0.2))
    blue = _add(mesh.primitive_uv_sphere_add, "Blue", (0.1, 0.3, 0.8), radius=0.8, location=(1.2, 0.0, -0.2))
    pillar = _add(mesh.primitive_cube_add, "Pillar", (0.5, 0.5, 0.5), size=0.5, location=(-0.9, 0.2, 1.6))
    bpy.ops.object.light_add(type='POINT', location=(-0.5, 0.5, 3.5))
    key = bpy.context.active_object
    key.data.energy = 800.0
    key.data.shadow_soft_size = 0.3
    bpy.ops.object.light_add(type='AREA', location=(2.0, -3.0, 3.0))
    fill = bpy.context.active_object
    fill.data.energy = 150.0
    fill.data.size = 2.0
    receivers = bpy.data.collections.new("KeyReceivers")
    for obj in (floor, red):
        receivers.objects.link(obj)
    blockers = bpy.data.collections.new("KeyBlockers")
    blockers.objects.link(blue)
    key.light_linking.receiver_collection = receivers
    key.light_linking.blocker_collection = blockers
    del pillar
    small_resolution(scene, WIDTH, HEIGHT)
    return scene


@pytest.fixture(scope="module")
def renders(registered_addon, tmp_path_factory):
    require('light_linking' in bpy.types.Object.bl_rna.properties, "light linking is Blender 4.0's")
    folder = tmp_path_factory.mktemp("linking")
    out = render_seeds(linked_scene(), folder, "linking", SEEDS, SPP, 700, BOUNCES)
    return {engine: images[..., :3] for engine, images in out.items()}


def test_light_and_shadow_linking_match_cycles(renders):
    ember, cycles = renders['EMBER'], renders['CYCLES']
    assert np.isfinite(ember).all()
    seed_block_test("light linking parity blocks", "light linking parity image mean", "light and shadow linking",
                    ember, cycles)


def test_empty_and_deleted_linking_collections(registered_addon, tmp_path):
    """Hostile input: a receiver collection that is empty links every object
    (Blender's rule), with a warning naming the light; one that was deleted
    is no link; the render stays finite."""
    require('light_linking' in bpy.types.Object.bl_rna.properties, "light linking is Blender 4.0's")
    from addon.export.scene import export_scene
    scene = linked_scene()
    key = bpy.data.objects['Point']
    empty = bpy.data.collections.new("Nothing")
    key.light_linking.receiver_collection = empty
    export = export_scene(bpy.context.evaluated_depsgraph_get())
    assert any("'Point'" in w and "'Nothing'" in w and "empty" in w for w in export.warnings), export.warnings
    receivers, blockers = export.scene.light_links[0]
    assert receivers is None and blockers is not None
    bpy.data.collections.remove(bpy.data.collections["KeyBlockers"])
    bpy.data.collections.remove(empty)
    export = export_scene(bpy.context.evaluated_depsgraph_get())
    assert export.scene.light_links == {}
    setup_ember(scene, 4, 1, 1)
    assert np.isfinite(render_array(scene, tmp_path, "deleted")).all()
